"""The table plane seen in a picture: a square mm grid on the plane ``z`` of the table frame, the
plane's homography and the rectification of a picture onto it.

With the table located by its markers (``T_cam_table``), the plane ``z = h`` of the table frame is
seen through ``K [r1 r2 (h r3 + t)]`` (:func:`plane_homography`); composed with a :class:`PlaneGrid`
and the lens model, one rectified pixel is a fixed square of that plane in millimetres
(:func:`rectify`). Seen so, an object's top face at ``z = h`` keeps its true shape and size from any
camera pose. Frames and units: docs/design.md (``T_a_b``, mm).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from app.geometry.model_edges import project_points_px
from app.geometry.transforms import transform_points

FINE_MM_PER_PX = 0.25       # rectification of teaching and of the final fit


@dataclass(frozen=True)
class PlaneGrid:
    """A square pixel grid on the table plane ``z = z_mm`` (table frame): pixel (u, v) is table point
    ``(x0_mm + u * mm_per_px, y0_mm + v * mm_per_px, z_mm)`` (u along table x, v along table y)."""

    x0_mm: float
    y0_mm: float
    mm_per_px: float
    width: int
    height: int
    z_mm: float = 0.0

    @staticmethod
    def around(x_lo: float, x_hi: float, y_lo: float, y_hi: float, mm_per_px: float, z_mm: float) -> PlaneGrid:
        """The grid covering the box [x_lo, x_hi] x [y_lo, y_hi] (mm) at ``mm_per_px``."""
        w = int(np.ceil((x_hi - x_lo) / mm_per_px)) + 1
        h = int(np.ceil((y_hi - y_lo) / mm_per_px)) + 1
        return PlaneGrid(float(x_lo), float(y_lo), float(mm_per_px), max(w, 2), max(h, 2), float(z_mm))

    def to_mm(self, uv: np.ndarray) -> np.ndarray:
        """Grid pixels (N, 2) -> table x, y (N, 2), mm."""
        return np.asarray(uv, float) * self.mm_per_px + [self.x0_mm, self.y0_mm]

    def to_px(self, xy: np.ndarray) -> np.ndarray:
        """Table x, y (N, 2), mm -> grid pixels (N, 2)."""
        return (np.asarray(xy, float) - [self.x0_mm, self.y0_mm]) / self.mm_per_px

    def pixels(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Table x, y (N, 2), mm -> the nearest grid pixels (N, 2) int, and which of them are on the grid."""
        ij = np.rint(self.to_px(xy)).astype(int)
        return ij, (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < self.width) & (ij[:, 1] < self.height)

    def to_dict(self) -> dict:
        return {"x0_mm": self.x0_mm, "y0_mm": self.y0_mm, "mm_per_px": self.mm_per_px, "width": self.width,
                "height": self.height, "z_mm": self.z_mm}


def plane_homography(K: np.ndarray, T_cam_table: np.ndarray, grid: PlaneGrid) -> np.ndarray:
    """3x3 homography from grid pixels (u, v, 1) to ideal (undistorted) image pixels: the plane
    ``z = grid.z_mm`` of the table seen by the camera, ``K [r1 r2 (z r3 + t)] A`` with ``A`` the grid."""
    T = np.asarray(T_cam_table, float)
    H_plane = np.asarray(K, float) @ np.column_stack([T[:3, 0], T[:3, 1], grid.z_mm * T[:3, 2] + T[:3, 3]])
    A = np.array([[grid.mm_per_px, 0, grid.x0_mm], [0, grid.mm_per_px, grid.y0_mm], [0, 0, 1.0]])
    return H_plane @ A


def _maps(K, dist, T_cam_table, grid: PlaneGrid) -> tuple[np.ndarray, np.ndarray]:
    """Where each grid pixel is in the (distorted) camera image: float32 maps for :func:`cv2.remap`."""
    uu, vv = np.meshgrid(np.arange(grid.width, dtype=float), np.arange(grid.height, dtype=float))
    xy = grid.to_mm(np.stack([uu.ravel(), vv.ravel()], axis=1))
    P = transform_points(np.asarray(T_cam_table, float), np.column_stack([xy, np.full(len(xy), grid.z_mm)]))
    uv = project_points_px(P, K, dist)
    uv = np.where(np.isfinite(uv), uv, -1e6)
    return (uv[:, 0].reshape(grid.height, grid.width).astype(np.float32),
            uv[:, 1].reshape(grid.height, grid.width).astype(np.float32))


def rectify(image: np.ndarray, K: np.ndarray, dist, T_cam_table: np.ndarray, grid: PlaneGrid,
            mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The picture seen on the table plane ``z = grid.z_mm``.

    image : (H, W) grey or (H, W, 3) BGR uint8 as taken (distorted); K (3, 3) px; dist OpenCV's
    mask : optional (H, W) uint8 camera-image mask carried along (nearest neighbour)
    Returns (rectified float32 grey, valid uint8 (255 where the grid point is inside the picture),
    rectified mask or None). Without lens distortion this is :func:`cv2.warpPerspective` through
    :func:`plane_homography`; with distortion the same homography is composed with the lens model
    into one :func:`cv2.remap` (one interpolation either way, bicubic)."""
    img = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    img = img.astype(np.float32)
    d = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    size = (grid.width, grid.height)
    ones = np.full(img.shape, 255, np.uint8)
    if not np.any(d):
        Hm = plane_homography(K, T_cam_table, grid)
        flags = cv2.WARP_INVERSE_MAP
        out = cv2.warpPerspective(img, Hm, size, flags=cv2.INTER_CUBIC | flags, borderMode=cv2.BORDER_REPLICATE)
        valid = cv2.warpPerspective(ones, Hm, size, flags=cv2.INTER_NEAREST | flags, borderValue=0)
        m = None if mask is None else cv2.warpPerspective(mask, Hm, size, flags=cv2.INTER_NEAREST | flags,
                                                          borderValue=0)
        return out, valid, m
    mx, my = _maps(K, d, T_cam_table, grid)
    out = cv2.remap(img, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    valid = cv2.remap(ones, mx, my, cv2.INTER_NEAREST, borderValue=0)
    m = None if mask is None else cv2.remap(mask, mx, my, cv2.INTER_NEAREST, borderValue=0)
    return out, valid, m


def camera_mm_per_px(K: np.ndarray, T_cam_table: np.ndarray, xy_mm: np.ndarray, z_mm: float) -> float:
    """Size (mm) on the plane ``z`` at table point ``xy_mm`` of one camera pixel (geometric mean)."""
    grid = PlaneGrid(float(xy_mm[0]), float(xy_mm[1]), 1.0, 2, 2, z_mm)
    Hm = plane_homography(K, T_cam_table, grid)
    p = Hm @ np.array([0.0, 0.0, 1.0])
    J = (Hm[:2, :2] * p[2] - np.outer(p[:2], Hm[2, :2])) / p[2] ** 2   # d(image px) / d(mm)
    return float(1.0 / np.sqrt(abs(np.linalg.det(J))))


def point_grid(P: np.ndarray, margin_mm: float, mm_per_px: float = 0.25) -> PlaneGrid:
    """A grid (at ``z = 0``) over the points ``P`` (N, 2), mm, with ``margin_mm`` on every side: where a
    template's points are drawn as an image."""
    lo = P.min(axis=0) - margin_mm
    return PlaneGrid(float(lo[0]), float(lo[1]), mm_per_px, int((P[:, 0].max() - lo[0] + margin_mm) / mm_per_px) + 1,
                     int((P[:, 1].max() - lo[1] + margin_mm) / mm_per_px) + 1)


def point_distance(grid: PlaneGrid, P: np.ndarray) -> np.ndarray:
    """Distance (grid px) of every grid pixel to the nearest of the points ``P`` (N, 2), mm (those off
    the grid left out)."""
    img = np.full((grid.height, grid.width), 255, np.uint8)
    ij, ok = grid.pixels(P)
    img[ij[ok, 1], ij[ok, 0]] = 0
    return cv2.distanceTransform(img, cv2.DIST_L2, 5)
