"""Numpy z-buffer rasterizer that samples triangles at arbitrary per-pixel sample rays.

The scene renderer (:mod:`app.synth.scene`) takes several passes per image; in each pass every
output pixel carries ONE sample position (pixel centre, or a stratified jittered point inside the
pixel) that was mapped through the inverse of OpenCV's lens model to an ideal normalised ray
``(x, y, 1)``. Triangles are tested against those per-pixel rays directly, so the rendered image
follows the distortion model exactly (no resampling of an ideal image) and the coverage of an edge
is estimated without bias (stratified jitter; no grid quantisation).

Coordinates: a "plane" position ``(x, y)`` is either a normalised perspective ray (``x = X/Z``,
``y = Y/Z``, camera frame, OpenCV axes) or an orthographic position (shadow maps). Depth is ``Z``
(mm) for perspective and the coordinate along the projection axis for orthographic.

Pixel convention (OpenCV): pixel ``(u, v)`` covers ``[u - 0.5, u + 0.5) x [v - 0.5, v + 0.5)``, its
centre is at integer ``(u, v)``; image arrays are indexed ``img[v, u]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

NEAR_MM = 1.0


# ---------------------------------------------------------------------------------------------
# Lens model
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class UndistortGrid:
    """Ideal normalised coordinates of a regular grid of distorted pixel positions.

    ``x[j, i], y[j, i]`` are the undistorted normalised coordinates of the distorted pixel position
    ``(u0 + i * step, v0 + j * step)``. Bilinear interpolation on this grid (step 4 px) is accurate
    to ~1e-3 px for the mild distortion of machine-vision lenses (second derivative of the map).
    """

    x: np.ndarray
    y: np.ndarray
    u0: float
    v0: float
    step: float

    def lookup(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normalised ideal ``(x, y)`` for distorted pixel positions ``u, v`` (any equal shapes)."""
        gu = (np.asarray(u, dtype=np.float64) - self.u0) / self.step
        gv = (np.asarray(v, dtype=np.float64) - self.v0) / self.step
        i0 = np.clip(np.floor(gu).astype(np.int64), 0, self.x.shape[1] - 2)
        j0 = np.clip(np.floor(gv).astype(np.int64), 0, self.x.shape[0] - 2)
        fu = gu - i0
        fv = gv - j0
        out = []
        for m in (self.x, self.y):
            a = m[j0, i0]
            b = m[j0, i0 + 1]
            c = m[j0 + 1, i0]
            d = m[j0 + 1, i0 + 1]
            out.append((a * (1 - fu) + b * fu) * (1 - fv) + (c * (1 - fu) + d * fu) * fv)
        return out[0], out[1]

    def lookup_pixel_grid(self, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """``lookup`` at every pixel centre (H, W), done as two sparse bilinear products
        (same numbers as ``lookup``, a few times faster)."""
        from scipy.sparse import csr_matrix

        def weights(n_out: int, origin: float, n_grid: int) -> csr_matrix:
            g = (np.arange(n_out, dtype=np.float64) - origin) / self.step
            i0 = np.clip(np.floor(g).astype(np.int64), 0, n_grid - 2)
            f = g - i0
            rows = np.repeat(np.arange(n_out), 2)
            cols = np.stack([i0, i0 + 1], axis=1).ravel()
            vals = np.stack([1 - f, f], axis=1).ravel()
            return csr_matrix((vals, (rows, cols)), shape=(n_out, n_grid))

        Au = weights(width, self.u0, self.x.shape[1])      # (W, Gw)
        Av = weights(height, self.v0, self.x.shape[0])     # (H, Gh)
        return (np.asarray(Av @ (Au @ self.x.T).T), np.asarray(Av @ (Au @ self.y.T).T))


def make_undistort_grid(K: np.ndarray, dist: np.ndarray, width: int, height: int,
                        step: float = 4.0, margin_px: float = 8.0) -> UndistortGrid:
    """Undistort (exactly, iterating OpenCV's inverse to 1e-14) a grid covering the image."""
    us = np.arange(-margin_px, width + margin_px + step, step) - 0.5
    vs = np.arange(-margin_px, height + margin_px + step, step) - 0.5
    gu, gv = np.meshgrid(us, vs)
    pts = np.stack([gu, gv], -1).reshape(-1, 1, 2)
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 60, 1e-15)
    xy = cv2.undistortPoints(pts, np.asarray(K, float), np.asarray(dist, float), None, None, None, crit)
    xy = xy.reshape(gu.shape + (2,))
    return UndistortGrid(x=xy[..., 0].copy(), y=xy[..., 1].copy(), u0=float(us[0]), v0=float(vs[0]),
                         step=float(step))


# ---------------------------------------------------------------------------------------------
# Rasterizer
# ---------------------------------------------------------------------------------------------

@dataclass
class SampleGrid:
    """One sample per pixel: plane coordinates ``x, y`` (H, W) float64 and their column/row ranges."""

    x: np.ndarray
    y: np.ndarray

    def __post_init__(self) -> None:
        # Conservative monotone envelopes, used to map a plane-space bbox to a pixel index range.
        self.col_min_up = np.maximum.accumulate(self.x.max(axis=0))  # monotone upper envelope
        self.row_min_up = np.maximum.accumulate(self.y.max(axis=1))
        self.col_lo = np.minimum.accumulate(self.x.min(axis=0)[::-1])[::-1]
        self.row_lo = np.minimum.accumulate(self.y.min(axis=1)[::-1])[::-1]

    @property
    def shape(self) -> tuple[int, int]:
        return self.x.shape

    TILE = 32

    def tile_bounds(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per tile (TILE x TILE pixels): min/max of the samples' x and y, each (Ht, Wt)."""
        if not hasattr(self, "_tiles"):
            H, W = self.shape
            T = self.TILE
            Ht, Wt = -(-H // T), -(-W // T)
            pad = ((0, Ht * T - H), (0, Wt * T - W))
            out = []
            for a in (self.x, self.y):
                ap = np.pad(a, pad, mode="edge").reshape(Ht, T, Wt, T)
                out += [ap.min(axis=(1, 3)), ap.max(axis=(1, 3))]
            self._tiles = tuple(out)
        return self._tiles

    def pixel_ranges(self, x0, x1, y0, y1):
        """Index ranges [c0, c1), [r0, r1) of pixels whose sample may fall inside the box."""
        # A column u can hold a sample with x >= x0 only if max_v x[v, u] >= x0; the upper envelope
        # col_min_up (running max of the column maxima) is monotone, so searchsorted applies.
        c0 = np.searchsorted(self.col_min_up, x0, side="left")
        c1 = np.searchsorted(self.col_lo, x1, side="right")
        r0 = np.searchsorted(self.row_min_up, y0, side="left")
        r1 = np.searchsorted(self.row_lo, y1, side="right")
        return c0, c1, r0, r1


@dataclass
class Triangles:
    """Triangles ready for rasterizing: 2D plane vertices and the plane equation for depth.

    ``p`` (T, 3, 2) plane coordinates of the vertices; depth at plane point (x, y) is
    ``d / (a x + b y + c)`` (perspective) or ``(d - a x - b y) / c`` (orthographic), with
    ``abc_d`` (T, 4) = (a, b, c, d). ``ids`` (T,) int32 are written to the id buffer.
    """

    p: np.ndarray
    abc_d: np.ndarray
    ids: np.ndarray
    perspective: bool


def _clip_near(V: np.ndarray, near: float) -> list[np.ndarray]:
    """Clip one triangle (3, 3) against z >= near (Sutherland-Hodgman); return 0..2 triangles."""
    poly = []
    for i in range(3):
        a, b = V[i], V[(i + 1) % 3]
        ina, inb = a[2] >= near, b[2] >= near
        if ina:
            poly.append(a)
        if ina != inb:
            t = (near - a[2]) / (b[2] - a[2])
            poly.append(a + t * (b - a))
    if len(poly) < 3:
        return []
    return [np.array([poly[0], poly[k], poly[k + 1]]) for k in range(1, len(poly) - 1)]


def perspective_triangles(V_cam: np.ndarray, ids: np.ndarray, near: float = NEAR_MM) -> Triangles:
    """Project triangles (T, 3, 3) given in the camera frame (mm) to normalised coordinates."""
    V = np.asarray(V_cam, dtype=np.float64)
    ids = np.asarray(ids, dtype=np.int32)
    zmin = V[:, :, 2].min(axis=1)
    zmax = V[:, :, 2].max(axis=1)
    keep = zmin >= near
    cross = (zmax >= near) & ~keep
    Vs = [V[keep]]
    idl = [ids[keep]]
    for k in np.nonzero(cross)[0]:
        for tri in _clip_near(V[k], near):
            Vs.append(tri[None])
            idl.append(ids[k:k + 1])
    V = np.concatenate(Vs)
    ids = np.concatenate(idl)
    n = np.cross(V[:, 1] - V[:, 0], V[:, 2] - V[:, 0])
    d = np.einsum("ij,ij->i", n, V[:, 0])
    p = V[:, :, :2] / V[:, :, 2:3]
    return Triangles(p=p, abc_d=np.column_stack([n, d]), ids=ids, perspective=True)


def orthographic_triangles(V_l: np.ndarray, ids: np.ndarray) -> Triangles:
    """Triangles (T, 3, 3) in a frame whose z axis is the projection direction (depth = z)."""
    V = np.asarray(V_l, dtype=np.float64)
    n = np.cross(V[:, 1] - V[:, 0], V[:, 2] - V[:, 0])
    ok = np.abs(n[:, 2]) > 1e-12 * np.maximum(1.0, np.linalg.norm(n, axis=1))
    V, n, ids = V[ok], n[ok], np.asarray(ids, dtype=np.int32)[ok]
    d = np.einsum("ij,ij->i", n, V[:, 0])
    return Triangles(p=V[:, :, :2].copy(), abc_d=np.column_stack([n, d]), ids=ids, perspective=False)


def depth_at(tri_abcd: np.ndarray, x: np.ndarray, y: np.ndarray, perspective: bool) -> np.ndarray:
    a, b, c, d = (tri_abcd[..., k] for k in range(4))
    if perspective:
        den = a * x + b * y + c
        with np.errstate(divide="ignore", invalid="ignore"):
            return d / den
    return (d - a * x - b * y) / c


def inside_triangle(p: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Samples inside (inclusive) triangles p (..., 3, 2) broadcast against x, y."""
    x0, y0 = p[..., 0, 0], p[..., 0, 1]
    x1, y1 = p[..., 1, 0], p[..., 1, 1]
    x2, y2 = p[..., 2, 0], p[..., 2, 1]
    area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
    s = np.sign(area)
    w0 = ((x2 - x1) * (y - y1) - (y2 - y1) * (x - x1)) * s
    w1 = ((x0 - x2) * (y - y2) - (y0 - y2) * (x - x2)) * s
    w2 = ((x1 - x0) * (y - y0) - (y1 - y0) * (x - x0)) * s
    return (w0 >= 0) & (w1 >= 0) & (w2 >= 0) & (s != 0)


def rasterize(grid: SampleGrid, tris: Triangles, zbuf: np.ndarray, idbuf: np.ndarray,
              near: float = NEAR_MM, max_batch_samples: int = 1_000_000) -> None:
    """Z-buffer ``tris`` into ``zbuf`` (H, W) float64 / ``idbuf`` (H, W) int32, in place.

    ``idbuf`` receives the index of the triangle in ``tris`` (map through ``tris.ids``).

    Small triangles are processed in vectorised batches (a B x B pixel window each, B a power of
    two); large ones one by one on their bounding-box slice.
    """
    if len(tris.ids) == 0:
        return
    H, W = grid.shape
    p = tris.p
    c0, c1, r0, r1 = grid.pixel_ranges(p[:, :, 0].min(1), p[:, :, 0].max(1),
                                       p[:, :, 1].min(1), p[:, :, 1].max(1))
    c0 = np.clip(c0, 0, W)
    c1 = np.clip(c1, 0, W)
    r0 = np.clip(r0, 0, H)
    r1 = np.clip(r1, 0, H)
    ext = np.maximum(c1 - c0, r1 - r0)
    live = (c1 > c0) & (r1 > r0)
    zflat = zbuf.reshape(-1)
    iflat = idbuf.reshape(-1)
    xflat = grid.x.reshape(-1)
    yflat = grid.y.reshape(-1)
    B = 2
    while True:
        sel = np.nonzero(live & (ext <= B) & (ext > B // 2 if B > 2 else True))[0]
        if B > 64:
            break
        if len(sel):
            chunk = max(1, max_batch_samples // (B * B))
            ar = np.arange(B)
            for s in range(0, len(sel), chunk):
                k = sel[s:s + chunk]
                rows = np.minimum(r0[k, None] + ar, H - 1)           # (T, B)
                cols = np.minimum(c0[k, None] + ar, W - 1)
                pix = (rows[:, :, None] * W + cols[:, None, :]).reshape(len(k), -1)  # (T, B*B)
                xs = xflat[pix]
                ys = yflat[pix]
                inside = inside_triangle(p[k][:, None], xs, ys)
                z = depth_at(tris.abc_d[k][:, None, :], xs, ys, tris.perspective)
                ok = inside & (z > (near if tris.perspective else -np.inf)) & (z < zflat[pix])
                if not ok.any():
                    continue
                tri_idx = np.broadcast_to(k[:, None], pix.shape)[ok]
                pz = z[ok]
                pp = pix[ok]
                order = np.lexsort((pz, pp))
                pp, pz, tri_idx = pp[order], pz[order], tri_idx[order]
                first = np.ones(len(pp), bool)
                first[1:] = pp[1:] != pp[:-1]
                zflat[pp[first]] = pz[first]
                iflat[pp[first]] = tri_idx[first]
        B *= 2
    big = np.nonzero(live & (ext > 64))[0]
    if len(big):
        _rasterize_big(grid, tris, big, c0, c1, r0, r1, zflat, iflat, near)


def _rasterize_big(grid, tris, big, c0, c1, r0, r1, zflat, iflat, near) -> None:
    """Large triangles one by one, over the tiles of their bounding box that they may touch."""
    H, W = grid.shape
    T = grid.TILE
    xmin, xmax, ymin, ymax = grid.tile_bounds()
    ar = np.arange(T)
    for k in big:
        tr = slice(r0[k] // T, (r1[k] - 1) // T + 1)
        tc = slice(c0[k] // T, (c1[k] - 1) // T + 1)
        bx0, bx1, by0, by1 = xmin[tr, tc], xmax[tr, tc], ymin[tr, tc], ymax[tr, tc]
        p = tris.p[k]
        area = (p[1, 0] - p[0, 0]) * (p[2, 1] - p[0, 1]) - (p[2, 0] - p[0, 0]) * (p[1, 1] - p[0, 1])
        if area == 0:
            continue
        sgn = np.sign(area)
        keep = np.ones(bx0.shape, bool)
        for i in range(3):
            a, b = p[i], p[(i + 1) % 3]
            A = -sgn * (b[1] - a[1])
            B = sgn * (b[0] - a[0])
            C = -A * a[0] - B * a[1]
            emax = A * (bx1 if A > 0 else bx0) + B * (by1 if B > 0 else by0) + C
            keep &= emax >= -1e-12
        ti, tj = np.nonzero(keep)
        if len(ti) == 0:
            continue
        rows = np.minimum((ti + tr.start)[:, None] * T + ar, H - 1)      # (n, T)
        cols = np.minimum((tj + tc.start)[:, None] * T + ar, W - 1)
        pix = (rows[:, :, None] * W + cols[:, None, :]).reshape(-1)
        xs = grid.x.reshape(-1)[pix]
        ys = grid.y.reshape(-1)[pix]
        inside = inside_triangle(p, xs, ys)
        z = depth_at(tris.abc_d[k], xs, ys, tris.perspective)
        ok = inside & (z < zflat[pix])
        if tris.perspective:
            ok &= z > near
        zflat[pix[ok]] = z[ok]
        iflat[pix[ok]] = k


def candidate_triangles(idbuf: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Distinct triangle indices seen at the 3x3 pixel centres around each (row, col).

    Returns (N, C) int32, -1 padded, C the largest number of distinct triangles of any pixel.
    """
    H, W = idbuf.shape
    c = []
    for dv in (-1, 0, 1):
        for du in (-1, 0, 1):
            c.append(idbuf[np.clip(rows + dv, 0, H - 1), np.clip(cols + du, 0, W - 1)])
    c = np.sort(np.stack(c, axis=1), axis=1)
    dup = np.zeros(c.shape, bool)
    dup[:, 1:] = c[:, 1:] == c[:, :-1]
    c[dup | (c < 0)] = np.iinfo(np.int32).max
    c = np.sort(c, axis=1)
    width = int(max(1, (c < np.iinfo(np.int32).max).sum(axis=1).max()))
    c = c[:, :width]
    c[c == np.iinfo(np.int32).max] = -1
    return c.astype(np.int32)


def resolve_samples(tris: Triangles, cands: np.ndarray, x: np.ndarray, y: np.ndarray,
                    near: float = NEAR_MM,
                    fallback: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Nearest candidate triangle hit by each sample ray (exact test, no grid).

    cands : (N, C) triangle indices per pixel (-1 = none); x, y : (N, S) plane coordinates of the
    pixel's samples. ``fallback`` (N,) triangle per pixel (-1: none) whose PLANE takes samples
    that hit no candidate. Returns depth (N, S) (inf: no hit) and triangle index (N, S) (-1: no hit).
    """
    z_best = np.full(x.shape, np.inf)
    t_best = np.full(x.shape, -1, np.int32)
    for k in range(cands.shape[1]):
        rows = np.nonzero(cands[:, k] >= 0)[0]
        if len(rows) == 0:
            continue
        t = cands[rows, k]
        xs, ys = x[rows], y[rows]
        inside = inside_triangle(tris.p[t][:, None], xs, ys)
        z = depth_at(tris.abc_d[t][:, None, :], xs, ys, tris.perspective)
        zb = z_best[rows]
        better = inside & (z < zb) & (z > near)
        z_best[rows] = np.where(better, z, zb)
        t_best[rows] = np.where(better, t[:, None], t_best[rows])
    if fallback is not None:
        miss = (t_best < 0) & (fallback >= 0)[:, None]
        if miss.any():
            r, c = np.nonzero(miss)
            t = fallback[r]
            z = depth_at(tris.abc_d[t], x[r, c], y[r, c], tris.perspective)
            ok = np.isfinite(z) & (z > near)
            z_best[r[ok], c[ok]] = z[ok]
            t_best[r[ok], c[ok]] = t[ok]
    return z_best, t_best
