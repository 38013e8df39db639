"""Stage 3 of locating: what the fit is checked by besides its score. Edges inside the outline that
the model lacks (:func:`unexplained`), inner template edges the picture lacks (:func:`missing_inner`),
the drop of the score when the pose moves (:func:`distinctiveness`) and the edge IoU
(:func:`edge_iou`) by which look-alikes compete."""

from __future__ import annotations

import cv2
import numpy as np

from app.vision.photo_model.fit import SUPPORT_MM, Fit, supported
from app.vision.photo_model.model import TEMPLATE_SPACING_MM, PhotoModel, rot, transform
from app.vision.photo_model.plane import point_distance, point_grid

EXPLAINED_MM = 0.7          # an image edge inside the outline this close to a template point is explained


def _dt_coverage(fit: Fit, model: PhotoModel, x: float, y: float, t: float, d: np.ndarray) -> float:
    """Share of template points within ``SUPPORT_MM`` of an image edge at pose (x, y, t) (no normals:
    for the distinctiveness probes); ``d`` is ``fit.edge_dt``."""
    Q, _ = transform(model, x, y, t)
    ij, ok = fit.grid.pixels(Q)
    v = np.full(len(Q), 1e9)
    v[ok] = d[ij[ok, 1], ij[ok, 0]] * fit.grid.mm_per_px
    return float(np.mean(v < SUPPORT_MM + 0.15))


def distinctiveness(fit: Fit, model: PhotoModel, cam_mm: float) -> float:
    """The least drop of the supported share (edges within ``SUPPORT_MM`` + 0.15 mm, no normals) when
    the pose moves by 4 camera pixels (``cam_mm``: one camera pixel on the top face, mm) along table x
    or y, or turns by as much at the template's radius."""
    probe_mm = 4.0 * cam_mm
    probes = [(fit.x + dx, fit.y + dy, fit.theta) for dx, dy in ((probe_mm, 0), (-probe_mm, 0), (0, probe_mm),
                                                                 (0, -probe_mm))]
    probes += [(fit.x, fit.y, fit.theta + s * probe_mm / model.radius_mm) for s in (1, -1)]
    dt = fit.edge_dt
    base = _dt_coverage(fit, model, fit.x, fit.y, fit.theta, dt)
    return float(base - max(_dt_coverage(fit, model, *p, dt) for p in probes))


def unexplained(fit: Fit, model: PhotoModel) -> tuple[float, float, float]:
    """Edges inside the fitted outline (grown by 1 mm) that no template point explains: (their share
    of the edges there, their total length mm, the longest connected piece mm)."""
    g = fit.grid
    R = rot(fit.theta)
    inside = np.zeros((g.height, g.width), np.uint8)
    cv2.fillPoly(inside, [np.rint(g.to_px(model.outline_mm @ R.T + [fit.x, fit.y]) * 4).astype(np.int32)], 255, shift=2)
    # not in the holes: what shows through them (their walls, the table below) depends on the view
    holes = np.zeros_like(inside)
    for h in model.holes_mm:
        cv2.fillPoly(holes, [np.rint(g.to_px(h @ R.T + [fit.x, fit.y]) * 4).astype(np.int32)], 255, shift=2)
    r = max(1, round(1.0 / g.mm_per_px))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    inside = cv2.dilate(inside, disk) & ~cv2.dilate(holes, disk)
    Q, _ = transform(model, fit.x, fit.y, fit.theta)
    near = point_distance(g, Q) * g.mm_per_px < EXPLAINED_MM
    edges_in = (fit.edges.canny > 0) & (inside > 0)
    unexpl = (edges_in & ~near).astype(np.uint8)
    n_in = int(edges_in.sum())
    if not unexpl.any():
        return 0.0, 0.0, 0.0
    n, lab, _stats, _ = cv2.connectedComponentsWithStats(cv2.dilate(unexpl, np.ones((3, 3), np.uint8)), connectivity=8)
    longest = max(float(np.sum(unexpl[lab == i])) for i in range(1, n)) * g.mm_per_px
    return float(unexpl.sum() / max(n_in, 1)), float(unexpl.sum() * g.mm_per_px), longest


def missing_inner(fit: Fit, model: PhotoModel) -> float:
    """Longest connected piece (mm) of the template's inner edges (more than 1.5 mm inside the outline:
    holes, pockets, steps) that the picture does not show at the fit. The outline may be hidden in
    part (a clamp over an edge); a whole inner feature missing means another object (a plate without
    that hole)."""
    P = model.points_mm
    contour = model.outline_mm.astype(np.float32).reshape(-1, 1, 2)
    depth = np.array([cv2.pointPolygonTest(contour, (float(x), float(y)), True) for x, y in P])
    seen = supported(fit.found, fit.residual_mm, SUPPORT_MM + 0.2)
    miss = (depth > 1.5) & ~seen
    if not miss.any():
        return 0.0
    g = point_grid(P, 2)
    img = np.zeros((g.height, g.width), np.uint8)
    ij = np.rint(g.to_px(P[miss])).astype(int)
    img[ij[:, 1], ij[:, 0]] = 255
    n, lab = cv2.connectedComponents(cv2.dilate(img, np.ones((7, 7), np.uint8)), connectivity=8)
    per = np.bincount(lab[ij[:, 1], ij[:, 0]], minlength=n)
    return float(per[1:].max() * TEMPLATE_SPACING_MM) if n > 1 else 0.0


def edge_iou(coverage: float, model: PhotoModel, unexplained_mm: float) -> float:
    """Supported template edge length over (template length + unexplained edge length inside the
    outline): 1 for the right object; a plate without a hole fitted to one with it scores lower."""
    L = model.edge_length_mm
    return float(coverage * L / (L + unexplained_mm))
