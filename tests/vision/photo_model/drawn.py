"""Pictures of a notched plate drawn directly through the plane homographies (a textured table at z = 0,
the object's top face at z = h) for the photo model's tests, so every number has an exact truth and the
tests stay fast; the rendered scenes with the T-slot table, shadows and side walls are in
benchmarks/photo_model.py, test_sigma_coverage.py and the API test.
"""

from __future__ import annotations

import cv2
import numpy as np

from app.geometry.transforms import make_pose
from app.synth.scene import look_at_pose
from app.vision import photo_model as pm

W, H = 1280, 800
K = np.array([[1400.0, 0, 640], [0, 1400.0, 400], [0, 0, 1]])
HEIGHT = 12.0


def plate_top(holes=((30.0, 25.0, 8.0), (110.0, 25.0, 8.0))) -> tuple[np.ndarray, list]:
    """Outline (mm, plate frame: front-left corner at 0) of a notched 140 x 90 plate and its holes."""
    outline = np.array([[0, 0], [140, 0], [140, 65], [115, 90], [0, 90]], float)
    return outline, list(holes)


def draw(T_cam_table: np.ndarray, T_table_plate: np.ndarray, holes, dist=None, seed: int = 0) -> np.ndarray:
    """A grey picture: a streaked table (z = 0) and the plate's top face (z = HEIGHT) with dark holes."""
    rng = np.random.default_rng(seed)
    dist = np.zeros(5) if dist is None else dist
    # the table: a top view at 0.5 mm/px, machining streaks along x
    gt = pm.PlaneGrid(0.0, 0.0, 0.5, 1600, 800, 0.0)
    tex = (110 + 5 * np.sin(np.arange(gt.height)[:, None] / 3.0) + rng.normal(0, 4, (gt.height, gt.width)))
    tex = cv2.GaussianBlur(tex.astype(np.float32), (0, 0), 0.8)
    # the plate's top at 0.1 mm/px in its own frame
    gp = pm.PlaneGrid(-5.0, -5.0, 0.1, 1500, 1000, HEIGHT)
    top = np.zeros((gp.height, gp.width), np.float32)
    outline, _ = plate_top()
    cv2.fillPoly(top, [np.rint(gp.to_px(outline) * 16).astype(np.int32)], 1.0, lineType=cv2.LINE_AA, shift=4)
    for x, y, r in holes:
        cv2.circle(top, tuple(np.rint(gp.to_px([[x, y]])[0] * 16).astype(int)), int(r / gp.mm_per_px * 16), 0.35,
                   -1, lineType=cv2.LINE_AA, shift=4)
    img = _warp(tex, gt, T_cam_table, dist)
    T_cam_plate = T_cam_table @ T_table_plate
    alpha = _warp(np.where(top > 0, 1.0, 0.0).astype(np.float32) * np.minimum(top * 4, 1), gp, T_cam_plate, dist)
    shade = _warp(top, gp, T_cam_plate, dist)
    out = img * (1 - alpha) + alpha * (60 + 130 * shade)
    out += rng.normal(0, 1.5, out.shape)
    return np.clip(cv2.GaussianBlur(out.astype(np.float32), (0, 0), 0.7), 0, 255).astype(np.uint8)


def _warp(src: np.ndarray, grid: pm.PlaneGrid, T_cam_plane: np.ndarray, dist) -> np.ndarray:
    """Draw a top view (on its grid, in the frame of ``T_cam_plane``) into the camera picture."""
    Hm = pm.plane_homography(K, T_cam_plane, grid)
    if not np.any(dist):
        return cv2.warpPerspective(src, Hm, (W, H), flags=cv2.INTER_LINEAR)
    # distorted: for each camera pixel, its ideal pixel, then the grid pixel through the inverse homography
    uu, vv = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32))
    pts = cv2.undistortPoints(np.stack([uu.ravel(), vv.ravel()], 1)[:, None, :], K, dist, P=K)[:, 0, :]
    g = np.linalg.inv(Hm) @ np.vstack([pts.T, np.ones(len(pts))])
    mx = (g[0] / g[2]).reshape(H, W).astype(np.float32)
    my = (g[1] / g[2]).reshape(H, W).astype(np.float32)
    return cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderValue=0)


def rot_z(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def placed(x: float, y: float, c_deg: float) -> np.ndarray:
    """T_table_plate with the plate's middle (70, 45) at (x, y), turned c_deg."""
    R = rot_z(c_deg)
    return make_pose(R, np.array([x, y, 0.0]) - R @ np.array([70.0, 45.0, 0.0]))


CAM_A = look_at_pose(np.array([400.0, -350.0, 600.0]), np.array([400.0, 200.0, 0.0]))
CAM_B = look_at_pose(np.array([150.0, -250.0, 650.0]), np.array([350.0, 180.0, 0.0]), roll_deg=4.0)
DIST = np.array([-0.08, 0.04, 2e-4, -1e-4, 0.0])
