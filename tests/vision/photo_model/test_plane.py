"""The table plane (app/vision/photo_model/plane.py): the plane's homography, rectification with and
without lens distortion."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.vision import photo_model as pm
from tests.vision.photo_model.drawn import CAM_A, DIST, H, K, W


def test_plane_homography_is_the_projection_of_the_plane() -> None:
    grid = pm.PlaneGrid(100.0, 50.0, 0.5, 200, 100, 25.0)
    uv = np.array([[0.0, 0.0], [199.0, 0.0], [37.5, 81.25]])
    p = pm.plane_homography(K, CAM_A, grid) @ np.vstack([uv.T, np.ones(3)])
    xy = grid.to_mm(uv)
    P = (CAM_A @ np.vstack([xy.T, np.full(3, 25.0), np.ones(3)]))[:3]
    np.testing.assert_allclose((p[:2] / p[2]).T, (K @ P)[:2].T / P[2][:, None], atol=1e-9)


@pytest.mark.parametrize("dist", [None, DIST])
def test_rectify_puts_table_points_on_their_grid_pixel(dist) -> None:
    """A dot drawn where the camera sees table point (x, y, z) is found at that point's grid pixel,
    with and without lens distortion (warpPerspective and remap paths)."""
    img = np.zeros((H, W), np.uint8)
    pts = np.array([[300.0, 150.0], [420.5, 230.25], [510.0, 180.0]])
    from app.geometry.model_edges import project_points_px
    from app.geometry.transforms import transform_points
    uv = project_points_px(transform_points(CAM_A, np.column_stack([pts, np.full(3, 7.0)])), K,
                           np.zeros(5) if dist is None else dist)
    for u, v in uv:
        cv2.circle(img, (round(u * 16), round(v * 16)), 3 * 16, 255, -1, lineType=cv2.LINE_AA, shift=4)
    grid = pm.PlaneGrid.around(250, 560, 100, 280, 0.25, 7.0)
    rect, valid, _ = pm.rectify(img, K, dist, CAM_A, grid)
    assert valid.min() == 255
    for p in pts:
        c = np.rint(grid.to_px(p[None])[0]).astype(int)
        win = rect[c[1] - 20:c[1] + 21, c[0] - 20:c[0] + 21].astype(float)
        vv, uu = np.mgrid[-20:21, -20:21]
        centre = np.array([(win * uu).sum(), (win * vv).sum()]) / win.sum() * grid.mm_per_px
        assert np.hypot(*(centre + (c - grid.to_px(p[None])[0]) * grid.mm_per_px)) < 0.05
