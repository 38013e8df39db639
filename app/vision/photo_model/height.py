"""The height of an object's top face from two pictures taken from different camera poses
(:func:`measure_height`): the plane ``z`` of the table frame on which their rectified edges coincide
(a plane sweep)."""

from __future__ import annotations

import numpy as np

from app.geometry.transforms import inv
from app.vision.photo_model.edges import edge_distance, plane_edges
from app.vision.photo_model.plane import PlaneGrid, rectify
from app.vision.photo_model.template import TeachError
from app.vision.photo_model.view import View


def measure_height(views: list[View], region_mm: tuple[float, float, float, float],
                   z_range_mm: tuple[float, float] = (2.0, 200.0)) -> tuple[float, float]:
    """Height (mm) of an object's top face from two or more pictures of it (one placement) taken from
    different camera poses: the plane ``z`` on which the rectified edges of the views coincide best
    (a plane sweep, 1 mm steps on a 1 mm grid, then 0.1 mm steps on a 0.25 mm grid, inside
    ``region_mm``). Returns (height, the share of edge
    points that coincide there). Raises :class:`TeachError` when the views cannot tell."""
    if len(views) < 2:
        raise TeachError("measuring the height needs two pictures from different camera poses")
    C = [inv(np.asarray(v.T_cam_table, float))[:3, 3] for v in views]
    base = max(np.linalg.norm(c - C[0]) for c in C[1:])
    if base < 50.0:
        raise TeachError(f"the camera moved only {base:.0f} mm between the pictures: too little to measure the "
                         "height (move it 100 mm or more, or give the height)")
    x_lo, x_hi, y_lo, y_hi = region_mm

    def agreement(z: float, res: float) -> tuple[float, float]:
        """(share of view 1's edge points within 2 px of view 2's edges, their mean distance capped at
        1 mm) on the plane z."""
        g = PlaneGrid.around(x_lo, x_hi, y_lo, y_hi, res, z)
        es = []
        for v in views[:2]:
            rect, valid, ign = rectify(v.image, v.K, v.dist, v.T_cam_table, g, v.ignore)
            es.append(plane_edges(rect, valid, ign, smooth_px=1.0))
        dmap = edge_distance(es[1].canny)
        ij = np.clip(np.rint(es[0].uv).astype(int), 0, [g.width - 1, g.height - 1])
        if len(ij) < 20:
            return 0.0, 1.0
        d = dmap[ij[:, 1], ij[:, 0]]
        return float(np.mean(d < 2.0)), float(np.mean(np.minimum(d * res, 1.0)))

    zs = np.arange(z_range_mm[0], z_range_mm[1] + 1e-9, 1.0)
    # chosen by the mean distance: the share within 2 px saturates over a few millimetres
    z0 = float(zs[int(np.argmin([agreement(z, 1.0)[1] for z in zs]))])
    fine = np.arange(z0 - 1.5, z0 + 1.5001, 0.1)
    fs = [agreement(z, 0.25) for z in fine]
    best = int(np.argmin([f[1] for f in fs]))
    if fs[best][0] < 0.3:
        raise TeachError(f"the pictures agree on no plane (best {fs[best][0]:.0%} of edges at {fine[best]:.1f} mm): "
                         "give the height")
    return float(fine[best]), float(fs[best][0])
