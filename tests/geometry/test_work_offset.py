"""work_offset_from_poses: known compositions, random round trips, tilt refusal."""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.transforms import PoseError, inv, make_pose, pose_from_xyz_euler, transform_points
from app.geometry.work_offset import work_offset_from_poses


def _random_pose(rng: np.random.Generator, span_mm: float = 500.0) -> np.ndarray:
    a, b, c = rng.uniform(-180, 180, 3)
    x, y, z = rng.uniform(-span_mm, span_mm, 3)
    return pose_from_xyz_euler(x, y, z, a, b, c)


def test_known_composition_by_hand():
    # table corner at machine (100, 50, -400), table turned +90° about Z
    T_machine_table = pose_from_xyz_euler(100, 50, -400, c_deg=90)
    # part lies 20 mm along table x, 10 mm along table y, on the top face, turned +30°
    T_table_obj = pose_from_xyz_euler(20, 10, 0, c_deg=30)
    # datum: top face of the 25 mm high part, 5 mm along the part's x
    T_obj_datum = pose_from_xyz_euler(5, 0, 25)
    r = work_offset_from_poses(T_machine_table, T_table_obj, T_obj_datum, max_tilt_deg=0.1)
    assert r.ok and r.reason == ""
    # by hand: table x -> machine +Y, table y -> machine -X; part rotated 90+30 = 120° in machine
    ang = np.radians(120)
    expect_x = 100 - 10 + 5 * np.cos(ang)
    expect_y = 50 + 20 + 5 * np.sin(ang)
    assert r.x_mm == pytest.approx(expect_x, abs=1e-9)
    assert r.y_mm == pytest.approx(expect_y, abs=1e-9)
    assert r.z_mm == pytest.approx(-375, abs=1e-9)
    assert r.c_deg == pytest.approx(120, abs=1e-9)
    assert r.a_deg == pytest.approx(0, abs=1e-9) and r.b_deg == pytest.approx(0, abs=1e-9)
    # a program point in the datum frame lands where the composed poses put it
    p_datum = np.array([[12.0, -7.0, 3.0]])
    T_written = pose_from_xyz_euler(r.x_mm, r.y_mm, r.z_mm, c_deg=r.c_deg)
    p_chain = transform_points(T_machine_table, transform_points(T_table_obj, transform_points(T_obj_datum, p_datum)))
    assert np.allclose(transform_points(T_written, p_datum), p_chain, atol=1e-9)


def test_random_round_trips_recover_offset_and_tilt():
    rng = np.random.default_rng(0)
    for _ in range(200):
        x, y, z = rng.uniform(-800, 800, 3)
        c = rng.uniform(-179.9, 179.9)
        a, b = rng.uniform(-0.5, 0.5, 2)
        T_target = pose_from_xyz_euler(x, y, z, a, b, c)
        T_machine_table = _random_pose(rng)
        T_table_obj = _random_pose(rng)
        T_obj_datum = inv(T_machine_table @ T_table_obj) @ T_target
        r = work_offset_from_poses(T_machine_table, T_table_obj, T_obj_datum, max_tilt_deg=1.0)
        assert r.ok, r.reason
        assert (r.x_mm, r.y_mm, r.z_mm) == pytest.approx((x, y, z), abs=1e-8)
        assert r.c_deg == pytest.approx(c, abs=1e-8)
        assert (r.a_deg, r.b_deg) == pytest.approx((a, b), abs=1e-8)
        assert np.allclose(r.T_machine_datum, T_target, atol=1e-9)


def test_c_is_independent_of_how_the_chain_is_split():
    rng = np.random.default_rng(1)
    T_target = pose_from_xyz_euler(10, 20, 30, 0.0, 0.0, -135.0)
    for _ in range(20):
        M, P = _random_pose(rng), _random_pose(rng)
        r = work_offset_from_poses(M, P, inv(M @ P) @ T_target, max_tilt_deg=0.0 + 1e-6)
        assert r.c_deg == pytest.approx(-135.0, abs=1e-8)


def test_tilt_beyond_tolerance_is_refused_with_the_reason():
    T = pose_from_xyz_euler(1, 2, 3, a_deg=0.3, b_deg=-0.4, c_deg=10)
    r = work_offset_from_poses(np.eye(4), T, np.eye(4), max_tilt_deg=0.2)
    assert not r and not r.ok
    assert r.tilt_deg == pytest.approx(0.5, abs=1e-3)  # sqrt(0.3² + 0.4²) for small angles
    assert "residual tilt 0.500°" in r.reason and "exceeds the allowed 0.200°" in r.reason
    assert "A +0.300°" in r.reason and "B -0.400°" in r.reason
    # the numbers stay available for display
    assert r.c_deg == pytest.approx(10, abs=1e-6)
    # the same pose passes a looser tolerance
    assert work_offset_from_poses(np.eye(4), T, np.eye(4), max_tilt_deg=0.6).ok


def test_upside_down_part_is_refused():
    flipped = make_pose(np.diag([1.0, -1.0, -1.0]), [0, 0, 50])
    r = work_offset_from_poses(np.eye(4), flipped, np.eye(4), max_tilt_deg=1.0)
    assert not r.ok and r.tilt_deg == pytest.approx(180.0)


def test_bad_inputs_raise():
    with pytest.raises(PoseError, match="T_table_obj"):
        work_offset_from_poses(np.eye(4), np.ones((4, 4)), np.eye(4), max_tilt_deg=1)
    with pytest.raises(ValueError, match="max_tilt_deg"):
        work_offset_from_poses(np.eye(4), np.eye(4), np.eye(4), max_tilt_deg=-1)


def test_sheet_work_offset_turns_the_bed_origin_into_machine_x_y_c():
    from app.geometry.work_offset import sheet_work_offset

    # bed corner at machine (100, 50, -20), bed turned +90° about Z; sheet origin 30 mm along bed x,
    # 10 mm along bed y, turned +15°, 3 mm thick
    x, y, c = sheet_work_offset(pose_from_xyz_euler(100, 50, -20, c_deg=90), 30, 10, 15, 3)
    assert np.allclose([x, y, c], [100 - 10, 50 + 30, 105])
