"""A small software renderer for thumbnails and previews of meshes (no OpenGL).

Orthographic view from a direction given by azimuth/elevation (default: isometric-like, from the
front-right above), flat Lambert shading with two lights plus ambient, back-face culling, a vectorised numpy z-buffer
(exact visibility, no painter's-algorithm artefacts) and dark crease / silhouette lines, rendered at
2x and downsampled with area averaging for anti-aliased edges. Good for parts, fixtures and tables; it
is not a hidden-line renderer for measurement (the localisation has its own projection).
"""

from __future__ import annotations

import cv2
import numpy as np
import trimesh

_SUPERSAMPLE = 2


def _view_rotation(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """R_view_obj: rows are the view's right, up and towards-viewer axes in the obj frame (z up)."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    to_viewer = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    right = np.cross([0.0, 0.0, 1.0], to_viewer)
    right /= np.linalg.norm(right)
    up = np.cross(to_viewer, right)
    return np.stack([right, up, to_viewer])


def project_triangles(
    mesh: trimesh.Trimesh, S: int, azimuth_deg: float = -60.0, elevation_deg: float = 30.0, margin: float = 0.06,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Orthographic projection of the visible side of ``mesh`` into an S x S pixel square.

    Returns ``tri`` (F, 3, 3) view coordinates (x right, y up, z towards the viewer, mm), unit
    normals ``n`` (F, 3) facing the viewer, and ``uv`` (F, 3, 2) pixel coordinates (y down) with the
    mesh's silhouette fitted inside ``margin``. Back faces are culled for closed meshes; open
    meshes keep both sides (normals flipped towards the viewer).
    """
    R = _view_rotation(azimuth_deg, elevation_deg)
    v = mesh.vertices @ R.T
    tri = v[mesh.faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(n, axis=1)
    ok = norm > 0
    n[ok] /= norm[ok, None]
    if mesh.is_watertight:
        ok &= n[:, 2] > 0
    else:
        n[n[:, 2] < 0] *= -1.0
    tri, n = tri[ok], n[ok]
    lo = v[:, :2].min(axis=0)
    hi = v[:, :2].max(axis=0)
    span = float(max(hi - lo)) or 1.0
    scale = S * (1.0 - 2 * margin) / span
    uv = (tri[:, :, :2] - (lo + hi) / 2.0) * scale
    uv[:, :, 1] *= -1.0  # image y down
    uv += S / 2.0
    return tri, n, uv


def render_mesh_rgba(
    mesh: trimesh.Trimesh,
    size_px: int = 256,
    azimuth_deg: float = -60.0,
    elevation_deg: float = 30.0,
    color_rgb: tuple[int, int, int] = (120, 150, 190),
    margin: float = 0.06,
) -> np.ndarray:
    """Render ``mesh`` into an RGBA uint8 image of shape (size_px, size_px, 4), transparent background.

    ``azimuth_deg`` is measured in the obj xy-plane from +x towards +y, ``elevation_deg`` above the
    xy-plane: (-60, 30) looks from the front-right (negative y, positive x) and above.
    """
    S = int(size_px) * _SUPERSAMPLE
    if len(mesh.faces) == 0:
        return np.zeros((size_px, size_px, 4), np.uint8)
    tri, n, uv = project_triangles(mesh, S, azimuth_deg, elevation_deg, margin)
    winner = _zbuffer(uv, tri[:, :, 2], S)  # (S, S) index into tri, -1 = background
    hit = winner >= 0
    key = np.array([0.3, 0.8, 0.5])
    fill = np.array([-0.7, -0.1, 0.4])
    key /= np.linalg.norm(key)
    fill /= np.linalg.norm(fill)
    shade = 0.32 + 0.63 * np.clip(n @ key, 0, None) + 0.25 * np.clip(n @ fill, 0, None)
    shade_px = np.zeros((S, S))
    shade_px[hit] = shade[winner[hit]]
    # Dark lines where the surface normal turns by more than ~25 degrees between neighbouring
    # pixels (creases) and at the silhouette: the usual CAD look, cheap in image space.
    nrm = np.zeros((S, S, 3))
    nrm[hit] = n[winner[hit]]
    edge = np.zeros((S, S), bool)
    for dy, dx in ((0, 1), (1, 0)):
        a, b = nrm[: S - dy, : S - dx], nrm[dy:, dx:]
        ha, hb = hit[: S - dy, : S - dx], hit[dy:, dx:]
        crease = (ha & hb & (np.sum(a * b, axis=2) < 0.9)) | (ha != hb)
        edge[: S - dy, : S - dx] |= crease & ha
        edge[dy:, dx:] |= crease & hb
    shade_px[edge & hit] *= 0.55
    rgb = np.clip(shade_px[:, :, None] * np.asarray(color_rgb, float)[None, None, :], 0, 255)
    alpha = hit.astype(float) * 255.0
    small = cv2.resize(rgb, (size_px, size_px), interpolation=cv2.INTER_AREA)
    small_a = cv2.resize(alpha, (size_px, size_px), interpolation=cv2.INTER_AREA)
    # un-premultiply the colour at anti-aliased borders (background was black)
    a = np.maximum(small_a, 1.0)[:, :, None] / 255.0
    out_rgb = np.clip(small / a, 0, 255).astype(np.uint8)
    return np.dstack([out_rgb, np.round(small_a).astype(np.uint8)])


def _zbuffer(uv: np.ndarray, z: np.ndarray, S: int) -> np.ndarray:
    """Vectorised scanline z-buffer: which triangle is nearest at each pixel centre.

    ``uv`` (F, 3, 2) pixel coordinates, ``z`` (F, 3) depth towards the viewer (bigger = nearer).
    Every triangle is cut into one span per pixel row (intersection of the row's centre line with
    its edges), spans are expanded to pixels with ``np.repeat`` (work ~ covered pixels, no bounding
    box waste), depth comes from the triangle's plane (exact for an orthographic view) and the
    nearest wins through one ``np.minimum.at`` on a key packing (quantised distance, triangle index).
    Returns (S, S) int64 triangle indices, -1 = background.
    """
    F = len(uv)
    best = np.full(S * S, np.iinfo(np.int64).max, dtype=np.int64)
    if F == 0:
        return np.full((S, S), -1, dtype=np.int64)
    a, b, c = uv[:, 0], uv[:, 1], uv[:, 2]
    # plane z = za + gx * (x - ax) + gy * (y - ay) of each triangle
    e1 = np.concatenate([b - a, (z[:, 1] - z[:, 0])[:, None]], axis=1)
    e2 = np.concatenate([c - a, (z[:, 2] - z[:, 0])[:, None]], axis=1)
    nrm = np.cross(e1, e2)
    valid = np.abs(nrm[:, 2]) > 1e-12
    gxz = np.where(valid, -nrm[:, 0] / np.where(valid, nrm[:, 2], 1.0), 0.0)
    gyz = np.where(valid, -nrm[:, 1] / np.where(valid, nrm[:, 2], 1.0), 0.0)

    ymin = np.ceil(uv[:, :, 1].min(axis=1) - 0.5).astype(np.int64)
    ymax = np.floor(uv[:, :, 1].max(axis=1) - 0.5).astype(np.int64)
    ymin, ymax = np.clip(ymin, 0, S), np.clip(ymax, -1, S - 1)
    rows = np.where(valid, np.maximum(ymax - ymin + 1, 0), 0)
    tri_r = np.repeat(np.arange(F), rows)
    if tri_r.size == 0:
        return np.full((S, S), -1, dtype=np.int64)
    start = np.cumsum(rows) - rows
    y = ymin[tri_r] + (np.arange(tri_r.size) - start[tri_r])
    py = y + 0.5
    xl = np.full(tri_r.size, np.inf)
    xr = np.full(tri_r.size, -np.inf)
    P = uv[tri_r]  # (R, 3, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        for i, j in ((0, 1), (1, 2), (2, 0)):
            p, q = P[:, i], P[:, j]
            dy = q[:, 1] - p[:, 1]
            t = (py - p[:, 1]) / dy
            hit = (dy != 0) & (t >= 0) & (t <= 1)
            x = p[:, 0] + t * (q[:, 0] - p[:, 0])
            xl = np.where(hit, np.minimum(xl, x), xl)
            xr = np.where(hit, np.maximum(xr, x), xr)
    ok = np.isfinite(xl) & np.isfinite(xr)
    xs = np.where(ok, np.ceil(np.where(ok, xl, 0) - 0.5), 0).astype(np.int64)
    xe = np.where(ok, np.floor(np.where(ok, xr, -1) - 0.5), -1).astype(np.int64)
    xs, xe = np.clip(xs, 0, S), np.clip(xe, -1, S - 1)
    cnt = np.maximum(xe - xs + 1, 0)
    row_p = np.repeat(np.arange(tri_r.size), cnt)
    if row_p.size == 0:
        return np.full((S, S), -1, dtype=np.int64)
    pstart = np.cumsum(cnt) - cnt
    x = xs[row_p] + (np.arange(row_p.size) - pstart[row_p])
    t_idx = tri_r[row_p]
    yy = y[row_p]
    depth = (z[t_idx, 0] + gxz[t_idx] * (x + 0.5 - a[t_idx, 0]) + gyz[t_idx] * (yy + 0.5 - a[t_idx, 1]))
    zmin, zmax = float(z.min()), float(z.max())
    zr = (zmax - zmin) or 1.0
    dist = np.clip(np.round((zmax - depth) / zr * (1 << 30)), 0, (1 << 31)).astype(np.int64)
    np.minimum.at(best, yy * S + x, (dist << 24) | t_idx)
    out = np.where(best == np.iinfo(np.int64).max, -1, best & ((1 << 24) - 1))
    return out.reshape(S, S)


def render_thumbnail(
    mesh: trimesh.Trimesh,
    size_px: int = 256,
    background_rgb: tuple[int, int, int] | None = (245, 246, 248),
    max_faces: int = 40_000,
    **view,
) -> bytes:
    """PNG thumbnail of ``mesh`` (size_px x size_px). ``background_rgb=None`` gives a transparent
    RGBA PNG, else an RGB PNG on that colour. Meshes above ``max_faces`` are drawn from a
    vertex-clustered simplification so that big uploads stay fast (sub-pixel detail is lost anyway).
    ``view`` is passed to :func:`render_mesh_rgba` (azimuth_deg, elevation_deg, color_rgb)."""
    if len(mesh.faces) > max_faces:
        mesh = _cluster_simplify(mesh, cells=max(64, int(np.sqrt(max_faces / 6.0))))
    rgba = render_mesh_rgba(mesh, size_px=size_px, **view)
    if background_rgb is None:
        out = cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA)
    else:
        a = rgba[:, :, 3:].astype(float) / 255.0
        bg = np.asarray(background_rgb, float)[None, None, :]
        rgb = (rgba[:, :, :3] * a + bg * (1 - a)).astype(np.uint8)
        out = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", out)
    if not ok:  # pragma: no cover - cv2 PNG encoding of a uint8 image does not fail
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def _cluster_simplify(mesh: trimesh.Trimesh, cells: int) -> trimesh.Trimesh:
    """Vertex clustering on a grid of ``cells`` per longest side: merge vertices per cell, drop
    collapsed faces. Crude but fast and robust; only for drawing."""
    lo = mesh.bounds[0]
    step = float(mesh.extents.max()) / max(cells, 1) or 1.0
    ijk = np.floor((mesh.vertices - lo) / step).astype(np.int64)
    key = (ijk[:, 0] * (cells + 2) + ijk[:, 1]) * (cells + 2) + ijk[:, 2]
    _, inverse = np.unique(key, return_inverse=True)
    inverse = inverse.reshape(-1)
    counts = np.bincount(inverse)
    verts = np.zeros((counts.size, 3))
    np.add.at(verts, inverse, mesh.vertices)
    verts /= counts[:, None]
    faces = inverse[mesh.faces]
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    out = trimesh.Trimesh(vertices=verts, faces=faces[keep], process=False)
    return out
