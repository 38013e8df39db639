"""The table's tilt and height re-read from a fixture standing on it (app.vision.table_levelling)."""

from __future__ import annotations

import numpy as np
import trimesh

from app.geometry.transforms import inv, make_pose, transform_points
from app.vision.object_pose.uncertainty import table_error, table_plane_sigma
from app.vision.table_levelling import (
    GATE_CHI2,
    HEIGHT_STEP_MM,
    MAX_HEIGHTS,
    Stance,
    level_table,
    search_heights,
    stance,
    standing_base,
)

CENTROID = np.array([400.0, 100.0, 0.0])
# a table seen through two markers along x: its turn about x is open (0.3 deg), the rest well fixed
S_TWO = np.diag(np.r_[np.radians([0.3, 0.03, 0.02]) ** 2, [0.05 ** 2, 0.05 ** 2, 0.1 ** 2]])


def _true_cam_table() -> np.ndarray:
    return make_pose(np.eye(3), [-400.0, -100.0, 900.0])


def _tilt_and_height(T_cam_located: np.ndarray, T_cam_true: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The true top seen in the located frame: its tilt about x and y (deg) and its height at ``at``."""
    T = inv(T_cam_located) @ T_cam_true
    u = T[:3, 2]
    z = T[2, 3] - (u[0] * (at[0] - T[0, 3]) + u[1] * (at[1] - T[1, 3])) / u[2]
    return np.array([np.degrees(-u[1]), np.degrees(u[0]), z])


def test_the_table_plane_sigma_grows_with_the_lever_from_the_markers():
    sh0, st = table_plane_sigma((S_TWO, CENTROID), CENTROID)
    assert np.isclose(sh0, 0.1) and np.isclose(np.degrees(st), 0.3)
    sh, _ = table_plane_sigma((S_TWO, CENTROID), CENTROID + [0.0, 200.0, 0.0])   # 200 mm across the open axis
    assert np.isclose(sh, np.hypot(0.1, 200.0 * np.radians(0.3)), rtol=1e-6)
    sh, _ = table_plane_sigma((S_TWO, CENTROID), CENTROID + [200.0, 0.0, 0.0])   # along it: the fixed turn
    assert np.isclose(sh, np.hypot(0.1, 200.0 * np.radians(0.03)), rtol=1e-6)
    assert table_plane_sigma((np.full((6, 6), np.inf), CENTROID), CENTROID)[0] == np.inf


def test_search_heights_cover_the_tables_height_error_in_steps_capped():
    assert search_heights((np.zeros((6, 6)), CENTROID), [(0, 0), (800, 400)]) == (0.0,)
    h = search_heights((S_TWO, CENTROID), [(0, 0), (0, 400), (800, 0), (800, 400)])
    assert h[0] == 0.0 and len(h) == MAX_HEIGHTS and np.allclose(np.diff(sorted(h)), HEIGHT_STEP_MM)
    small = np.diag([1e-8, 1e-8, 1e-8, 0.01, 0.01, 0.3 ** 2])           # 0.3 mm: 3 sigma is 0.9 mm
    assert sorted(search_heights((small, CENTROID), [(400, 100)])) == [-1.4, -0.7, 0.0, 0.7, 1.4]


def test_a_box_stands_on_the_middle_of_its_base():
    box = trimesh.creation.box(extents=(200.0, 80.0, 60.0))
    T_rest_obj = make_pose(np.eye(3), [0.0, 0.0, 30.0])                  # standing as modelled
    up, base = standing_base(T_rest_obj, np.asarray(box.vertices))
    assert np.allclose(up, [0, 0, 1]) and np.allclose(base, [0, 0, -30.0])
    on_side = make_pose(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])[:3, :3], [0, 0, 40.0])
    up, base = standing_base(on_side, np.asarray(box.vertices))
    assert np.allclose(up, [0, 1, 0], atol=1e-9) and np.allclose(base, [0, -40.0, 0], atol=1e-9)


def _reading(T_cam_located, T_cam_true, at, sd_deg=0.02, sd_mm=0.05):
    """A fixture standing flat on the true table at ``at``, read exactly in the located frame."""
    T_true_fix = make_pose(np.eye(3), at)
    T_loc_fix = inv(T_cam_located) @ T_cam_true @ T_true_fix
    cov = np.diag([0.01, 0.01, sd_mm ** 2, *(np.radians([sd_deg, sd_deg, 0.02]) ** 2)])
    return stance(T_loc_fix, cov, [0, 0, 1], [0, 0, 0])


def test_a_vise_that_stands_flat_levels_a_table_tilted_about_its_open_axis():
    """Two markers tilt the located table 0.4 deg about x (and 0.1 mm): a vise 200 mm away reads that
    tilt and about 1.5 mm of height under it; the levelled frame is within a few hundredths of the truth and
    its tilt sigma is the vise's, not the markers'."""
    T_true = _true_cam_table()
    e = np.r_[np.radians([0.4, 0.01, 0.0]), [0.0, 0.0, 0.1]]
    T_loc = T_true @ table_error(e, CENTROID)
    at = CENTROID + [50.0, 200.0, 0.0]
    before = _tilt_and_height(T_loc, T_true, at)
    assert abs(before[0]) > 0.35 and abs(before[2]) > 1.0
    st = _reading(T_loc, T_true, at)
    assert np.allclose(np.degrees(st.m[:2]), before[:2], atol=1e-3) and np.isclose(st.m[2], before[2], atol=1e-3)
    lev = level_table(T_loc, S_TWO, CENTROID, st)
    after = _tilt_and_height(lev.T_cam_table, T_true, at)
    assert np.all(np.abs(after[:2]) < 0.03) and abs(after[2]) < 0.1, after
    assert np.allclose(lev.correction, before, atol=0.06)
    sd = np.sqrt(np.diag(lev.covariance))
    assert np.degrees(sd[0]) < 0.06 and np.all(sd <= np.sqrt(np.diag(S_TWO)) + 1e-12)
    assert lev.chi2 < 9.0
    # the points the markers fix stay where they were (the levelling turns about the open axis)
    np.testing.assert_allclose(transform_points(inv(T_true) @ lev.T_cam_table, CENTROID[None])[0],
                               transform_points(inv(T_true) @ T_loc, CENTROID[None])[0], atol=0.35)


def test_a_stance_far_beyond_both_sigmas_is_gated():
    """A fixture read 3 deg off flat where the table allows 0.3 and the fixture 0.05: not a table error."""
    st = Stance(m=np.array([np.radians(3.0), 0.0, 0.0]), C=np.diag([np.radians(0.05) ** 2] * 2 + [0.05 ** 2]),
                at=CENTROID + [0.0, 200.0, 0.0])
    assert level_table(np.eye(4), S_TWO, CENTROID, st).chi2 > GATE_CHI2


def test_a_table_that_is_right_stays_where_it_is():
    T_true = _true_cam_table()
    at = CENTROID + [-150.0, 120.0, 0.0]
    lev = level_table(T_true, S_TWO, CENTROID, _reading(T_true, T_true, at))
    np.testing.assert_allclose(lev.T_cam_table, T_true, atol=1e-9)
    assert lev.chi2 < 1e-12
