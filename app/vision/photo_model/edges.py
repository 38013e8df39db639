"""Edges of a rectified picture (:func:`app.vision.photo_model.plane.rectify`): Canny edges with
subpixel positions and directions in grid pixels, with the edges that known geometry (table edges,
marker labels) explains left out, and their distance map."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True, eq=False)
class PlaneEdges:
    """Edges of a rectified picture: subpixel positions (grid px), their gradient direction (rad) and
    strength, the Canny map, the smoothed gradient images and the valid area."""

    uv: np.ndarray
    angle: np.ndarray
    mag: np.ndarray
    canny: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    threshold: float
    valid: np.ndarray


def plane_edges(rect: np.ndarray, valid: np.ndarray, ignore: np.ndarray | None = None,
                smooth_px: float = 1.0) -> PlaneEdges:
    """Canny edges of a rectified picture with subpixel positions (parabola through the gradient
    magnitude across the edge). Thresholds follow the image noise (MAD), as the engine's
    :func:`~app.vision.object_pose.edge_image.prepare_image`. Edges within 3 px of the picture's
    border or of ``ignore`` (uint8, > 0: edges known to be something else) are dropped."""
    sm = cv2.GaussianBlur(rect, (0, 0), smooth_px)
    gx = cv2.Sobel(sm, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(sm, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    mag = np.hypot(gx, gy)
    inside = cv2.erode(valid, np.ones((7, 7), np.uint8)) > 0
    noise = float(1.4826 * np.median(mag[inside])) + 1e-3 if inside.any() else 1.0
    lo, hi = max(1.0, 3.0 * noise), max(2.5, 7.0 * noise)
    s = 8.0  # Canny on the Sobel scale
    canny = cv2.Canny(np.clip(np.round(gx * s), -32767, 32767).astype(np.int16),
                      np.clip(np.round(gy * s), -32767, 32767).astype(np.int16), lo * s, hi * s, L2gradient=True)
    keep = inside
    if ignore is not None and ignore.any():
        keep = keep & ~explained_by(ignore, np.arctan2(gy, gx))
    canny = np.where(keep, canny, 0).astype(np.uint8)
    vv, uu = np.nonzero(canny)
    ang = np.arctan2(gy[vv, uu], gx[vv, uu])
    n = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    base = np.stack([uu, vv], axis=1).astype(np.float32)
    m0 = mag[vv, uu]
    mp = sample(mag, base + n.astype(np.float32))
    mm = sample(mag, base - n.astype(np.float32))
    den = mm - 2 * m0 + mp
    off = np.where(den < -1e-6, 0.5 * (mm - mp) / np.where(den < -1e-6, den, -1.0), 0.0)
    uv = base + n * np.clip(off, -0.5, 0.5)[:, None]
    return PlaneEdges(uv, ang, m0, canny, gx, gy, lo, valid)


def explained_by(ignore: np.ndarray, angle: np.ndarray, max_deg: float = 25.0) -> np.ndarray:
    """Pixels whose edge the known geometry in ``ignore`` explains: inside the (1 px grown) mask and,
    where the mask is a thin band (a table edge drawn a few px wide), running along it (gradient
    within ``max_deg`` of the band's normal, from the mask's structure tensor); inside wide masked
    areas (printed labels) every edge. An object's edge crossing a table edge is so kept."""
    m = cv2.GaussianBlur(ignore.astype(np.float32) / 255.0, (0, 0), 1.0)
    mx = cv2.Sobel(m, cv2.CV_32F, 1, 0, ksize=3)
    my = cv2.Sobel(m, cv2.CV_32F, 0, 1, ksize=3)
    jxx = cv2.GaussianBlur(mx * mx, (0, 0), 2.5)
    jxy = cv2.GaussianBlur(mx * my, (0, 0), 2.5)
    jyy = cv2.GaussianBlur(my * my, (0, 0), 2.5)
    band_normal = 0.5 * np.arctan2(2 * jxy, jxx - jyy)
    strength = np.sqrt((jxx - jyy) ** 2 + 4 * jxy ** 2)
    masked = cv2.dilate(ignore, np.ones((3, 3), np.uint8)) > 0
    along = np.abs(np.sin(angle - band_normal)) < np.sin(np.radians(max_deg))
    band = strength > 0.02
    return masked & (along | ~band)


def sample(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img`` at ``uv`` (N, 2) or (N, M, 2) px; outside: 0."""
    uv = np.asarray(uv, np.float32)
    shape = uv.shape[:-1]
    flat = uv.reshape(-1, 2)
    n = len(flat)
    if n == 0:
        return np.zeros(shape, np.float32)
    cols = 1024                       # remap's maps must stay under 32767 rows and columns
    pad = np.full(((n + cols - 1) // cols * cols, 2), -10.0, np.float32)
    pad[:n] = flat
    pad = pad.reshape(-1, cols, 2)
    out = cv2.remap(img, pad[..., 0], pad[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.reshape(-1)[:n].reshape(shape)


def edge_distance(canny: np.ndarray) -> np.ndarray:
    """Distance (grid px) of every pixel to the nearest edge pixel of a Canny map."""
    return cv2.distanceTransform(np.where(canny > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, 5)
