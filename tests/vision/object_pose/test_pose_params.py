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
