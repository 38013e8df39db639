"""How the fits move a pose (app.vision.object_pose.pose_params)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from app.geometry.transforms import make_pose
from app.vision.object_pose.pose_params import flat_at, rotvec_matrix


def test_rotvec_matrix_is_scipys_rotation_bit_for_bit():
    rng = np.random.default_rng(5)
    for scale in (0.0, 1e-12, 1e-5, 1e-3, 0.1, 1.0, 3.0):      # the small-angle series and beyond
        for v in rng.normal(size=(300, 3)) * scale:
            assert np.array_equal(rotvec_matrix(v), Rotation.from_rotvec(v).as_matrix())
    assert np.array_equal(rotvec_matrix(np.array([0, 0, 1])), Rotation.from_rotvec([0, 0, 1.0]).as_matrix())


def test_the_point_jacobian_is_the_derivative_of_perturb():
    """``perturb_point_jacobian`` against central differences of :func:`perturb` (translation mm,
    rotation vector rad; at 0, at a degree and a few millimetres, and at 1e-7 rad, where the left
    Jacobian is taken from its series), and ``left_jacobian`` as SciPy composes rotations."""
    from app.geometry.transforms import transform_points
    from app.vision.object_pose.pose_params import left_jacobian, perturb, perturb_point_jacobian

    rng = np.random.default_rng(3)
    T0 = np.eye(4)
    T0[:3, :3] = Rotation.from_rotvec([0.2, -0.1, 1.0]).as_matrix()
    T0[:3, 3] = [300.0, 150.0, 20.0]
    X = rng.normal(0.0, 60.0, (30, 3))
    c = np.array([310.0, 140.0, 35.0])
    for p in (np.zeros(6), np.array([2.0, -1.0, 0.5, 0.01, -0.015, 0.02]), np.array([0, 0, 0, 1e-7, -2e-7, 0])):
        J = perturb_point_jacobian(transform_points(T0, X), c, p)
        num = np.zeros_like(J)
        for k in range(6):
            h = 1e-4 if k < 3 else 1e-7
            dp = np.zeros(6)
            dp[k] = h
            num[:, :, k] = (transform_points(perturb(T0, c, p + dp), X)
                            - transform_points(perturb(T0, c, p - dp), X)) / (2 * h)
        np.testing.assert_allclose(J, num, atol=1e-5 * np.abs(num).max())
    w, dw = np.array([0.3, -0.2, 0.5]), np.array([1e-6, 2e-6, -1e-6])
    R_next = Rotation.from_rotvec(left_jacobian(w) @ dw) * Rotation.from_rotvec(w)
    np.testing.assert_allclose(R_next.as_matrix(), Rotation.from_rotvec(w + dw).as_matrix(), atol=1e-11)


def test_flat_at_moves_a_flat_pose_to_where_a_6dof_fit_put_the_part():
    """A flat start 6 mm off and turned 2 deg from a slightly tilted 6-DoF pose, 5 mm lower: moved and
    turned in the table plane, its height and stance kept, its centre over the 6-DoF pose's."""
    stance = Rotation.from_euler("x", 90, degrees=True).as_matrix()        # lying on its side
    c = np.array([10.0, -4.0, 7.0])
    T_flat = make_pose(Rotation.from_euler("z", 30, degrees=True).as_matrix() @ stance, [100.0, 50.0, 25.0])
    R6 = (Rotation.from_euler("xyz", [0.3, -0.2, 32.0], degrees=True).as_matrix() @ stance)
    T6 = make_pose(R6, [103.0, 55.0, 20.5])
    T = flat_at(T_flat, T6, c)
    np.testing.assert_allclose((T[:3, :3] @ c + T[:3, 3])[:2], (T6[:3, :3] @ c + T6[:3, 3])[:2], atol=1e-9)
    assert T[2, 3] == T_flat[2, 3]
    # still flat in its stance: only turned about the table normal, by the 6-DoF pose's 2 deg
    turn = Rotation.from_matrix(T[:3, :3] @ T_flat[:3, :3].T).as_rotvec()
    np.testing.assert_allclose(turn[:2], 0.0, atol=1e-12)
    assert abs(np.degrees(turn[2]) - 2.0) < 0.02
