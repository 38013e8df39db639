"""Stage 1 of locating: the coarse search over x, y and the turn about table z
(:func:`coarse_starts`), an oriented chamfer correlation of the template with a coarse
rectification of the table."""

from __future__ import annotations

import cv2
import numpy as np

from app.vision.photo_model.edges import explained_by, plane_edges
from app.vision.photo_model.model import PhotoModel, angle_gap, rot, thin
from app.vision.photo_model.plane import PlaneGrid, rectify
from app.vision.photo_model.view import View


def coarse_starts(view: View, model: PhotoModel, search_xy: tuple[float, float, float, float],
                  n_starts: int = 3) -> list[tuple[float, float, float, float]]:
    """Oriented edge search: (score, x, y, theta) of the best distinct starts.

    The plane is rectified at ~R/25 mm per pixel. The score of a pose is the mean over the template's
    points of ``w cos(2 (phi - psi))``: ``phi`` the image's gradient direction there, ``psi`` the
    point's (turned by theta), ``w`` the image edge's strength (saturating at the Canny threshold), so
    an edge of the right direction counts +1, across -1, none or random texture about 0, and the sign
    of the contrast does not matter. ``cos 2(phi - psi) = cos 2phi cos 2psi + sin 2phi sin 2psi``
    makes it two correlations per turn (:func:`cv2.filter2D` of the images ``w cos 2phi`` and
    ``w sin 2phi``, slightly blurred for capture range, with kernels holding ``cos 2psi`` and
    ``sin 2psi`` at the points): a distance-free oriented chamfer."""
    R = max(model.radius_mm, float(np.max(np.linalg.norm(model.points_mm, axis=1))), 10.0)
    res = float(np.clip(R / 25.0, 1.0, 3.0))
    x_lo, x_hi, y_lo, y_hi = search_xy
    g = PlaneGrid.around(x_lo, x_hi, y_lo, y_hi, res, model.height_mm)
    rect, valid, ign = rectify(view.image, view.K, view.dist, view.T_cam_table, g, view.ignore)
    e = plane_edges(rect, valid, ign, smooth_px=0.8)
    phi = np.arctan2(e.gy, e.gx)
    w = np.clip(np.hypot(e.gx, e.gy) / e.threshold - 0.5, 0.0, 1.0)
    if ign is not None and ign.any():
        w = np.where(explained_by(ign, phi), 0.0, w)
    w = (w * (cv2.erode(valid, np.ones((5, 5), np.uint8)) > 0)).astype(np.float32)
    Cimg = cv2.GaussianBlur((w * np.cos(2 * phi)).astype(np.float32), (0, 0), 0.7)
    Simg = cv2.GaussianBlur((w * np.sin(2 * phi)).astype(np.float32), (0, 0), 0.7)
    sel = thin(model.points_mm, res)
    P, A = model.points_mm[sel], model.normal_rad[sel]
    step = float(np.degrees(0.7 * res / R))
    sym = min([s for s in model.symmetry_deg] + [360.0])
    thetas = np.radians(np.arange(0.0, sym, max(step, 0.5)))
    half = int(np.ceil(R / res)) + 2
    ks = 2 * half + 1
    found = []
    for t in thetas:
        q = np.rint(P @ rot(t).T / res + half).astype(int)
        kc = np.zeros((ks, ks), np.float32)
        ksn = np.zeros((ks, ks), np.float32)
        np.add.at(kc, (q[:, 1], q[:, 0]), np.cos(2 * (A + t)))
        np.add.at(ksn, (q[:, 1], q[:, 0]), np.sin(2 * (A + t)))
        score = (cv2.filter2D(Cimg, -1, kc, anchor=(half, half), borderType=cv2.BORDER_CONSTANT)
                 + cv2.filter2D(Simg, -1, ksn, anchor=(half, half), borderType=cv2.BORDER_CONSTANT)) / len(P)
        for _ in range(2):
            _, s, _, (u, v) = cv2.minMaxLoc(score)
            xy = g.to_mm(np.array([[u, v]], float))[0]
            found.append((float(s), float(xy[0]), float(xy[1]), float(t)))
            cv2.circle(score, (u, v), max(2, int(0.3 * R / res)), -1.0, -1)
    found.sort(key=lambda f: -f[0])
    out: list[tuple[float, float, float, float]] = []
    for f in found:
        if f[0] < 0.5 * found[0][0]:
            break
        if all(np.hypot(f[1] - o[1], f[2] - o[2]) > 0.3 * R or angle_gap(f[3], o[3], model) > np.radians(10)
               for o in out):
            out.append(f)
        if len(out) >= n_starts:
            break
    return out
