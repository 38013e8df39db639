"""The z-buffer's pixel loops compiled with numba (:func:`app.geometry.model_edges.render_depth`).

numpy expanded every (face, row) pair and then every (face, pixel) pair into arrays of millions of
entries before a scattered minimum; here each row's span is walked once and the buffer is updated in
place. The arithmetic is numpy's, term by term in the same order and precision (no fast-math, so no
fused multiply-adds), and the buffer is updated in numpy's order (meshes, faces, rows, pixels), so
depth and face ids are the same bit for bit; tests/geometry/test_raster_kernels.py keeps the numpy
rasteriser as the reference.

Units: barycentric planes ``l_k = A_k u + B_k v + C_k`` of each face in buffer pixels (pixel centres
at integers), camera z of its three vertices in mm.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _row_span(a0, b0, c0, a1, b1, c1, py, width):
    """(first, last) pixel column of row ``py`` inside the face (last < first: none), as numpy's
    half-plane bounds ``A_k x >= -(B_k py + C_k)`` with their 1e-12 and 1e-9 tolerances (finite
    faces: the callers drop degenerate ones)."""
    a2 = -a0 - a1
    b2 = -b0 - b1
    c2 = 1.0 - c0 - c1
    lo = -np.inf
    hi = np.inf
    for a, b, c in ((a0, b0, c0), (a1, b1, c1), (a2, b2, c2)):
        rhs = -(b * py + c)
        if a > 1e-12:
            bound = rhs / a
        elif abs(a) <= 1e-12:
            bound = -np.inf if rhs <= 1e-12 else np.inf
        else:
            bound = -np.inf
        if bound > lo:
            lo = bound
        if a < -1e-12 and rhs / a < hi:
            hi = rhs / a
    x0 = min(max(np.ceil(lo - 1e-9), 0.0), float(width))
    x1 = min(max(np.floor(hi + 1e-9), -1.0), float(width - 1))
    return np.int64(x0), np.int64(x1)


@njit(cache=True, nogil=True)
def span_pixel_count(A0, B0, C0, A1, B1, C1, y0, nrow, width):
    """Pixel tests the faces' rows make (numpy's ``cnt.sum()``): what the budget is checked against."""
    total = 0
    for f in range(len(A0)):
        for r in range(nrow[f]):
            x0, x1 = _row_span(A0[f], B0[f], C0[f], A1[f], B1[f], C1[f], y0[f] + r, width)
            if x1 >= x0:
                total += x1 - x0 + 1
    return total


@njit(cache=True, nogil=True)
def raster_min_depth(depth, face_id, mesh_tag, fidx, A0, B0, C0, A1, B1, C1, zt, y0, nrow, width):
    """Walk every face's rows and pixels, keeping in ``depth`` (flattened ``v * width + u``, mm) the
    nearest surface and in ``face_id`` its ``mesh_tag + face index``; of equal depths the last one
    drawn, as numpy's scatter keeps it. A NaN depth stays (``np.minimum``); the caller clears the face
    id of such pixels, which numpy's ``z <= depth`` never set."""
    for f in range(len(A0)):
        a0, b0, c0, a1, b1, c1 = A0[f], B0[f], C0[f], A1[f], B1[f], C1[f]
        z0, z1, z2 = zt[f, 0], zt[f, 1], zt[f, 2]
        tag = mesh_tag + fidx[f]
        for r in range(nrow[f]):
            py = y0[f] + r
            x0, x1 = _row_span(a0, b0, c0, a1, b1, c1, py, width)
            fy = float(py)
            for px in range(x0, x1 + 1):
                fx = float(px)
                l0 = a0 * fx + b0 * fy + c0
                l1 = a1 * fx + b1 * fy + c1
                l2 = 1.0 - l0 - l1
                z = 1.0 / (l0 / z0 + l1 / z1 + l2 / z2)      # perspective-correct depth
                k = py * width + px
                if z != z:
                    depth[k] = z
                elif z <= depth[k]:
                    depth[k] = z
                    face_id[k] = tag
