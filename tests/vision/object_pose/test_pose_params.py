"""How the fits move a pose (app.vision.object_pose.pose_params)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from app.vision.object_pose.pose_params import rotvec_matrix


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
