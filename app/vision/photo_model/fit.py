"""Stage 2 of locating: the least-squares fit of the template's edges to subpixel image edges found
along their normals on a fine rectification (:func:`refine`; :func:`refine_fixed` finds the
correspondences at a pose without fitting), and the supported share (``SUPPORT_MM``) that is the
fit's score."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from app.vision.photo_model.edges import PlaneEdges, edge_distance, plane_edges, sample
from app.vision.photo_model.model import PhotoModel, rot, transform
from app.vision.photo_model.plane import FINE_MM_PER_PX, PlaneGrid, rectify
from app.vision.photo_model.view import View

SUPPORT_MM = 0.4            # a template point is supported by an image edge this close (along its normal)


@dataclass(frozen=True, eq=False)
class Fit:
    """The template fitted (or placed) at ``(x mm, y mm, theta rad)`` on the table, with its score
    (``coverage``: the share of template points supported), its correspondences, the Jacobian of the
    point-to-line residuals in (x, y, theta) and the fine rectification's grid and edges."""

    x: float
    y: float
    theta: float
    coverage: float
    residual_mm: np.ndarray      # per template point (NaN: no edge found)
    found: np.ndarray            # per template point: an edge was found along the normal
    J: np.ndarray
    grid: PlaneGrid
    edges: PlaneEdges

    @property
    def edge_dt(self) -> np.ndarray:
        """Distance (grid px) of every grid pixel to the nearest image edge."""
        return edge_distance(self.edges.canny)


def supported(found: np.ndarray, residual_mm: np.ndarray, within_mm: float = SUPPORT_MM) -> np.ndarray:
    """Per template point: an image edge was found along its normal within ``within_mm``."""
    return found & (np.abs(np.nan_to_num(residual_mm, nan=9.0)) < within_mm)


def _fine_edges(view: View, model: PhotoModel, x: float, y: float, margin_mm: float = 8.0
                ) -> tuple[PlaneGrid, PlaneEdges]:
    """The picture's edges on a ``FINE_MM_PER_PX`` rectification of the top face's plane around (x, y)."""
    R = model.radius_mm + margin_mm
    grid = PlaneGrid.around(x - R, x + R, y - R, y + R, FINE_MM_PER_PX, model.height_mm)
    rect, valid, ign = rectify(view.image, view.K, view.dist, view.T_cam_table, grid, view.ignore)
    return grid, plane_edges(rect, valid, ign, smooth_px=1.5)


def correspond(e: PlaneEdges, grid: PlaneGrid, Q: np.ndarray, N: np.ndarray, reach_mm: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Along each normal ``N`` (unit, table axes) from each point ``Q`` (mm): the strongest image edge
    of that direction within ``reach_mm`` (subpixel). Returns (offset mm along N, found)."""
    step = 0.5
    n_s = int(np.ceil(reach_mm / (grid.mm_per_px * step)))
    s = np.arange(-n_s, n_s + 1) * step                          # grid px
    q = grid.to_px(Q)
    pts = q[:, None, :] + s[None, :, None] * N[:, None, :]
    gx, gy = sample(e.gx, pts), sample(e.gy, pts)
    along = np.abs(gx * N[:, None, 0] + gy * N[:, None, 1])
    mag = np.hypot(gx, gy) + 1e-9
    score = np.where(along > 0.85 * mag, along, 0.0)
    k = np.argmax(score, axis=1)
    best = score[np.arange(len(k)), k]
    inner = (k > 0) & (k < len(s) - 1)
    kk = np.clip(k, 1, len(s) - 2)
    a, b, c = (along[np.arange(len(k)), kk - 1], along[np.arange(len(k)), kk], along[np.arange(len(k)), kk + 1])
    den = a - 2 * b + c
    off = np.where(den < -1e-9, 0.5 * (a - c) / np.where(den < -1e-9, den, -1.0), 0.0)
    pos = (s[kk] + np.clip(off, -1, 1) * step) * grid.mm_per_px
    found = inner & (best > e.threshold)
    return np.where(found, pos, np.nan), found


def refine(view: View, model: PhotoModel, start: tuple[float, float, float]) -> Fit:
    """Least-squares fit of the template's edges to subpixel image edges along their normals on a
    fine rectification, correspondences found anew with a shrinking reach (ICP, point to line)."""
    x, y, t = start
    grid, e = _fine_edges(view, model, x, y)
    P = model.points_mm
    for reach in (4.0, 2.5, 1.5, 1.0, 0.8, 0.8):
        Q, N = transform(model, x, y, t)
        off, found = correspond(e, grid, Q, N, reach)
        if found.sum() < 10:
            break
        T = Q[found] + off[found][:, None] * N[found]        # the image edge points
        Pf, Af = P[found], model.normal_rad[found]

        def res(p, Pf=Pf, Af=Af, T=T):
            R = rot(p[2])
            n = np.stack([np.cos(Af + p[2]), np.sin(Af + p[2])], axis=1)
            return np.einsum("ij,ij->i", n, Pf @ R.T + p[:2] - T)

        sol = least_squares(res, [x, y, t], loss="soft_l1", f_scale=0.25, x_scale=[1.0, 1.0, 0.01])
        x, y, t = (float(v) for v in sol.x)
    Q, N = transform(model, x, y, t)
    off, found = correspond(e, grid, Q, N, 0.8)
    # d residual / d (x, y, theta): the normal, and the normal on dR/dtheta p
    J = np.column_stack([N, np.einsum("ij,ij->i", N, (model.points_mm @ rot(t + np.pi / 2).T))])
    cov = float(np.mean(supported(found, off)))
    return Fit(x, y, t, cov, off, found, J, grid, e)


def refine_fixed(view: View, model: PhotoModel, pose: tuple[float, float, float]) -> Fit:
    """Correspondences of ``model`` at a fixed pose (no fit): which of its edges the picture shows."""
    x, y, t = pose
    grid, e = _fine_edges(view, model, x, y)
    Q, N = transform(model, x, y, t)
    off, found = correspond(e, grid, Q, N, 0.8)
    return Fit(x, y, t, float(np.mean(supported(found, off))), off, found, np.zeros((len(Q), 3)), grid, e)
