"""One camera model: project_points_px against cv2.projectPoints for every coefficient count."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.geometry.model_edges import project_points_px

K = np.array([[1400.0, 0.0, 955.0], [0.0, 1395.0, 610.0], [0.0, 0.0, 1.0]])
FULL = np.array([-0.21, 0.09, 8e-4, -6e-4, -0.015, 0.02, -0.01, 0.004, 1e-3, -5e-4, 7e-4, -2e-4, 0.01, -0.008])


@pytest.mark.parametrize("n", [4, 5, 8, 12, 14])
def test_projection_matches_opencv(n):
    rng = np.random.default_rng(n)
    P = np.column_stack([rng.uniform(-400, 400, 500), rng.uniform(-250, 250, 500), rng.uniform(500, 1500, 500)])
    d = FULL[:n].copy()
    ref = cv2.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, d)[0].reshape(-1, 2)
    np.testing.assert_allclose(project_points_px(P, K, d), ref, atol=1e-6)


def test_points_behind_the_camera_are_nan_and_bad_lengths_are_refused():
    uv = project_points_px(np.array([[0.0, 0.0, -5.0], [10.0, 0.0, 500.0]]), K, FULL[:5])
    assert np.isnan(uv[0]).all() and np.isfinite(uv[1]).all()
    with pytest.raises(ValueError, match="4, 5, 8, 12 or 14"):
        project_points_px(np.ones((1, 3)), K, np.zeros(6))
