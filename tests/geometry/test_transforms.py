import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.geometry.transforms import (
    PoseError, check_pose, inv, make_pose, pose_from_xyz_euler, pose_to_rvec_tvec,
    rotation_angle_deg, rvec_tvec_to_pose, tilt_deg, transform_points, xyz_euler_from_pose,
)


def random_pose(rng):
    return make_pose(Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(), rng.normal(0, 300, 3))


def test_inverse_and_composition_axioms():
    rng = np.random.default_rng(0)
    for _ in range(50):
        A, B, C = random_pose(rng), random_pose(rng), random_pose(rng)
        assert np.allclose(inv(A) @ A, np.eye(4), atol=1e-9)
        assert np.allclose((A @ B) @ C, A @ (B @ C), atol=1e-6)
        assert np.allclose(inv(A @ B), inv(B) @ inv(A), atol=1e-9)
        p = rng.normal(0, 100, (5, 3))
        assert np.allclose(transform_points(inv(A), transform_points(A, p)), p, atol=1e-9)


def test_core_relation_is_independent_of_camera_pose():
    rng = np.random.default_rng(1)
    T_table_obj = pose_from_xyz_euler(120, 80, 15, 0, 0, 23)
    T_world_table = random_pose(rng)
    for _ in range(5):
        T_world_cam = random_pose(rng)
        T_cam_table = inv(T_world_cam) @ T_world_table
        T_cam_obj = T_cam_table @ T_table_obj
        assert np.allclose(inv(T_cam_table) @ T_cam_obj, T_table_obj, atol=1e-9)


def test_euler_round_trip_and_tilt():
    T = pose_from_xyz_euler(1, 2, 3, 0.5, -0.25, 30)
    assert np.allclose(xyz_euler_from_pose(T), (1, 2, 3, 0.5, -0.25, 30), atol=1e-9)
    assert tilt_deg(pose_from_xyz_euler(c_deg=70)) == pytest.approx(0, abs=1e-6)
    assert tilt_deg(pose_from_xyz_euler(a_deg=0.8)) == pytest.approx(0.8, abs=1e-9)
    assert rotation_angle_deg(pose_from_xyz_euler(c_deg=10), pose_from_xyz_euler(c_deg=-5)) == pytest.approx(15)


def test_rvec_round_trip():
    T = pose_from_xyz_euler(10, -20, 500, 10, 20, 30)
    r, t = pose_to_rvec_tvec(T)
    assert np.allclose(rvec_tvec_to_pose(r, t), T)


@pytest.mark.parametrize(
    "bad, match",
    [
        (np.eye(3), r"expected shape \(4, 4\), got \(3, 3\)"),
        ([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1]], "last row"),
        (make_pose(np.diag([1, 1, 1.03])), "not orthonormal"),
        (make_pose(np.diag([1, 1, -1])), "reflection"),
        (np.full((4, 4), np.nan), "NaN"),
        ("abc", "not a numeric"),
    ],
)
def test_check_pose_says_what_is_wrong(bad, match):
    with pytest.raises(PoseError, match=match):
        check_pose(bad, "T_table_marker of marker 7")
