"""The plane search's inner loops compiled with numba (:mod:`app.vision.object_pose.search`): each
is one pass where numpy made a dozen full-size temporaries, and each gives numpy's numbers.

* :func:`planar_scores`, the image scorer (``search._image_scorer``): 10-20 million (pose, template
  point) pairs per image, about 450 ns each in numpy, a seventh of that here. The arithmetic is the
  numpy scorer's, per pair in the same order and the same precision (the distance weight in float32,
  as numpy computes it from the float32 distance map); tests/vision/object_pose/test_search_kernels.py
  holds the numpy scorer as the reference. Units: template points mm in the resting frame moved by
  planar poses (x mm, y mm, theta rad) on the table; pixels of the raw (distorted) image.
* :func:`conj_product_sum`, the coarse correlation's spectra summed over the (level, channel) maps
  for one turn: numpy's ``conj(einsum("kij,kij->ij", a, b))``, in the same order, bit for bit, at
  about half its time.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _project(X0, X1, X2, K, d, distorted, rational, prism):
    """One camera-frame point (mm) -> raw pixel (u, v), as ``project_points_px`` (NaN behind)."""
    if X2 <= 1e-6:
        return np.nan, np.nan
    x = X0 / X2
    y = X1 / X2
    if distorted:
        k1, k2, p1, p2, k3 = d[0], d[1], d[2], d[3], d[4]
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        if rational:
            radial = radial / (1 + r2 * (d[5] + r2 * (d[6] + r2 * d[7])))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        if prism:
            r4 = r2 * r2
            xd = xd + d[8] * r2 + d[9] * r4
            yd = yd + d[10] * r2 + d[11] * r4
    else:
        xd, yd = x, y
    if K[0, 1] != 0:
        u = K[0, 0] * xd + K[0, 1] * yd + K[0, 2]
    else:
        u = K[0, 0] * xd + K[0, 2]
    return u, K[1, 1] * yd + K[1, 2]


@njit(cache=True, nogil=True)
def planar_scores(hx, hy, ht, P, D, w, N0, N1, smooth, use_normals, w_floor, R, t, C, K, d, distorted,
                  rational, prism, d_map, cos_map, sin_map, W, H, tau_px, cos_tol):
    """Score of each planar pose ``(hx[i], hy[i], ht[i])``: the weighted share of the template's
    points ``P`` (directions ``D``, weights ``w``) that project within ``tau_px`` of an image edge of
    compatible direction (soft: ``1 - dist / tau``). With ``use_normals``, only the points that can
    show (a crease with a face towards the camera centre ``C``, a smooth edge on a silhouette) count,
    over at least ``w_floor`` of weight. ``R, t``: camera from table; ``d``: 12 distortion
    coefficients (OpenCV order, zero-padded) with flags for the terms in use; the maps flattened
    ``v * W + u``."""
    n, M = hx.shape[0], P.shape[0]
    out = np.empty(n)
    tau32 = np.float32(tau_px)
    w_sum = 0.0
    for j in range(M):
        w_sum += w[j]
    for i in range(n):
        c = np.cos(ht[i])
        s = np.sin(ht[i])
        num = 0.0
        den = 0.0
        for j in range(M):
            X0 = hx[i] + c * P[j, 0] - s * P[j, 1]
            X1 = hy[i] + s * P[j, 0] + c * P[j, 1]
            X2 = P[j, 2]
            vis = True
            if use_normals:
                V0, V1, V2 = C[0] - X0, C[1] - X1, C[2] - X2
                f0 = (c * N0[j, 0] - s * N0[j, 1]) * V0 + (s * N0[j, 0] + c * N0[j, 1]) * V1 + N0[j, 2] * V2 > 0
                f1 = (c * N1[j, 0] - s * N1[j, 1]) * V0 + (s * N1[j, 0] + c * N1[j, 1]) * V1 + N1[j, 2] * V2 > 0
                vis = (f0 != f1) if smooth[j] else (f0 or f1)
                if not vis:
                    continue
                den += w[j]
            Xc0 = X0 * R[0, 0] + X1 * R[0, 1] + X2 * R[0, 2] + t[0]      # camera frame
            Xc1 = X0 * R[1, 0] + X1 * R[1, 1] + X2 * R[1, 2] + t[1]
            Xc2 = X0 * R[2, 0] + X1 * R[2, 1] + X2 * R[2, 2] + t[2]
            u, v = _project(Xc0, Xc1, Xc2, K, d, distorted, rational, prism)
            if not (u >= 0 and v >= 0 and u <= W - 1 and v <= H - 1):     # NaN fails too
                continue
            px = int(v) * W + int(u)
            val = np.float32(1.0) - d_map[px] / tau32
            if val <= 0:                # no edge near: its direction does not matter (a third of them)
                continue
            if val > 1:
                val = np.float32(1.0)
            # the edge's direction in the image: the point half a mm along it, projected
            Dt0 = c * D[j, 0] - s * D[j, 1]
            Dt1 = s * D[j, 0] + c * D[j, 1]
            Dt2 = D[j, 2]
            Y0 = (Dt0 * R[0, 0] + Dt1 * R[0, 1] + Dt2 * R[0, 2]) * 0.5 + Xc0
            Y1 = (Dt0 * R[1, 0] + Dt1 * R[1, 1] + Dt2 * R[1, 2]) * 0.5 + Xc1
            Y2 = (Dt0 * R[2, 0] + Dt1 * R[2, 1] + Dt2 * R[2, 2]) * 0.5 + Xc2
            u2, v2 = _project(Y0, Y1, Y2, K, d, distorted, rational, prism)
            tu, tv = u2 - u, v2 - v
            tn = np.sqrt(tu * tu + tv * tv) + 1e-12
            # the image gradient is perpendicular to the edge: |sin(angle between gradient and edge)|
            if np.abs(cos_map[px] * tv - sin_map[px] * tu) / tn >= cos_tol:
                num += val * w[j]
        if use_normals:
            out[i] = num / max(den, w_floor + 1e-9)
        else:
            out[i] = num / max(w_sum, 1e-9)
    return out


@njit(cache=True, nogil=True)
def conj_product_sum(a, b):
    """``conj(sum_k a[k] * b[k])`` of two (K, ny, nx) complex arrays: the sum taken over k in order,
    as ``np.einsum("kij,kij->ij", a, b)`` does, so that the numbers are the same."""
    K, ny, nx = a.shape
    out = np.zeros((ny, nx), a.dtype)
    for k in range(K):
        for i in range(ny):
            for j in range(nx):
                out[i, j] += a[k, i, j] * b[k, i, j]
    for i in range(ny):
        for j in range(nx):
            out[i, j] = np.conj(out[i, j])
    return out
