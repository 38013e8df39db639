"""Synthetic camera images of a machine table with markers and objects, with exact ground truth.

``render_scene(scene, rng)`` draws a :class:`Scene` (table mesh with an ArUco layout, objects at
``T_table_obj``, a camera with OpenCV intrinsics at ``T_cam_table``) into a grey 8-bit image plus
depth, per-pixel labels and the ground truth (poses, marker corners in px).

How it renders
--------------
* Exact OpenCV lens model: every sample position in the distorted output image is mapped through
  the inverse of OpenCV's model (``cv2.undistortPoints`` iterated to 1e-15 on a 4 px grid, bilinear
  in between: < 1e-3 px) to an ideal ray; triangles are rasterized against those rays (numpy
  z-buffer, :mod:`app.synth.raster`). Straight edges thus bend exactly as OpenCV's model says and
  ``cv2.projectPoints`` of a 3D point lands on its image.
* Adaptive anti-aliasing: one sample at every pixel centre; pixels whose 3x3 neighbourhood shows
  another surface (coplanar faces of one object count as one surface, so the seams of a
  tessellated flat face are no edges) or a radiance step (> ``edge_threshold``: marker cells,
  shadow borders) get ``samples_per_axis``\\ ² (default 4 x 4) stratified jittered samples, each
  resolved EXACTLY against the triangles seen around the pixel and shaded, averaged in linear
  radiance. A sample in a sliver triangle that no pixel centre sees falls on the plane of the
  pixel's own triangle (unless background is near). Edge coverage is thus unbiased (no grid
  quantisation); the jitter adds a little per-pixel noise on edges (std of the edge position
  <= ~0.06 px per pixel, averaging out along an edge). Features thinner than about a pixel that
  no pixel centre sees can be missed. Back faces of proper volumes are culled; open or
  inside-out meshes are drawn two-sided.
* Table top: procedural machined-grey texture; markers (``cv2.aruco.generateImageMarker``) are
  evaluated exactly at each sample's ray-plane intersection, on a white label of one cell margin.
* Shading: Lambert per flat face, ``albedo * (ambient + (1 - ambient) * max(0, n.l) * lit)`` with a
  directional light; ``lit`` from an orthographic shadow map (0.5 mm texels, bilinear PCF; baked
  into a 1 mm texture for the table top) of the table and the objects, so objects cast shadows on the table and on each other, slot walls into
  the slots.
* Camera: optical blur (Gaussian, in linear radiance), gamma encoding ``255 * L^(1/gamma)``,
  additive Gaussian noise in grey levels, 8-bit quantisation, optional JPEG.
* Labels and depth are those at the pixel centres.

What it does NOT model
----------------------
Specular highlights and reflections of the machined metal, interreflections (no light bounced
from the table onto the part's shadowed faces beyond the constant ambient), soft light sources
(shadow penumbra is only the shadow map's filtering), smooth shading of curved surfaces (faceted
cylinders show their facets), chamfers and rounded edges unless they are in the mesh, depth of
field, rolling shutter, motion blur, chromatic aberration, colour (grey only), sensor
non-uniformity (PRNU/DSNU), signal-dependent (shot) noise, chips/coolant/dirt, markers off the table
top plane (layouts with tilted or raised markers are refused), printing errors of the markers,
light falling through T-slots (the table is one closed body lit by one directional light).

Speed: about 4-5 s CPU for 1920 x 1200 with the T-slot table and a few library parts (numpy,
single thread).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
import trimesh

from app.geometry.transforms import check_pose, inv, make_pose, transform_points
from app.synth.raster import (SampleGrid, candidate_triangles, make_undistort_grid,
                              orthographic_triangles, resolve_samples,
                              perspective_triangles, rasterize)
from app.synth.table import (TableTopAlbedo, box_table_layout, box_table_mesh,
                             marker_corners_table, printed_markers)

BACKGROUND_RADIANCE = 0.08   # dark machine interior behind the table


@dataclass
class SceneObject:
    """An object on the table: mesh in its own CAD frame (mm) and its pose on the table."""

    name: str
    mesh: trimesh.Trimesh
    T_table_obj: np.ndarray
    albedo: float = 0.55


def _default_light() -> np.ndarray:
    v = np.array([0.35, -0.45, 0.82])
    return v / np.linalg.norm(v)


@dataclass
class Scene:
    """Everything needed to render one image. Poses 4x4 in mm, frames as in DESIGN.

    ``T_cam_table`` is the pose of the table in the camera frame (OpenCV camera axes);
    ``table_mesh`` is in the table frame with its top face at z = 0, z up; ``table_layout`` is the
    DESIGN fiducial layout; ``light_dir_table`` a unit vector pointing towards the light.
    """

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    T_cam_table: np.ndarray
    table_mesh: trimesh.Trimesh
    table_layout: dict
    objects: list[SceneObject]
    light_dir_table: np.ndarray = field(default_factory=_default_light)
    ambient: float = 0.35
    shadows: bool = True
    noise_sigma: float = 2.0
    blur_sigma_px: float = 0.6
    gamma: float = 2.2
    jpeg_quality: int | None = 92
    samples_per_axis: int = 4
    edge_threshold: float = 0.04
    table_albedo: float = 0.42
    texture_seed: int = 0
    marker_margin_cells: float = 1.0
    exposure: float = 1.0
    vignetting: float = 0.0          # radiance falls by this share from the centre to the corners (r^2)


@dataclass
class Rendered:
    """A rendered image with its ground truth.

    image : (H, W) uint8 grey (after blur, gamma, noise, JPEG).
    radiance : (H, W) float32 linear radiance before blur/gamma/noise (for diagnostics).
    depth_mm : (H, W) float32, z of the surface in the camera frame at the pixel centre, inf if none.
    labels : (H, W) int16, 0 background, 1 table, 2 + i object i, at the pixel centre.
    truth : dict with "K", "dist", "T_cam_table", "T_table_obj" {name: 4x4}, "T_cam_obj"
        {name: 4x4}, "marker_corners_px" {id: (4, 2) in OpenCV corner order, distorted pixels},
        "marker_visible" {id: bool} (all four corners inside the image and the marker unoccluded).
    """

    image: np.ndarray
    radiance: np.ndarray
    depth_mm: np.ndarray
    labels: np.ndarray
    truth: dict


# ---------------------------------------------------------------------------------------------

@dataclass
class _Faces:
    V_cam: np.ndarray        # (F, 3, 3)
    label: np.ndarray        # (F,) int16
    albedo: np.ndarray       # (F,) float32
    lambert: np.ndarray      # (F,) float32 max(0, n.l)
    top: np.ndarray          # (F,) bool: table top face (textured)
    bias_mm: np.ndarray      # (F,) shadow-map depth bias
    closed: np.ndarray       # (F,) bool: face of a watertight mesh (may be back-face culled)
    surface: np.ndarray      # (F,) int: coplanar faces of one object share a surface id
    ndotl: np.ndarray        # (F,) signed n.l of the face's stored normal


def _collect_faces(scene: Scene, T_cam_table: np.ndarray, light: np.ndarray) -> _Faces:
    Vs, labels, albedo, lam, top, closed = [], [], [], [], [], []
    meshes = [(scene.table_mesh, np.eye(4), 1, scene.table_albedo)]
    for i, ob in enumerate(scene.objects):
        T = check_pose(ob.T_table_obj, f"T_table_obj of {ob.name}")
        meshes.append((ob.mesh, T, 2 + i, float(ob.albedo)))
    for k, (mesh, T_table_m, lab, alb) in enumerate(meshes):
        V_t = transform_points(T_table_m, mesh.vertices)[mesh.faces]      # (F, 3, 3) table frame
        n = np.cross(V_t[:, 1] - V_t[:, 0], V_t[:, 2] - V_t[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        Vs.append(V_t)
        closed.append(np.full(len(V_t), bool(mesh.is_volume)))   # watertight, outward normals
        labels.append(np.full(len(V_t), lab, np.int16))
        albedo.append(np.full(len(V_t), alb, np.float32))
        lam.append((n @ light).astype(np.float32))            # signed n.l; clipped below
        if k == 0:
            top.append((n[:, 2] > 1 - 1e-6) & (np.abs(V_t[:, :, 2]).max(axis=1) < 1e-6))
        else:
            top.append(np.zeros(len(V_t), bool))
    V_t = np.concatenate(Vs)
    # surfaces: faces of one object in one plane (a tessellated flat face, the table top's lands);
    # boundaries between their triangles are not edges of the picture
    nrm = np.cross(V_t[:, 1] - V_t[:, 0], V_t[:, 2] - V_t[:, 0])
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    key = np.column_stack([np.concatenate(labels), np.round(nrm * 1e4),
                           np.round(np.einsum("ij,ij->i", nrm, V_t[:, 0]) * 100)]).astype(np.int64)
    surface = np.unique(key, axis=0, return_inverse=True)[1].reshape(-1)
    ndotl = np.concatenate(lam)
    lam_all = np.clip(ndotl, 0, 1)
    sin_ = np.sqrt(np.clip(1 - lam_all.astype(np.float64) ** 2, 0, 1))
    tan_ = np.clip(sin_ / np.maximum(lam_all, 1e-3), 0, 8)
    V_cam = (V_t.reshape(-1, 3) @ T_cam_table[:3, :3].T + T_cam_table[:3, 3]).reshape(-1, 3, 3)
    return _Faces(V_cam=V_cam, label=np.concatenate(labels), albedo=np.concatenate(albedo),
                  lambert=lam_all, top=np.concatenate(top), bias_mm=0.4 + 0.5 * tan_,
                  closed=np.concatenate(closed), ndotl=ndotl, surface=surface)


class _ShadowMap:
    """Orthographic depth map of the objects seen from the (directional) light."""

    def __init__(self, scene: Scene | None, light: np.ndarray, texel_mm: float = 0.5,
                 max_texels: int = 3000) -> None:
        self.empty = scene is None
        if self.empty:
            return
        z = -light                                    # projection direction, away from the light
        a = np.array([1.0, 0, 0]) if abs(z[0]) < 0.9 else np.array([0, 1.0, 0])
        x = np.cross(a, z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        self.R_l_table = np.stack([x, y, z])          # rows: light-frame axes in table frame
        Vs = []
        casters = [(np.eye(4), scene.table_mesh)] + [(ob.T_table_obj, ob.mesh) for ob in scene.objects]
        for T, mesh in casters:   # the table too: its T-slot walls shade the slots
            V_t = transform_points(T, mesh.vertices)[mesh.faces]
            Vs.append(V_t.reshape(-1, 3) @ self.R_l_table.T)
        V_l = np.concatenate(Vs).reshape(-1, 3, 3)
        lo = V_l[:, :, :2].reshape(-1, 2).min(0) - 2 * texel_mm
        hi = V_l[:, :, :2].reshape(-1, 2).max(0) + 2 * texel_mm
        texel = max(texel_mm, float((hi - lo).max()) / max_texels)
        nx, ny = (np.ceil((hi - lo) / texel).astype(int) + 1)
        gx, gy = np.meshgrid(lo[0] + texel * np.arange(nx), lo[1] + texel * np.arange(ny))
        grid = SampleGrid(gx, gy)
        self.depth = np.full((ny, nx), np.inf)
        ids = np.full((ny, nx), -1, np.int32)
        rasterize(grid, orthographic_triangles(V_l, np.arange(len(V_l))), self.depth, ids)
        self.lo, self.texel = lo, texel
        self.depth_pad = np.pad(self.depth.astype(np.float32), 1, constant_values=np.inf)

    def lit(self, P_table: np.ndarray, bias_mm: np.ndarray) -> np.ndarray:
        """Fraction (N,) of light reaching table-frame points (N, 3), bilinear PCF."""
        res = np.ones(len(P_table), np.float32)
        if self.empty or len(P_table) == 0:
            return res
        ny, nx = self.depth.shape
        R = self.R_l_table
        P = np.asarray(P_table)
        x, y, z = P[:, 0], P[:, 1], P[:, 2]
        gx = ((R[0, 0] * x + R[0, 1] * y + R[0, 2] * z) - self.lo[0]) * (1.0 / self.texel)
        gy = ((R[1, 0] * x + R[1, 1] * y + R[1, 2] * z) - self.lo[1]) * (1.0 / self.texel)
        inb = np.nonzero((gx > -1) & (gx < nx) & (gy > -1) & (gy < ny))[0]
        if len(inb) == 0:
            return res
        if len(inb) < len(P):
            x, y, z, gx, gy = x[inb], y[inb], z[inb], gx[inb], gy[inb]
            bias_mm = np.asarray(bias_mm)[inb]
        gx = (gx + 1).astype(np.float32)                 # +1: padded map
        gy = (gy + 1).astype(np.float32)
        zb = (R[2, 0] * x + R[2, 1] * y + R[2, 2] * z - bias_mm).astype(np.float32)
        ix = np.clip(gx.astype(np.int32), 0, nx)         # gx > 0 here: truncation = floor
        iy = np.clip(gy.astype(np.int32), 0, ny)
        fx = np.clip(gx - ix, 0, 1)
        fy = np.clip(gy - iy, 0, 1)
        D = self.depth_pad.ravel()
        stride = nx + 2
        i00 = iy.astype(np.int64) * stride + ix
        top = (1 - fx) * (zb <= D[i00]) + fx * (zb <= D[i00 + 1])
        bot = (1 - fx) * (zb <= D[i00 + stride]) + fx * (zb <= D[i00 + stride + 1])
        res[inb] = (1 - fy) * top + fy * bot
        return res


def _shade(scene: Scene, faces: _Faces, albedo_top: TableTopAlbedo, shadow: _ShadowMap,
           T_table_cam: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray,
           face: np.ndarray) -> np.ndarray:
    """Linear radiance at samples: plane coords x, y, depth z (mm), face index (-1: none)."""
    rad = np.full(x.shape, BACKGROUND_RADIANCE, np.float32)
    hit = np.nonzero(face.ravel() >= 0)[0]
    if len(hit) == 0:
        return rad
    f = face.ravel()[hit]
    alb = faces.albedo[f]
    lam = faces.lambert[f]
    top = np.nonzero(faces.top[f])[0]
    need = np.nonzero(faces.top[f] | (lam > 0))[0]
    if len(need):
        k = hit[need]
        zz = z.ravel()[k]
        xx = x.ravel()[k] * zz
        yy = y.ravel()[k] * zz
        R, t = T_table_cam[:3, :3], T_table_cam[:3, 3]
        P_tab = np.empty((len(k), 3))
        for r in range(3):
            P_tab[:, r] = R[r, 0] * xx + R[r, 1] * yy + R[r, 2] * zz + t[r]
        pos = np.full(len(f), -1, np.int64)
        pos[need] = np.arange(len(need))
        lam = lam.copy()
        if len(top):
            xt, yt = P_tab[pos[top], 0], P_tab[pos[top], 1]
            alb[top] = albedo_top(xt, yt)
            if scene.shadows:
                lam[top] *= albedo_top.lit(xt, yt)
        if scene.shadows and not shadow.empty:
            lit_i = np.nonzero((lam > 0) & ~faces.top[f])[0]
            lam[lit_i] *= shadow.lit(P_tab[pos[lit_i]], faces.bias_mm[f[lit_i]])
    rad.ravel()[hit] = scene.exposure * alb * (scene.ambient + (1 - scene.ambient) * lam)
    return rad


def _jitter_rays(xc: np.ndarray, yc: np.ndarray, v: np.ndarray, u: np.ndarray, du: np.ndarray,
                 dv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rays of sample positions (u + du, v + dv), |du|, |dv| <= 0.5, from the pixel-centre rays
    ``xc, yc`` (H, W) and their local derivative (central differences): the lens map is smooth, so
    the second-order error over half a pixel is ~1e-6 px."""
    H, W = xc.shape
    ul, ur = np.maximum(u - 1, 0), np.minimum(u + 1, W - 1)
    vu, vd = np.maximum(v - 1, 0), np.minimum(v + 1, H - 1)
    out = []
    for m in (xc, yc):
        gu = (m[v, ur] - m[v, ul]) / (ur - ul)
        gv = (m[vd, u] - m[vu, u]) / (vd - vu)
        out.append(m[v, u][:, None] + gu[:, None] * du + gv[:, None] * dv)
    return out[0], out[1]


def render_scene(scene: Scene, rng: np.random.Generator) -> Rendered:
    """Render ``scene``; all randomness (jitter, noise) comes from ``rng`` (same seed, same image)."""
    W, H = int(scene.width), int(scene.height)
    K = np.asarray(scene.K, float)
    dist = np.zeros(5) if scene.dist is None else np.asarray(scene.dist, float).reshape(-1)
    T_cam_table = check_pose(scene.T_cam_table, "T_cam_table")
    T_table_cam = inv(T_cam_table)
    light = np.asarray(scene.light_dir_table, float)
    light = light / np.linalg.norm(light)

    faces = _collect_faces(scene, T_cam_table, light)
    # back faces of closed meshes cannot be seen: cull them (about half the work)
    n_cam = np.cross(faces.V_cam[:, 1] - faces.V_cam[:, 0], faces.V_cam[:, 2] - faces.V_cam[:, 0])
    back = np.einsum("ij,ij->i", n_cam, faces.V_cam[:, 0]) > 0
    front = ~(faces.closed & back)
    # open meshes (user CAD with holes or flipped triangles) are lit on the side the camera sees
    flip = back & ~faces.closed
    faces.lambert[flip] = np.clip(-faces.ndotl[flip], 0, 1)
    tris = perspective_triangles(faces.V_cam[front], np.nonzero(front)[0])
    markers = printed_markers(scene.table_layout, scene.marker_margin_cells)
    b = scene.table_mesh.bounds
    albedo_top = TableTopAlbedo(b[:, :2], markers, base=scene.table_albedo,
                                seed=scene.texture_seed)
    shadow = _ShadowMap(scene if scene.shadows else None, light)
    if scene.shadows:
        top_bias = 0.4 + 0.5 * np.sqrt(max(0.0, 1 - light[2] ** 2)) / max(light[2], 1e-3)
        albedo_top.set_shadow(lambda P: shadow.lit(P, np.full(len(P), top_bias)))
    ugrid = make_undistort_grid(K, dist, W, H)

    def shade(x, y, z, t):
        face = np.where(t >= 0, tris.ids[np.maximum(t, 0)], -1)
        return _shade(scene, faces, albedo_top, shadow, T_table_cam, x, y, z, face)

    # 1. Pixel centres: depth, labels and the radiance of pixels without an edge inside.
    xc, yc = ugrid.lookup_pixel_grid(W, H)
    zbuf = np.full((H, W), np.inf)
    tbuf = np.full((H, W), -1, np.int32)
    rasterize(SampleGrid(xc, yc), tris, zbuf, tbuf)
    face_c = np.where(tbuf >= 0, tris.ids[np.maximum(tbuf, 0)], -1)
    labels = np.where(face_c >= 0, faces.label[np.maximum(face_c, 0)], 0).astype(np.int16)
    depth = zbuf.astype(np.float32)
    radiance = shade(xc, yc, zbuf, tbuf)

    # 2. Pixels that may hold an edge (triangle, texture, marker or shadow boundary): a 3x3
    #    neighbour differs. Any straight boundary crossing a pixel separates two of the 3x3
    #    centres around it, so this finds every boundary wider than the pixel spacing.
    surf = np.where(face_c >= 0, faces.surface[np.maximum(face_c, 0)], -1)
    edge = np.zeros((H, W), bool)
    bg_near = surf < 0                      # background at or next to the pixel centre
    for dv, du in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = (slice(0, H - dv), slice(max(0, -du), W - max(0, du)))
        bsl = (slice(dv, H), slice(max(0, du), W - max(0, -du)))
        diff = (surf[a] != surf[bsl]) | (np.abs(radiance[a] - radiance[bsl]) > scene.edge_threshold)
        edge[a] |= diff
        edge[bsl] |= diff
        bg_near[a] |= surf[bsl] < 0
        bg_near[bsl] |= surf[a] < 0
    ev, eu = np.nonzero(edge)

    # 3. Edge pixels: s x s stratified jittered samples, each resolved exactly against the
    #    triangles seen around the pixel, shaded, averaged in linear radiance.
    s = max(1, int(scene.samples_per_axis))
    if len(ev):
        cands = candidate_triangles(tbuf, ev, eu)
        # a sample that hits none of the triangles seen at the 3x3 centres fell into a sliver
        # triangle thinner than a pixel (CAD tessellation); unless background is near, it lies
        # on the plane of the pixel's own triangle
        fallback = np.where(bg_near[ev, eu], -1, tbuf[ev, eu])
        gi, gj = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
        gi, gj = gi.ravel(), gj.ravel()
        acc = np.zeros(len(ev))
        chunk = max(1, 2_000_000 // (s * s))
        for c0 in range(0, len(ev), chunk):
            sl = slice(c0, c0 + chunk)
            n = len(ev[sl])
            du = (gi[None] + rng.random((n, s * s))) / s - 0.5
            dv = (gj[None] + rng.random((n, s * s))) / s - 0.5
            x, y = _jitter_rays(xc, yc, ev[sl], eu[sl], du, dv)
            z, t = resolve_samples(tris, cands[sl], x, y, fallback=fallback[sl])
            acc[sl] = shade(x, y, z, t).mean(axis=1)
        radiance[ev, eu] = acc
    del xc, yc
    radiance = radiance.astype(np.float32)

    img = radiance
    if scene.vignetting > 0:            # lens falloff: darker towards the corners, before the noise
        Hr, Wr = img.shape
        vv, uu = np.mgrid[0:Hr, 0:Wr].astype(np.float32)
        r2 = ((uu - K[0, 2]) ** 2 + (vv - K[1, 2]) ** 2) / float(max(K[0, 2], Wr - K[0, 2]) ** 2 +
                                                               max(K[1, 2], Hr - K[1, 2]) ** 2)
        img = img * (1.0 - float(scene.vignetting) * r2)
    if scene.blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), scene.blur_sigma_px, borderType=cv2.BORDER_REPLICATE)
    img = 255.0 * np.clip(img, 0, 1) ** (1.0 / scene.gamma)
    if scene.noise_sigma > 0:
        img = img + rng.normal(0.0, scene.noise_sigma, img.shape)
    img = np.clip(np.round(img), 0, 255).astype(np.uint8)
    if scene.jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(scene.jpeg_quality)])
        img = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)

    truth = _truth(scene, K, dist, T_cam_table, markers, labels, depth)
    truth["edge_pixel_fraction"] = float(len(ev)) / (W * H)
    return Rendered(image=img, radiance=radiance, depth_mm=depth, labels=labels, truth=truth)


def project_points(K: np.ndarray, dist: np.ndarray, T_cam_x: np.ndarray,
                   p_x: np.ndarray) -> np.ndarray:
    """Project points (N, 3) given in frame x with OpenCV's model: (N, 2) distorted px."""
    p_cam = transform_points(T_cam_x, p_x)
    uv, _ = cv2.projectPoints(p_cam, np.zeros(3), np.zeros(3), K, dist)
    return uv.reshape(-1, 2)


def _truth(scene: Scene, K, dist, T_cam_table, markers, labels, depth) -> dict:
    H, W = labels.shape
    corners, visible = {}, {}
    for m in markers:
        c_t = marker_corners_table(m)
        uv = project_points(K, dist, T_cam_table, c_t)
        corners[m.id] = uv
        # Visible: corners in the image, all in front of the camera, and a 7x7 grid of points of the
        # marker (incl. its border) seen on the table at the expected depth.
        g = np.linspace(-0.5, 0.5, 7) * m.size_mm
        gx, gy = np.meshgrid(g, g)
        pts = transform_points(m.T_table_marker, np.column_stack([gx.ravel(), gy.ravel(),
                                                                   np.zeros(gx.size)]))
        p_cam = transform_points(T_cam_table, pts)
        ok = bool(np.all(p_cam[:, 2] > 1) and np.all(transform_points(T_cam_table, c_t)[:, 2] > 1))
        ok = ok and bool(np.all((uv >= 0) & (uv <= [W - 1, H - 1])))
        if ok:
            puv = project_points(K, dist, T_cam_table, pts)
            iu = np.clip(np.round(puv[:, 0]).astype(int), 0, W - 1)
            iv = np.clip(np.round(puv[:, 1]).astype(int), 0, H - 1)
            ok = bool(np.all(labels[iv, iu] == 1)
                      and np.all(np.abs(depth[iv, iu] - p_cam[:, 2]) < 0.02 * p_cam[:, 2]))
        visible[m.id] = ok
    T_table_obj = {ob.name: np.asarray(ob.T_table_obj, float) for ob in scene.objects}
    return {
        "K": K.copy(), "dist": dist.copy(), "T_cam_table": T_cam_table.copy(),
        "T_table_obj": T_table_obj,
        "T_cam_obj": {n: T_cam_table @ T for n, T in T_table_obj.items()},
        "marker_corners_px": corners, "marker_visible": visible,
    }


# ---------------------------------------------------------------------------------------------
# Random scenes
# ---------------------------------------------------------------------------------------------

def default_table() -> tuple[trimesh.Trimesh, dict]:
    """The library's T-slot table 800 x 400 with its layout, or the stand-in box table."""
    try:
        from app.geometry.parts import tslot_table, tslot_table_layout
    except ImportError:
        return box_table_mesh(), box_table_layout()
    return tslot_table(), tslot_table_layout()


def default_objects() -> list[tuple[str, trimesh.Trimesh]]:
    """A few simple parts (CAD frame: origin at the bottom face's corner/centre, z up)."""
    block = trimesh.creation.box(extents=(150.0, 100.0, 45.0))
    block.apply_translation((75.0, 50.0, 22.5))
    cyl = trimesh.creation.cylinder(radius=35.0, height=60.0, sections=48)
    cyl.apply_translation((0, 0, 30.0))
    foot = trimesh.creation.box(extents=(120.0, 60.0, 20.0))
    foot.apply_translation((60.0, 30.0, 10.0))
    web = trimesh.creation.box(extents=(20.0, 60.0, 60.0))
    web.apply_translation((10.0, 30.0, 50.0))
    angle = trimesh.util.concatenate([foot, web])
    return [("block", block), ("round", cyl), ("angle", angle)]


def look_at_pose(cam_pos_table: np.ndarray, target_table: np.ndarray,
                 roll_deg: float = 0.0) -> np.ndarray:
    """``T_cam_table`` of a camera at ``cam_pos_table`` looking at ``target_table`` (image up ~ +z)."""
    zc = np.asarray(target_table, float) - np.asarray(cam_pos_table, float)
    zc /= np.linalg.norm(zc)
    up = np.array([0, 0, 1.0])
    yc = -(up - (up @ zc) * zc)
    if np.linalg.norm(yc) < 1e-6:
        yc = np.array([0, 1.0, 0]) - zc[1] * zc
    yc /= np.linalg.norm(yc)
    xc = np.cross(yc, zc)
    R_table_cam = np.column_stack([xc, yc, zc])
    r = np.radians(roll_deg)
    Rz = np.array([[np.cos(r), -np.sin(r), 0], [np.sin(r), np.cos(r), 0], [0, 0, 1]])
    T_table_cam = make_pose(R_table_cam @ Rz, cam_pos_table)
    return inv(T_table_cam)


def place_on_table(mesh: trimesh.Trimesh, x_mm: float, y_mm: float, c_deg: float,
                   z_mm: float = 0.0) -> np.ndarray:
    """``T_table_obj`` putting the mesh (in its CAD orientation) with its lowest point at ``z_mm``,
    its bounding-box centre at (x, y), rotated ``c_deg`` about the table's z."""
    c = np.radians(c_deg)
    R = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    b = mesh.bounds
    centre = np.array([(b[0, 0] + b[1, 0]) / 2, (b[0, 1] + b[1, 1]) / 2, b[0, 2]])
    t = np.array([x_mm, y_mm, z_mm]) - R @ centre
    return make_pose(R, t)


def random_intrinsics(rng: np.random.Generator, width: int, height: int,
                      focal_px: tuple[float, float] = (1400.0, 2000.0),
                      distortion: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Plausible machine-vision intrinsics: square pixels, centre near the middle, mild distortion."""
    f = rng.uniform(*focal_px)
    K = np.array([[f * rng.uniform(0.998, 1.002), 0, width / 2 + rng.uniform(-25, 25)],
                  [0, f, height / 2 + rng.uniform(-20, 20)], [0, 0, 1.0]])
    if distortion:
        dist = np.array([rng.uniform(-0.15, 0.05), rng.uniform(-0.05, 0.12),
                         rng.uniform(-5e-4, 5e-4), rng.uniform(-5e-4, 5e-4),
                         rng.uniform(-0.03, 0.03)])
    else:
        dist = np.zeros(5)
    return K, dist


def random_scene(rng: np.random.Generator, *, width: int = 1920, height: int = 1200,
                 distance_mm: tuple[float, float] = (500.0, 1300.0),
                 objects: list[SceneObject] | None = None,
                 table_mesh: trimesh.Trimesh | None = None, table_layout: dict | None = None,
                 elevation_deg: tuple[float, float] = (30.0, 80.0),
                 focal_px: tuple[float, float] = (1400.0, 2000.0), distortion: bool = True,
                 min_visible_markers: int = 0, max_tries: int = 50, **scene_kw) -> Scene:
    """A random but plausible scene.

    The camera is ``distance_mm`` from a target point near the table centre (or the objects'
    centre), at an elevation ``elevation_deg`` above the table plane, any azimuth, roll +-10 deg.
    Without ``objects`` three default parts are placed at random, non-overlapping, on the table.
    ``min_visible_markers``: resample the camera until at least that many markers are fully in
    the image (occlusion by objects is not checked here; see ``Rendered.truth['marker_visible']``).
    Extra keyword arguments set :class:`Scene` fields (noise_sigma, shadows, ...).
    """
    if table_mesh is None:
        table_mesh, lay = default_table()
        table_layout = lay if table_layout is None else table_layout
    if table_layout is None:
        raise ValueError("a table_mesh was given without its table_layout")
    b = table_mesh.bounds
    L, Wt = b[1, 0] - b[0, 0], b[1, 1] - b[0, 1]
    centre = np.array([(b[0, 0] + b[1, 0]) / 2, (b[0, 1] + b[1, 1]) / 2, 0.0])
    if objects is None:
        objects = []
        placed: list[tuple[float, float, float]] = []
        for name, mesh in default_objects():
            r = float(np.linalg.norm(mesh.extents[:2])) / 2
            for _ in range(100):
                x = rng.uniform(b[0, 0] + 90 + r, b[1, 0] - 90 - r)
                y = rng.uniform(b[0, 1] + 75 + r, b[1, 1] - 75 - r) if Wt > 150 + 2 * r else centre[1]
                if all(np.hypot(x - px, y - py) > r + pr + 10 for px, py, pr in placed):
                    break
            placed.append((x, y, r))
            objects.append(SceneObject(name, mesh, place_on_table(mesh, x, y, rng.uniform(0, 360)),
                                       albedo=float(rng.uniform(0.45, 0.7))))
    K, dist = random_intrinsics(rng, width, height, focal_px, distortion)
    markers = printed_markers(table_layout)
    T = None
    for _ in range(max_tries):
        target = centre + np.array([rng.uniform(-L / 6, L / 6), rng.uniform(-Wt / 6, Wt / 6), 0])
        d = rng.uniform(*distance_mm)
        el = np.radians(rng.uniform(*elevation_deg))
        az = rng.uniform(0, 2 * np.pi)
        pos = target + d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        T = look_at_pose(pos, target, rng.uniform(-10, 10))
        if min_visible_markers <= 0:
            break
        n_in = 0
        # beyond ~1.5x the image corner's field angle OpenCV's polynomial can fold back into the
        # image: such points are not "in view"
        r_max = 1.5 * np.hypot(max(K[0, 2], width - K[0, 2]) / K[0, 0],
                               max(K[1, 2], height - K[1, 2]) / K[1, 1])
        for m in markers:
            p = transform_points(T, marker_corners_table(m))
            if np.any(p[:, 2] < 10) or np.any(np.hypot(p[:, 0], p[:, 1]) / p[:, 2] > r_max):
                continue
            uv = project_points(K, dist, T, marker_corners_table(m))
            n_in += bool(np.all((uv >= 2) & (uv <= [width - 3, height - 3])))
        if n_in >= min_visible_markers:
            break
    return Scene(width=width, height=height, K=K, dist=dist, T_cam_table=T, table_mesh=table_mesh,
                 table_layout=table_layout, objects=objects, **scene_kw)
