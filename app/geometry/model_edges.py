"""Edge models of CAD parts for image matching: feature edges, silhouettes, hidden lines, resting
states and rotational symmetry.

A model is prepared once (:func:`prepare_model`, picklable, so callers may cache it) and then asked,
for one pose ``T_cam_obj`` and one camera, which of its edges the camera sees
(:func:`visible_edge_samples`): crease edges with at least one front-facing face, silhouette edges
(front face next to a back face) and no edge hidden behind the model itself or behind other
models (occluders such as vise jaws), decided by a z-buffer.

Conventions (DESIGN.md): poses ``T_a_b`` 4x4, mm; pixel coordinates ``uv_px`` (N, 2) are OpenCV's
(u right, v down) with pixel centres at integer coordinates; the camera model is OpenCV's pinhole with
distortion ``dist = (k1, k2, p1, p2, k3)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from app.geometry.feature_edges import boundary_edges, feature_edges
from app.geometry.mesh import resting_poses
from app.geometry.raster_kernels import raster_min_depth, span_pixel_count
from app.geometry.transforms import inv, make_pose, transform_points

__all__ = [
    "RestingState",
    "Symmetry",
    "PreparedModel",
    "EdgeSamples",
    "prepare_model",
    "project_points_px",
    "face_planes",
    "render_depth",
    "visible_edge_samples",
    "resting_pose",
    "detect_symmetries",
    "EDGE_MODEL_VERSION",
]

#: bumped whenever the edges prepare_model picks from a mesh can change: key pickled PreparedModels
#: with it. 2: creases from features, not tessellation (coarse facets and scan noise, feature_edges.py)
EDGE_MODEL_VERSION = 2


# --------------------------------------------------------------------------------------------------
# data
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class RestingState:
    """One way the part can lie on a flat table.

    T_rest_obj : ndarray (4, 4)
        Pose of the obj (CAD) frame in the resting frame; the resting frame has z up, its xy plane is
        the table top (the part's lowest point at z = 0) and its origin under the part's centre of mass.
        A part in this state at (x, y) rotated by theta about the table normal is at
        ``T_table_obj = Trans(x, y, h) @ Rz(theta) @ T_rest_obj`` (see :func:`resting_pose`).
    probability : float
        Quasi-static probability of the state from :func:`trimesh.poses.compute_stable_poses`.
    height_mm : float
        Height of the part's top above the table in this state.
    same_as : int
        Index of an earlier state that is the same state up to a symmetry of the part, or -1.
    cad_axis : str
        ``"+z"`` / ``"-z"`` when the state stands the part with its CAD z axis up / down (how parts
        are modelled for machining, and how a vise holds them), else ``""``. These stances are always
        searched, however unlikely a random drop would end in them.
    """

    T_rest_obj: np.ndarray
    probability: float
    height_mm: float
    same_as: int = -1
    cad_axis: str = ""


@dataclass(frozen=True, eq=False)
class Symmetry:
    """A rotation that maps the part onto itself, as a pose ``S = T_obj_obj'``.

    If ``T_table_obj`` fits the image, so does ``T_table_obj @ S`` (the same shape, a different datum).
    ``exact`` symmetries map the whole surface (within ``max_dev_mm``) and cannot be told apart in any
    image; "near" ones map the outline but not small features (holes, chamfers): the fit must decide by
    those features and report how sure it is.
    """

    S: np.ndarray
    axis_obj: np.ndarray
    angle_deg: float
    matched_fraction: float
    exact: bool

    def to_dict(self) -> dict:
        return {"S": self.S.tolist(), "axis_obj": self.axis_obj.tolist(), "angle_deg": self.angle_deg,
                "matched_fraction": self.matched_fraction, "exact": self.exact}


@dataclass(frozen=True, eq=False)
class PreparedModel:
    """A CAD model prepared for edge matching (build it with :func:`prepare_model`).

    Edge arrays describe the mesh edges that can ever show in an image: crease edges (the part's
    surfaces meeting at more than ``feature_angle_deg``; :mod:`app.geometry.feature_edges`), boundary
    edges, and curved-surface edges (the facets of a bore, a fillet, a scan) that show as silhouettes
    only. On a noisy (scanned) mesh a crease's samples lie on the line where its two surfaces'
    fitted planes meet, and ``denoised_normals`` replace the mesh's own face normals wherever the
    model asks which way a face turns (:attr:`face_normals`).
    """

    name: str
    mesh: trimesh.Trimesh
    edge_vertices: np.ndarray        # (E, 2) vertex indices
    edge_faces: np.ndarray           # (E, 2) adjacent face indices, -1 for a boundary edge
    edge_feature: np.ndarray         # (E,) bool: crease/boundary (True) or smooth, silhouette only
    samples_obj: np.ndarray          # (S, 3) points on the edges, obj frame, mm
    sample_edge: np.ndarray          # (S,) edge index of each sample
    sample_dir_obj: np.ndarray       # (S, 3) unit direction of the sample's edge
    sample_corner_mm: np.ndarray     # (S,) distance to the nearest corner (end of a straight run), mm
    sample_step_mm: float
    resting_states: tuple[RestingState, ...]
    symmetries: tuple[Symmetry, ...]
    continuous_axis_obj: np.ndarray | None  # axis of a continuous (round) symmetry, or None
    center_obj: np.ndarray           # (3,) centre of mass, obj frame
    diameter_mm: float
    feature_angle_deg: float
    extra: dict = field(default_factory=dict)
    denoised_normals: np.ndarray | None = None   # (F, 3) obj frame, for a noisy mesh; else None

    @property
    def face_normals(self) -> np.ndarray:
        """(F, 3) unit face normals, obj frame: denoised for a scan, else the mesh's own."""
        return self.mesh.face_normals if self.denoised_normals is None else self.denoised_normals

    @property
    def stands_as_modelled(self) -> bool:
        """Whether the only stance is the CAD one, z up (:func:`prepare_model`'s ``upright_only``: a
        fixture, which never lies upside down or on its side)."""
        return len(self.resting_states) == 1 and self.resting_states[0].cad_axis == "+z"

    @cached_property
    def support_vertices(self) -> np.ndarray:
        """(V, 3) the vertices that can rest on a surface, obj frame, mm: all of them, except for a
        fixture standing as modelled (:attr:`stands_as_modelled`) whose mesh reaches below its
        standing face, such as a strap clamp's stud down into the T-slot: those at or above that face."""
        V = np.asarray(self.mesh.vertices, dtype=float)
        if not self.stands_as_modelled:
            return V
        z = transform_points(self.resting_states[0].T_rest_obj, V)[:, 2]
        return V[z >= -STANDING_TOL_MM]

    @cached_property
    def face_planes(self) -> tuple[np.ndarray, np.ndarray]:
        """(F, 3) face normals (:attr:`face_normals`) and (F, 3) a vertex of each face, obj frame, mm:
        which side of each face a point is on. Read from the mesh once per model: trimesh checks its
        cache (hashing the mesh) on every access, 30 to 60 us, and the fits ask ~10^4 times per image."""
        return self.face_normals, self.mesh.vertices[self.mesh.faces[:, 0]]

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "n_faces": int(len(self.mesh.faces)),
            "n_edges": int(len(self.edge_vertices)),
            "n_samples": int(len(self.samples_obj)),
            "sample_step_mm": self.sample_step_mm,
            "diameter_mm": self.diameter_mm,
            "resting_states": [
                {"T_rest_obj": r.T_rest_obj.tolist(), "probability": r.probability,
                 "height_mm": r.height_mm, "same_as": r.same_as} for r in self.resting_states],
            "symmetries": [s.to_dict() for s in self.symmetries],
            "continuous_axis_obj": None if self.continuous_axis_obj is None
            else self.continuous_axis_obj.tolist(),
        }


@dataclass(frozen=True, eq=False)
class EdgeSamples:
    """Model edge samples visible in one view.

    index : (N,) indices into ``model.samples_obj``
    points_obj : (N, 3) mm, obj frame
    points_cam : (N, 3) mm, camera frame
    uv_px : (N, 2) projected (with distortion) pixel positions
    normal_uv : (N, 2) unit image normals of the projected edge (perpendicular to the edge's image)
    silhouette : (N,) True where the edge is an outline of the part (one adjacent face turned away)
    """

    index: np.ndarray
    points_obj: np.ndarray
    points_cam: np.ndarray
    uv_px: np.ndarray
    normal_uv: np.ndarray
    silhouette: np.ndarray
    n_front: int  # samples before the occlusion test (front-facing or silhouette, inside the image)


# --------------------------------------------------------------------------------------------------
# projection and z-buffer
# --------------------------------------------------------------------------------------------------


def project_points_px(P_cam: np.ndarray, K: np.ndarray, dist=None) -> np.ndarray:
    """Project camera-frame points (N, 3) mm to pixels (N, 2) with OpenCV's distortion model.

    Same maths as ``cv2.projectPoints`` for every coefficient count OpenCV takes: 4, 5 (k1 k2 p1 p2
    [k3]), 8 (+ k4 k5 k6, rational), 12 (+ s1..s4, thin prism), vectorised and without the per-call
    overhead; 14 coefficients with a tilted sensor (tau_x, tau_y not 0) go through OpenCV itself.
    Points behind the camera give NaN.
    """
    P = np.asarray(P_cam, dtype=float).reshape(-1, 3)
    z = P[:, 2]
    dd = np.zeros(0) if dist is None else np.asarray(dist, dtype=float).ravel()
    if len(dd) not in (0, 4, 5, 8, 12, 14):
        raise ValueError(f"distortion must have 4, 5, 8, 12 or 14 coefficients (OpenCV), got {len(dd)}")
    if len(dd) == 14 and np.any(dd[12:] != 0):
        uv = np.full((len(P), 2), np.nan)
        ok = z > 1e-6
        if np.any(ok):
            uv[ok] = cv2.projectPoints(P[ok].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.asarray(K, float),
                                       dd)[0].reshape(-1, 2)
        return uv
    with np.errstate(divide="ignore", invalid="ignore"):
        x = P[:, 0] / z
        y = P[:, 1] / z
    if len(dd) and np.any(dd != 0):
        d = np.zeros(12)
        d[: min(len(dd), 12)] = dd[:12]
        k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = d
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        # terms whose coefficients are 0 are left out (a denominator of exactly 1, sums of + 0): the
        # same numbers for every finite point, fewer passes over them (the search projects millions)
        if k4 or k5 or k6:
            radial = radial / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        if s1 or s2 or s3 or s4:
            r4 = r2 * r2
            xd = xd + s1 * r2 + s2 * r4
            yd = yd + s3 * r2 + s4 * r4
    else:
        xd, yd = x, y
    uv = np.empty((len(P), 2))
    uv[:, 0] = K[0, 0] * xd + K[0, 1] * yd + K[0, 2] if K[0, 1] != 0 else K[0, 0] * xd + K[0, 2]
    uv[:, 1] = K[1, 1] * yd + K[1, 2]
    uv[z <= 1e-6] = np.nan
    return uv


def project_points_jacobian(P_cam: np.ndarray, K: np.ndarray, dist=None) -> np.ndarray:
    """(N, 2, 3): d(pixel) / d(camera-frame point) px per mm of :func:`project_points_px`'s projection,
    every OpenCV distortion model: ``cv2.projectPoints``' Jacobian by its translation at the identity
    pose (a point moved by dP projects as the point with the camera shifted by -dP)."""
    P = np.asarray(P_cam, dtype=float).reshape(-1, 3)
    if len(P) == 0:
        return np.zeros((0, 2, 3))
    dd = np.zeros(0) if dist is None else np.asarray(dist, dtype=float).ravel()
    J = cv2.projectPoints(P.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), np.asarray(K, float),
                          dd if len(dd) else None)[1]
    return J[:, 3:6].reshape(-1, 2, 3)


def face_planes(V, F, K: np.ndarray, width: int, height: int, cull_back_faces: bool = True):
    """What :func:`render_depth` draws of one mesh (vertices ``V`` mm in the camera frame, faces ``F``):
    the faces in front of the camera (and turned towards it, with ``cull_back_faces``) that cover a
    pixel row of the buffer, as (face indices, barycentric planes ``l_k = A_k x + B_k y + C_k`` of
    buffer pixels for k = 0, 1 (``l_2 = 1 - l_0 - l_1``), the vertices' camera z (n, 3), first pixel
    row, number of rows); None where no face is left."""
    V = np.asarray(V, dtype=float)
    F = np.asarray(F, dtype=np.int64)
    tri = V[F]                                   # (F, 3, 3)
    ok = np.all(tri[:, :, 2] > 1.0, axis=1)      # drop faces behind/at the camera (no clipping)
    if cull_back_faces:   # closed meshes: a face turned away is never the nearest surface
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        ok &= np.einsum("ij,ij->i", nrm, tri[:, 0]) < 0
    fidx = np.nonzero(ok)[0]
    tri = tri[ok]
    if len(tri) == 0:
        return None
    zt = tri[:, :, 2]
    u = K[0, 0] * tri[:, :, 0] / zt + K[0, 2]
    v = K[1, 1] * tri[:, :, 1] / zt + K[1, 2]
    # scanline rasterisation: each face's pixel rows, then each row's span
    y0 = np.clip(np.ceil(v.min(1)), 0, height).astype(np.int64)
    y1 = np.clip(np.floor(v.max(1)), -1, height - 1).astype(np.int64)
    nrow = np.maximum(y1 - y0 + 1, 0)
    ua, ub, uc = u[:, 0], u[:, 1], u[:, 2]
    va, vb, vc = v[:, 0], v[:, 1], v[:, 2]
    den = (vb - vc) * (ua - uc) + (uc - ub) * (va - vc)
    good = (np.abs(den) > 1e-9) & (nrow > 0)
    if not np.any(good):
        return None
    fidx, zt, y0, nrow = fidx[good], np.ascontiguousarray(zt[good]), y0[good], nrow[good]
    ua, ub, uc, va, vb, vc, den = ua[good], ub[good], uc[good], va[good], vb[good], vc[good], den[good]
    A0, B0 = (vb - vc) / den, (uc - ub) / den
    C0 = -A0 * uc - B0 * vc
    A1, B1 = (vc - va) / den, (ua - uc) / den
    C1 = -A1 * uc - B1 * vc
    return fidx, A0, B0, C0, A1, B1, C1, zt, y0, nrow


def render_depth(meshes_cam: list[tuple[np.ndarray, np.ndarray]], K: np.ndarray, width: int,
                 height: int, max_pixel_tests: int = 6_000_000, cull_back_faces: bool = True
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer of triangle meshes seen by a pinhole camera (no distortion).

    Parameters
    ----------
    meshes_cam : list of (vertices (V, 3) mm in the camera frame, faces (F, 3) int)
    K : (3, 3) intrinsics of the (possibly scaled) buffer; pixel centres at integer coordinates
    width, height : buffer size in px

    Returns
    -------
    depth : (height, width) float32, camera z in mm of the nearest surface, +inf where empty
    face_id : (height, width) int64, ``mesh_index * 2**32 + face_index`` of that surface, -1 where empty
    """
    if width <= 0 or height <= 0:
        raise ValueError(f"z-buffer size must be positive, got {width} x {height}")
    depth = np.full(height * width, np.inf, dtype=np.float64)
    face_id = np.full(height * width, -1, dtype=np.int64)
    to_draw = []
    budget = max_pixel_tests
    for mi, (V, F) in enumerate(meshes_cam):
        planes = face_planes(V, F, K, width, height, cull_back_faces)
        if planes is None:
            continue
        fidx, A0, B0, C0, A1, B1, C1, zt, y0, nrow = planes
        nr = int(nrow.sum())
        if nr > budget:
            raise ValueError(f"z-buffer needs {nr} rows, more than {budget}; render smaller")
        total = int(span_pixel_count(A0, B0, C0, A1, B1, C1, y0, nrow, width))
        if total > budget:
            raise ValueError(f"z-buffer needs {total} pixel tests, more than {budget}; render smaller")
        budget -= total
        to_draw.append((np.int64(mi) << 32, *planes))
    # every mesh's budget checked before the buffer is drawn, in the meshes' order
    for tag, fidx, A0, B0, C0, A1, B1, C1, zt, y0, nrow in to_draw:
        raster_min_depth(depth, face_id, tag, fidx, A0, B0, C0, A1, B1, C1, zt, y0, nrow, width)
    face_id[np.isnan(depth)] = -1
    return depth.reshape(height, width).astype(np.float32), face_id.reshape(height, width)


# --------------------------------------------------------------------------------------------------
# preparation
# --------------------------------------------------------------------------------------------------


def _sample_edges(vertices: np.ndarray, edge_vertices: np.ndarray, step_mm: float):
    return _sample_segments(vertices[edge_vertices[:, 0]], vertices[edge_vertices[:, 1]], step_mm)


def _sample_segments(a: np.ndarray, b: np.ndarray, step_mm: float):
    """Points every ~``step_mm`` along segments a[i] -> b[i] (mm): points, segment index, direction."""
    L = np.linalg.norm(b - a, axis=1)
    n = np.maximum(1, np.ceil(L / step_mm).astype(np.int64))
    rep = np.repeat(np.arange(len(L)), n)
    start = np.cumsum(n) - n
    k = np.arange(int(n.sum())) - start[rep]
    t = (k + 0.5) / n[rep]
    pts = a[rep] + (b - a)[rep] * t[:, None]
    d = (b - a) / np.maximum(L, 1e-12)[:, None]
    return pts, rep, d[rep]


def _corner_distance(vertices, ev, feat, pts, rep, corner_angle_deg: float = 30.0,
                     line_dir: np.ndarray | None = None, ends: np.ndarray | None = None) -> np.ndarray:
    """Distance (mm) of each edge sample to the nearest corner: a vertex where crease edges do not
    continue straight on (not exactly two crease edges, or two meeting at more than
    ``corner_angle_deg``). Silhouette-only edges (curved faces) use their own two ends. Image edges
    near corners are blurred by the other edge, so the subpixel search leaves them out.
    ``line_dir`` (E, 3), where given (not NaN), is the direction of a crease fitted to a noisy
    mesh: two such edges continue straight on when their lines are parallel, however the triangle
    edges under them zigzag. ``ends`` (E, 2, 3) are where the edges are drawn (default their vertices)."""
    if line_dir is not None and np.any(np.isfinite(line_dir[feat, 0])):
        return _corner_distance_lines(vertices, ev, feat, pts, rep, corner_angle_deg, line_dir, ends)
    fe = ev[feat]
    inc: dict[int, list[int]] = {}
    for k, (a, b) in enumerate(fe):
        inc.setdefault(int(a), []).append(k)
        inc.setdefault(int(b), []).append(k)
    corners = []
    cos_lim = np.cos(np.radians(corner_angle_deg))
    for vtx, ks in inc.items():
        if len(ks) != 2:
            corners.append(vtx)
            continue
        d = []
        for k in ks:
            a, b = fe[k]
            other = b if a == vtx else a
            v = vertices[other] - vertices[vtx]
            d.append(v / max(np.linalg.norm(v), 1e-12))
        if -float(d[0] @ d[1]) < cos_lim:   # not continuing straight on
            corners.append(vtx)
    out = np.full(len(pts), np.inf)
    if corners:
        out, _ = cKDTree(vertices[np.asarray(corners)]).query(pts)
    smooth = ~feat[rep]
    if np.any(smooth):
        a = vertices[ev[rep[smooth], 0]]
        b = vertices[ev[rep[smooth], 1]]
        p = pts[smooth]
        out[smooth] = np.minimum(np.linalg.norm(p - a, axis=1), np.linalg.norm(p - b, axis=1))
    return np.asarray(out, dtype=float)


def _corner_distance_lines(vertices, ev, feat, pts, rep, corner_angle_deg, line_dir, ends) -> np.ndarray:
    """:func:`_corner_distance` for creases with fitted line directions (see there)."""
    fe = ev[feat]
    fd = line_dir[feat]
    raw = ~np.isfinite(fd[:, 0])
    ends = vertices[ev] if ends is None else ends
    fd[raw] = (ends[feat][raw, 1] - ends[feat][raw, 0])
    fd = fd / np.maximum(np.linalg.norm(fd, axis=1, keepdims=True), 1e-12)
    v = np.concatenate([fe[:, 0], fe[:, 1]])
    k = np.concatenate([np.arange(len(fe)), np.arange(len(fe))])
    order = np.argsort(v, kind="stable")
    v, k = v[order], k[order]
    uniq, start, count = np.unique(v, return_index=True, return_counts=True)
    corner = count != 2
    two = np.nonzero(count == 2)[0]
    c = np.abs(np.einsum("ij,ij->i", fd[k[start[two]]], fd[k[start[two] + 1]]))
    corner[two] = c < np.cos(np.radians(corner_angle_deg))
    out = np.full(len(pts), np.inf)
    if np.any(corner):
        out, _ = cKDTree(vertices[uniq[corner]]).query(pts)
    smooth = ~feat[rep]
    if np.any(smooth):
        a, b = ends[rep[smooth], 0], ends[rep[smooth], 1]
        p = pts[smooth]
        out[smooth] = np.minimum(np.linalg.norm(p - a, axis=1), np.linalg.norm(p - b, axis=1))
    return np.asarray(out, dtype=float)


def _thin_samples(pts: np.ndarray, keep_from: np.ndarray, min_gap_mm: float) -> np.ndarray:
    """(S,) bool: samples to keep. Among ``keep_from`` (samples of fitted creases, which lie on their
    line and overlap where the triangle edges under them zigzag back) drop those within
    ``min_gap_mm`` of an earlier one."""
    keep = np.ones(len(pts), bool)
    idx = np.nonzero(keep_from)[0]
    if len(idx) < 2:
        return keep
    pairs = cKDTree(pts[idx]).query_pairs(min_gap_mm, output_type="ndarray")
    if len(pairs):
        drop = np.zeros(len(idx), bool)
        for i, j in pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]:
            if not drop[i]:
                drop[j] = True
        keep[idx[drop]] = False
    return keep


def _rotation_about(axis: np.ndarray, angle_rad: float, center: np.ndarray) -> np.ndarray:
    R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle_rad).as_matrix()
    return make_pose(R, center - R @ center)


def _one_of(S: np.ndarray, found: list[Symmetry], atol: float) -> bool:
    """Whether the pose ``S`` is one of ``found`` (``np.allclose(S, s.S, atol=atol)`` for any): all of
    them compared at once, since closing a set of 48 under composition asks this 100 000 times."""
    if not found:
        return False
    stack = np.stack([s.S for s in found])
    return bool(np.any(np.all(np.abs(S - stack) <= atol + 1e-5 * np.abs(stack), axis=(1, 2))))


def _share_within(tree: cKDTree, pts: np.ndarray, tol: float, need: float, chunk: int = 256) -> float:
    """Share of ``pts`` within ``tol`` (mm) of the tree's points, taken a chunk at a time: as soon as
    the share can no longer reach ``need``, that bound (below ``need``) is returned instead; a share
    that reaches it is exact (``np.mean(d <= tol)`` over all points, the same number)."""
    n = len(pts)
    if n == 0:
        d, _ = tree.query(pts, distance_upper_bound=4 * tol)
        return float(np.mean(d <= tol))
    hits = 0
    for i in range(0, n, chunk):
        d, _ = tree.query(pts[i:i + chunk], distance_upper_bound=4 * tol)
        hits += int(np.count_nonzero(d <= tol))
        best = hits + max(n - i - chunk, 0)
        if best < need * n:
            return best / n
    return hits / n


def detect_symmetries(mesh: trimesh.Trimesh, *, axes: list[np.ndarray] | None = None,
                      center: np.ndarray | None = None, tol_mm: float | None = None,
                      near_fraction: float = 0.85, orders: tuple[int, ...] = (2, 3, 4, 5, 6, 8),
                      n_points: int = 2500, seed: int = 0, crease_ends: np.ndarray | None = None
                      ) -> tuple[list[Symmetry], np.ndarray | None]:
    """Rotations that map ``mesh`` onto itself.

    Candidate axes through the centre of mass (the principal axes of inertia and the given ``axes``,
    e.g. the resting normals) are tested for orders n in ``orders``: surface samples rotated by 360/n
    degrees must land on the surface (nearest neighbour in a denser sample), and samples of the sharp
    edges on sharp edges. A rotation is ``exact`` when 99.5 % of both land within ``tol_mm`` and
    "near" when at least ``near_fraction`` do (the outline maps but small features do not). An axis that also maps at 360/7 degrees and at
    37 degrees is a continuous (round) symmetry, returned separately.

    Returns
    -------
    symmetries : list of :class:`Symmetry` (identity excluded; each rotation listed once, the whole
        group of an axis, e.g. 90, 180, 270 deg for a square block)
    continuous_axis : (3,) unit axis in the obj frame, or None
    """
    rng = np.random.default_rng(seed)
    c = np.asarray(mesh.center_mass if mesh.is_watertight else mesh.centroid, dtype=float) \
        if center is None else np.asarray(center, dtype=float)
    diag = float(np.linalg.norm(mesh.extents))
    ref, _ = trimesh.sample.sample_surface(mesh, n_points * 12, seed=int(rng.integers(1 << 31)))
    spacing = np.sqrt(mesh.area / (n_points * 12))
    tol = float(tol_mm) if tol_mm is not None else max(2.5 * spacing, 0.004 * diag)
    query = ref[rng.choice(len(ref), size=min(n_points, len(ref)), replace=False)]
    tree = cKDTree(ref)
    # the sharp edges separately: small features (holes, chamfers) are mostly edges, a small share of
    # the surface but what an image shows; an exact symmetry must map the edges too
    # (``crease_ends`` (C, 2, 3): the creases as prepare_model found them, a scan's without its noise)
    if crease_ends is None:       # the mesh's own: face adjacencies above 30 deg, and open boundaries
        crease = mesh.face_adjacency_edges[np.degrees(mesh.face_adjacency_angles) > 30.0].astype(np.int64)
        crease_ends = mesh.vertices[np.concatenate([crease, boundary_edges(mesh)[0]])]
    ep, _, _ = _sample_segments(crease_ends[:, 0], crease_ends[:, 1], min(diag / 600.0, tol / 2))
    tree_e = cKDTree(ep) if len(ep) else None
    query_e = ep[rng.choice(len(ep), size=min(3 * n_points, len(ep)), replace=False)] if len(ep) else ep

    cand = [np.asarray(a, dtype=float) for a in (axes or [])]
    try:
        cand += list(np.asarray(mesh.principal_inertia_vectors, dtype=float))
    except Exception:  # noqa: BLE001 - degenerate meshes have no inertia; the given axes remain
        pass
    cand += [np.eye(3)[i] for i in range(3)]
    uniq: list[np.ndarray] = []
    for a in cand:
        n = np.linalg.norm(a)
        if n < 1e-9:
            continue
        a = a / n
        if not any(abs(float(a @ b)) > 0.9995 for b in uniq):
            uniq.append(a)

    def frac(S, need: float):
        """min(share of surface samples, share of edge samples) mapped onto the part by S; once it
        cannot reach ``need``, some value below ``need`` (most rotations tried fail within a tenth
        of the samples)."""
        f = _share_within(tree, transform_points(S, query), tol, need)
        if tree_e is not None and f >= need:
            f = min(f, _share_within(tree_e, transform_points(S, query_e), tol, need))
        return f

    out: list[Symmetry] = []
    continuous = None
    for a in uniq:
        if (frac(_rotation_about(a, 2 * np.pi / 7, c), 0.995) >= 0.995
                and frac(_rotation_about(a, np.radians(37.0), c), 0.995) >= 0.995):
            continuous = a
            continue
        best_n = None
        for n in sorted(orders, reverse=True):
            f = frac(_rotation_about(a, 2 * np.pi / n, c), near_fraction)
            if f >= near_fraction:
                best_n = n
                break
        if best_n is None:
            continue
        for k in range(1, best_n):
            S = _rotation_about(a, 2 * np.pi * k / best_n, c)
            f = frac(S, near_fraction)
            if f < near_fraction:
                continue
            if _one_of(S, out, atol=1e-6 * max(1.0, diag)):
                continue
            out.append(Symmetry(S=S, axis_obj=a, angle_deg=360.0 * k / best_n,
                                matched_fraction=f, exact=f >= 0.995))
    # close the set under composition (e.g. a block: 180 deg about x and y give 180 deg about z)
    changed = True
    while changed and len(out) < 48:
        changed = False
        for s1 in list(out):
            for s2 in list(out):
                S = s1.S @ s2.S
                if np.allclose(S[:3, :3], np.eye(3), atol=1e-6):
                    continue
                if _one_of(S, out, atol=1e-6 * max(1.0, diag)):
                    continue
                rv = Rotation.from_matrix(S[:3, :3]).as_rotvec()
                ang = float(np.linalg.norm(rv))
                f = frac(S, near_fraction)
                if f < near_fraction:
                    continue
                out.append(Symmetry(S=S, axis_obj=rv / ang, angle_deg=float(np.degrees(ang)),
                                    matched_fraction=f, exact=f >= 0.995))
                changed = True
    return out, continuous


def prepare_model(mesh: trimesh.Trimesh, name: str = "model", *, feature_angle_deg: float = 30.0,
                  smooth_angle_deg: float = 2.0, sample_step_mm: float | None = None,
                  max_resting_states: int = 6, min_resting_probability: float = 0.03,
                  detect_symmetry: bool = True, upright_only: bool = False) -> PreparedModel:
    """Prepare a CAD model (obj frame, mm) for edge matching. Costs up to ~1 s; cache the result.

    Parameters
    ----------
    mesh : trimesh.Trimesh in the model's own CAD frame, mm
    feature_angle_deg : dihedral angle above which an edge is a crease that shows as an image edge
    smooth_angle_deg : edges between faces closer to coplanar than this are never drawn (not even as
        silhouettes); above it and below ``feature_angle_deg`` they are silhouette-only (curved faces)
    sample_step_mm : spacing of the edge samples; default diameter / 300 within [0.25, 4] mm
    max_resting_states, min_resting_probability : keep the likeliest stable poses (at least one);
        the stances with the CAD z axis up and down are added when they are not among them
    upright_only : the only stance is the CAD one (z up, its standing face on the plane:
        :func:`standing_height`): fixtures such as a vise, parallels or a strap clamp set are modelled
        standing as they are used and never lie any other way
    """
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"model {name!r}: expected a non-empty triangle mesh")
    mesh = mesh.copy()
    diameter = float(np.linalg.norm(mesh.extents))
    step = float(sample_step_mm) if sample_step_mm else float(np.clip(diameter / 300.0, 0.25, 4.0))
    fe = feature_edges(mesh, smooth_angle_deg=smooth_angle_deg, feature_angle_deg=feature_angle_deg)
    ev, ef, feat = fe.edge_vertices, fe.edge_faces, fe.edge_feature
    pts, rep, d = _sample_segments(fe.edge_ends[:, 0], fe.edge_ends[:, 1], step)
    if np.any(fe.fitted):
        d = np.where(fe.fitted[rep][:, None], fe.edge_line_dir[rep], d)
        keep = _thin_samples(pts, fe.fitted[rep], 0.7 * step)
        pts, rep, d = pts[keep], rep[keep], d[keep]
        line_dir = np.where(fe.fitted[:, None], fe.edge_line_dir, np.nan)
        corner_mm = _corner_distance(mesh.vertices, ev, feat, pts, rep, line_dir=line_dir, ends=fe.edge_ends)
    else:
        corner_mm = _corner_distance(mesh.vertices, ev, feat, pts, rep)
    center = np.asarray(mesh.center_mass if mesh.is_watertight else mesh.centroid, dtype=float)

    states: list[RestingState] = []
    for rp in resting_poses(mesh, max_poses=max_resting_states):
        if states and rp.probability < min_resting_probability:
            break
        T = np.asarray(rp.T_plane_obj, dtype=float)
        cm = transform_points(T, center[None])[0]
        T = make_pose(None, [-cm[0], -cm[1], 0.0]) @ T   # centre of mass exactly above the origin
        states.append(RestingState(T_rest_obj=T, probability=rp.probability, height_mm=rp.height_mm))
    states = _with_cad_stances(mesh, center, states, upright_only)

    syms: list[Symmetry] = []
    cont = None
    if detect_symmetry:
        normals = [inv(s.T_rest_obj)[:3, :3] @ np.array([0.0, 0.0, 1.0]) for s in states]
        syms, cont = detect_symmetries(mesh, axes=normals, center=center,
                                       crease_ends=fe.edge_ends[fe.edge_feature])
    # resting states that are the same up to an exact symmetry of the part
    marked: list[RestingState] = []
    for j, s in enumerate(states):
        same = -1
        for i in range(j):
            if marked[i].same_as >= 0:
                continue
            for S in [x.S for x in syms if x.exact]:
                M = s.T_rest_obj @ S @ inv(states[i].T_rest_obj)
                if M[2, 2] > 1 - 1e-6:
                    same = i
                    break
            if same >= 0:
                break
        marked.append(RestingState(s.T_rest_obj, s.probability, s.height_mm, same, s.cad_axis))
    return PreparedModel(
        name=name, mesh=mesh, edge_vertices=ev, edge_faces=ef, edge_feature=feat,
        samples_obj=pts, sample_edge=rep, sample_dir_obj=d, sample_corner_mm=corner_mm,
        sample_step_mm=step,
        resting_states=tuple(marked), symmetries=tuple(syms), continuous_axis_obj=cont,
        center_obj=center, diameter_mm=diameter, feature_angle_deg=feature_angle_deg,
        extra={"edges": fe.info, "edge_model_version": EDGE_MODEL_VERSION}, denoised_normals=fe.face_normals)


def _with_cad_stances(mesh: trimesh.Trimesh, center: np.ndarray, states: list[RestingState],
                      upright_only: bool) -> list[RestingState]:
    """``states`` with the CAD z-up and z-down stances marked, added when missing (as states of
    probability 0 behind the others). A stance needs a face down: a plane through the mesh's lowest
    points that carries the centre of mass inside its support (checked loosely: any stance of a
    CAD-modelled part along its z axis is taken; a vise holds the part however it would fall)."""
    out: list[RestingState] = []
    wanted = {"+z": np.eye(3), "-z": np.diag([1.0, -1.0, -1.0])}
    if upright_only:
        wanted.pop("-z")
        states = []
    for s in states:
        # the stance is R turned about the table normal: the turn keeps z
        tag = next((k for k, R in wanted.items() if (s.T_rest_obj[:3, :3] @ R.T)[2, 2] > 1 - 1e-6), "")
        out.append(RestingState(s.T_rest_obj, s.probability, s.height_mm, s.same_as, tag))
    have = {s.cad_axis for s in out}
    for tag, R in wanted.items():
        if tag in have:
            continue
        V = np.asarray(mesh.vertices) @ R.T
        cm = R @ center
        z0 = standing_height(mesh) if upright_only else float(V[:, 2].min())
        T = make_pose(R, [-cm[0], -cm[1], -z0])
        out.append(RestingState(T_rest_obj=T, probability=0.0, height_mm=float(V[:, 2].max() - z0), cad_axis=tag))
    return out


#: a fixture's standing face is its lowest downward face with at least this share of the area of its
#: largest downward face. The devset's strap clamp sets: the heel block's 1200 mm^2 beside the strap's
#: 2400 mm^2 underside carries the set; the stud's 200 mm^2 end (8 %), 16 mm down in the T-slot, does
#: not. Its vise's moving jaw rides on its tongue (900 mm^2 against 4800 mm^2, 19 %), 8 mm under the
#: jaw's underside, on a face of the body's rail.
STANDING_SHARE = 0.15
#: faces within this height of each other (mm) are one face; vertices this far under the standing
#: face still count as on it
STANDING_TOL_MM = 0.5


def standing_height(mesh: trimesh.Trimesh) -> float:
    """z (CAD frame, mm) of the face a fixture modelled upright stands on: the lowest downward face
    (faces grouped by height) with :data:`STANDING_SHARE` of the largest one's area. A stud or a
    key that reaches below it into a T-slot does not carry the fixture. The lowest vertex when the
    mesh has no downward face."""
    V = np.asarray(mesh.vertices, dtype=float)
    down = np.asarray(mesh.face_normals)[:, 2] < -0.99
    if not down.any():
        return float(V[:, 2].min())
    z = V[np.asarray(mesh.faces)[down]][:, :, 2].mean(axis=1)
    area = np.asarray(mesh.area_faces)[down]
    order = np.argsort(z)
    z, area = z[order], area[order]
    # group faces whose heights lie within the tolerance of the group's lowest face
    starts = [0]
    for i in range(1, len(z)):
        if z[i] - z[starts[-1]] > STANDING_TOL_MM:
            starts.append(i)
    bounds = starts + [len(z)]
    groups = [(float(z[a]), float(area[a:b].sum())) for a, b in zip(bounds[:-1], bounds[1:])]
    biggest = max(a for _, a in groups)
    return next(h for h, a in groups if a >= STANDING_SHARE * biggest)


def resting_pose(model: PreparedModel, state: int, x_mm: float, y_mm: float, theta_deg: float,
                 height_mm: float = 0.0) -> np.ndarray:
    """``T_table_obj`` of the part lying in resting state ``state`` with its centre of mass above
    (x_mm, y_mm), turned by ``theta_deg`` about the table normal, raised by ``height_mm`` (parallels)."""
    c, s = np.cos(np.radians(theta_deg)), np.sin(np.radians(theta_deg))
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return make_pose(Rz, [x_mm, y_mm, height_mm]) @ model.resting_states[state].T_rest_obj


# --------------------------------------------------------------------------------------------------
# visibility
# --------------------------------------------------------------------------------------------------


def _front_facing(model: PreparedModel, T_cam_obj: np.ndarray) -> np.ndarray:
    """(F,) bool: face turned towards the camera (camera centre on the face's outer side)."""
    cam_obj = inv(T_cam_obj)[:3, 3]
    normals, tri0 = model.face_planes
    return np.einsum("ij,ij->i", normals, cam_obj - tri0) > 0


def visible_edge_samples(model: PreparedModel, T_cam_obj: np.ndarray, K: np.ndarray, dist,
                         width: int, height: int, *,
                         occluders: tuple[tuple[PreparedModel | trimesh.Trimesh, np.ndarray], ...] = (),
                         occlusion_test: bool = True, max_buffer_px: int = 360,
                         margin_px: float = 2.0, subset: np.ndarray | None = None) -> EdgeSamples:
    """Edge samples of ``model`` at ``T_cam_obj`` that the camera sees.

    A sample shows if its edge is a crease with a front-facing face or a silhouette (front face next to
    a back face; smooth edges only as silhouettes), it projects inside the image, and (with
    ``occlusion_test``) nothing is in front of it: a z-buffer of the model and of ``occluders``
    (pairs of a mesh or prepared model and its ``T_cam_occ``) rendered at most ``max_buffer_px`` wide.
    ``subset`` restricts the candidate samples (indices into ``model.samples_obj``).
    """
    front = _front_facing(model, T_cam_obj)
    f0, f1 = model.edge_faces[:, 0], model.edge_faces[:, 1]
    fr0 = front[f0]
    fr1 = np.where(f1 >= 0, front[np.maximum(f1, 0)], ~fr0)
    sil_edge = fr0 != fr1
    show_edge = sil_edge | (model.edge_feature & (fr0 | fr1))
    idx = np.arange(len(model.samples_obj)) if subset is None else np.asarray(subset)
    idx = idx[show_edge[model.sample_edge[idx]]]
    P_obj = model.samples_obj[idx]
    P_cam = transform_points(T_cam_obj, P_obj)
    # image normal from the projected edge direction; the samples and their points a little along
    # the edge projected in one call (pointwise: the same numbers, half the calls on a few hundred)
    D_cam = model.sample_dir_obj[idx] @ T_cam_obj[:3, :3].T
    eps = np.maximum(0.05 * model.sample_step_mm, 1e-3)
    uv, uv2 = project_points_px(np.concatenate([P_cam, P_cam + D_cam * eps]), K, dist).reshape(2, len(idx), 2)
    t = uv2 - uv
    tn = np.linalg.norm(t, axis=1)
    inside = (np.isfinite(uv).all(1) & (uv[:, 0] >= margin_px) & (uv[:, 1] >= margin_px)
              & (uv[:, 0] <= width - 1 - margin_px) & (uv[:, 1] <= height - 1 - margin_px)
              & (tn > 1e-9) & _before_fold(P_cam, dist))
    idx, P_obj, P_cam, uv, t, tn = idx[inside], P_obj[inside], P_cam[inside], uv[inside], t[inside], tn[inside]
    n_front = len(idx)
    normal = np.stack([-t[:, 1], t[:, 0]], axis=1) / tn[:, None]
    sil = sil_edge[model.sample_edge[idx]]
    if occlusion_test and len(idx):
        keep = _unoccluded(model, T_cam_obj, K, width, height, idx, P_cam, occluders, max_buffer_px)
        idx, P_obj, P_cam, uv, normal, sil = idx[keep], P_obj[keep], P_cam[keep], uv[keep], normal[keep], sil[keep]
    return EdgeSamples(index=idx, points_obj=P_obj, points_cam=P_cam, uv_px=uv, normal_uv=normal,
                       silhouette=sil, n_front=n_front)


def _before_fold(P_cam: np.ndarray, dist) -> np.ndarray:
    """(N,) bool: in front of the camera and inside the radius where the radial distortion still
    grows with the angle (d r_d / d r > 0). Beyond it the polynomial folds back: a point far outside
    the field of view would land inside the image, where nothing of it can be seen."""
    z = P_cam[:, 2]
    ok = z > 1e-6
    d = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    if len(d) < 2 or not np.any(d):
        return ok
    k1, k2 = d[0], d[1]
    k3 = d[4] if len(d) > 4 else 0.0
    r2 = np.where(ok, (P_cam[:, 0] ** 2 + P_cam[:, 1] ** 2) / np.where(ok, z, 1.0) ** 2, np.inf)
    with np.errstate(invalid="ignore", over="ignore"):
        grow = 1 + 3 * k1 * r2 + 5 * k2 * r2 ** 2 + 7 * k3 * r2 ** 3
        if len(d) >= 8:                     # rational model: (1 + k1 r2 + ...) / (1 + k4 r2 + ...)
            k4, k5, k6 = d[5], d[6], d[7]
            num = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
            den = 1 + k4 * r2 + k5 * r2 ** 2 + k6 * r2 ** 3
            dnum = k1 + 2 * k2 * r2 + 3 * k3 * r2 ** 2
            dden = k4 + 2 * k5 * r2 + 3 * k6 * r2 ** 2
            grow = num / den + 2 * r2 * (dnum * den - num * dden) / den ** 2
    return ok & np.isfinite(grow) & (grow > 0)


def _unoccluded(model, T_cam_obj, K, width, height, idx, P_cam, occluders, max_buffer_px):
    # pinhole pixel positions of the samples (the buffer has no distortion)
    u = K[0, 0] * P_cam[:, 0] / P_cam[:, 2] + K[0, 2]
    v = K[1, 1] * P_cam[:, 1] / P_cam[:, 2] + K[1, 2]
    pad = 4.0
    x0, x1 = max(0.0, u.min() - pad), min(float(width - 1), u.max() + pad)
    y0, y1 = max(0.0, v.min() - pad), min(float(height - 1), v.max() + pad)
    if x1 < x0 or y1 < y0:          # every sample lies outside the image: nothing there to hide them
        return np.ones(len(P_cam), dtype=bool)
    s = min(1.0, max_buffer_px / max(x1 - x0, y1 - y0, 1.0))
    W = int(np.ceil((x1 - x0) * s)) + 2
    H = int(np.ceil((y1 - y0) * s)) + 2
    Kb = np.array([[K[0, 0] * s, 0.0, (K[0, 2] - x0) * s], [0.0, K[1, 1] * s, (K[1, 2] - y0) * s],
                   [0.0, 0.0, 1.0]])
    meshes = [(transform_points(T_cam_obj, model.mesh.vertices), model.mesh.faces)]
    for occ, T_cam_occ in occluders:
        m = occ.mesh if isinstance(occ, PreparedModel) else occ
        meshes.append((transform_points(T_cam_occ, m.vertices), m.faces))
    depth, fid = render_depth(meshes, Kb, W, H)
    ub = np.clip(np.rint((u - x0) * s).astype(int), 0, W - 1)
    vb = np.clip(np.rint((v - y0) * s).astype(int), 0, H - 1)
    z = P_cam[:, 2]
    # a sample is hidden when a surface is clearly nearer at its pixel (tolerance: a few buffer
    # pixels' footprint, for faces seen at a grazing angle, plus 0.2 mm)
    foot = z / (K[0, 0] * s)
    tol = 4.0 * foot + 0.2
    best = np.zeros(len(z), dtype=bool)
    own = model.edge_faces[model.sample_edge[idx]]
    # the pixel and its 4-neighbours: visible if any of them shows the sample's own faces or
    # something not nearer (edges lie on pixel boundaries of the buffer)
    for du, dv in ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1)):
        uu = np.clip(ub + du, 0, W - 1)
        vv = np.clip(vb + dv, 0, H - 1)
        d = depth[vv, uu]
        f = fid[vv, uu]
        is_own = (f >= 0) & (f < (1 << 32)) & ((f == own[:, 0]) | (f == own[:, 1]))
        best |= is_own | (d >= z - tol)
    return best
