"""The rotary table's chain: T_machine_table(angle) = T_machine_axis @ R(angle) @ T_axis_table for A, B and C."""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.rotary_chain import RotaryChain, angle_of_turn, axis_rotation
from app.geometry.transforms import (
    PoseError,
    inv,
    pose_from_xyz_euler,
    transform_points,
)
from app.geometry.work_offset import work_offset_from_poses


def _random_pose(rng, span_mm=400.0):
    return pose_from_xyz_euler(*rng.uniform(-span_mm, span_mm, 3), *rng.uniform(-180, 180, 3))


@pytest.mark.parametrize("name,euler", [("A", (1, 0, 0)), ("B", (0, 1, 0)), ("C", (0, 0, 1))])
def test_axis_rotation_is_the_right_handed_turn_about_x_y_z(name, euler):
    for deg in (-137.0, -30.0, 0.0, 37.0, 90.0, 180.0):
        expect = pose_from_xyz_euler(0, 0, 0, *(deg * e for e in euler))
        assert np.allclose(axis_rotation(name, deg), expect, atol=1e-12)


def test_c_by_hand_a_point_on_a_table_centred_on_the_axis():
    # axis at machine (100, 50, -300), z up; the table corner 200 mm before and 150 mm left of the axis
    chain = RotaryChain("C", pose_from_xyz_euler(100, 50, -300), pose_from_xyz_euler(-200, -150, 0))
    corner_0 = transform_points(chain.T_machine_table(0.0), [(0, 0, 0)])[0]
    assert np.allclose(corner_0, (-100, -100, -300))
    # +90°: the corner (-200, -150) relative to the axis turns to (150, -200)
    corner_90 = transform_points(chain.T_machine_table(90.0), [(0, 0, 0)])[0]
    assert np.allclose(corner_90, (250, -150, -300))
    # a point on the axis does not move
    centre = (200, 150, 0)  # table frame
    for deg in (0.0, 37.0, -120.0):
        assert np.allclose(transform_points(chain.T_machine_table(deg), [centre])[0], (100, 50, -300))


def test_a_trunnion_turns_about_machine_x_and_b_about_y():
    a = RotaryChain("A", pose_from_xyz_euler(0, 0, -200), pose_from_xyz_euler(-50, -40, 80))
    p = transform_points(a.T_machine_table(90.0), [(50, 40, 0)])[0]  # the point above the axis at 80 mm
    assert np.allclose(p, (0, -80, -200))     # +A turns +Z towards -Y
    b = RotaryChain("B", pose_from_xyz_euler(0, 0, -200), pose_from_xyz_euler(-50, -40, 80))
    p = transform_points(b.T_machine_table(90.0), [(50, 40, 0)])[0]
    assert np.allclose(p, (80, 0, -200))      # +B turns +Z towards +X
    assert np.allclose(a.axis_direction(), (1, 0, 0)) and np.allclose(b.axis_direction(), (0, 1, 0))


def test_a_reversed_axis_frame_turns_the_table_the_other_way():
    up = RotaryChain("C", np.eye(4), pose_from_xyz_euler(10, 0, 0))
    down = RotaryChain("C", pose_from_xyz_euler(0, 0, 0, 180, 0, 0), pose_from_xyz_euler(10, 0, 0, 180, 0, 0))
    assert np.allclose(up.T_machine_table(0), down.T_machine_table(0))
    assert np.allclose(up.T_machine_table(30), down.T_machine_table(-30))


@pytest.mark.parametrize("name", ["A", "B", "C"])
def test_round_trips_composition_and_the_angle_back(name):
    rng = np.random.default_rng(16)
    for _ in range(50):
        chain = RotaryChain(name, _random_pose(rng), _random_pose(rng))
        a, b = rng.uniform(-180, 180, 2)
        # composition: turning by a then by b is turning by a + b
        Ta, Tab = chain.T_machine_table(a), chain.T_machine_table(a + b)
        expect = chain.T_machine_axis @ axis_rotation(name, b) @ inv(chain.T_machine_axis) @ Ta
        assert np.allclose(Tab, expect, atol=1e-9)
        # the turn between two angles in the table's own frame, and the angle recovered from two poses
        assert np.allclose(chain.T_machine_table(a) @ chain.turn(a, b), chain.T_machine_table(b), atol=1e-9)
        d = angle_of_turn(chain, Ta, chain.T_machine_table(b))
        assert np.isclose((d - (b - a) + 180) % 360 - 180, 0.0, atol=1e-7)
        # every point on the axis stays where it is
        p_table = transform_points(inv(Ta), [chain.axis_point() + 123.0 * chain.axis_direction()])
        assert np.allclose(transform_points(chain.T_machine_table(b), p_table), transform_points(Ta, p_table))


def test_angle_of_turn_refuses_poses_that_no_turn_of_the_axis_joins():
    chain = RotaryChain("C", np.eye(4), np.eye(4))
    with pytest.raises(ValueError, match="C axis"):
        angle_of_turn(chain, np.eye(4), pose_from_xyz_euler(1, 0, 0))


def test_offset_at_the_export_angle_does_not_depend_on_the_picture_angle():
    """The part is located in the turning table's frame: the offset the NC program expects at C = 0 is
    the chain at 0, whatever the angle the picture was taken at; at the picture's angle the datum sits
    turned about the axis by exactly that angle."""
    chain = RotaryChain("C", pose_from_xyz_euler(20, -30, -350, c_deg=0.4), pose_from_xyz_euler(-400, -200, 0))
    T_table_obj, T_obj_datum = pose_from_xyz_euler(330, 120, 0, c_deg=20), pose_from_xyz_euler(0, 0, 35)
    at0 = work_offset_from_poses(chain.T_machine_table(0), T_table_obj, T_obj_datum, max_tilt_deg=0.1)
    at37 = work_offset_from_poses(chain.T_machine_table(37), T_table_obj, T_obj_datum, max_tilt_deg=0.1)
    assert at0.c_deg == pytest.approx(20.4) and at37.c_deg == pytest.approx(57.4)
    p0 = np.array([at0.x_mm, at0.y_mm]) - chain.axis_point()[:2]
    p37 = np.array([at37.x_mm, at37.y_mm]) - chain.axis_point()[:2]
    r = np.radians(37.0)
    assert np.allclose([[np.cos(r), -np.sin(r)], [np.sin(r), np.cos(r)]] @ p0, p37)
    assert at0.z_mm == pytest.approx(at37.z_mm)


def test_bad_chains_are_refused_with_the_reason():
    with pytest.raises(ValueError, match="one of A, B, C"):
        RotaryChain("D", np.eye(4), np.eye(4))
    with pytest.raises(PoseError, match="T_machine_axis: rotation not orthonormal"):
        RotaryChain("C", np.diag([2.0, 1, 1, 1]), np.eye(4))
    with pytest.raises(PoseError, match="T_axis_table: expected shape"):
        RotaryChain("C", np.eye(4), np.eye(3))
