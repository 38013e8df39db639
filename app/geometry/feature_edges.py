"""Which mesh edges are a part's real features: creases between surfaces, not facets of its tessellation.

A clean CAD mesh shows its creases directly: two flat triangles meeting at more than the feature
angle. Two kinds of mesh break that rule, and :func:`feature_edges` handles both:

* **Coarse tessellation** (a hole or fillet in 8-16 facets, 22-45 deg apart): every facet edge is
  above the feature angle, but the part is round there. A crease between two facet *strips* (flat
  facets bounded by a parallel crease of the same sense on their other side, of similar width and
  small chord height) is a facet edge of a cylinder, cone or fillet: it stays a silhouette-only edge.
  A chamfer is one strip between two wide faces and keeps its creases.
* **Noisy meshes** (scans: fine triangles, vertex noise 0.05-0.3 mm): single triangles meet at
  random angles, and a sharp edge is spread over a band of triangles none of which alone turns by
  the feature angle. The face normals are denoised first (a plain mean, then a bilateral filter
  over the vertex-sharing neighbours: noise is averaged out, creases are kept); the surface is cut
  where the denoised normals within a radius ``r`` (3 median edge lengths) spread like two sides of
  a crease (:func:`_crease_zone`), the pieces in between are the smooth patches, the cut band is
  handed back to the patches on its sides (:func:`_patches`), and a crease is a boundary between
  two patches whose local plane fits turn by more than the feature angle. Chains shorter than
  max(3 mm, 3 r) are dropped; each crease edge carries the line where the two patches' local planes
  meet (the zigzag of triangle edges along a crease is drawn on that line, in its direction).
  Silhouette-only edges are the rest where the denoised normals still turn (curved patches).

A mesh counts as noisy when most of its faces have no neighbour within 1 deg of their plane: a CAD
tessellation splits every flat or ruled face into coplanar pairs, a scan does not.

Units mm, angles deg at the interface; all geometry in the mesh's own (obj) frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy import sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

__all__ = ["FeatureEdges", "boundary_edges", "feature_edges", "normal_noise_deg"]

#: median angle (deg) between a face and its most nearly coplanar neighbour above which a mesh is
#: treated as noisy (CAD meshes: 0; a 0.05 mm noise on 1 mm triangles: about 3 deg)
NOISY_MESH_DEG = 1.0


@dataclass(frozen=True, eq=False)
class FeatureEdges:
    """The edges of a mesh that can show in an image.

    edge_vertices : (E, 2) vertex indices
    edge_faces : (E, 2) adjacent face indices, -1 for a boundary edge
    edge_feature : (E,) True for a crease or boundary edge, False for a silhouette-only edge
    edge_ends : (E, 2, 3) where to draw the edge, mm: its vertices, or for a crease of a noisy mesh
        their projection on the line where the two patches' planes meet
    edge_line_dir : (E, 3) unit direction of that line (the edge's own direction when not fitted)
    fitted : (E,) True where ``edge_ends`` and ``edge_line_dir`` come from fitted planes
    face_normals : (F, 3) denoised face normals for a noisy mesh, else None (use the mesh's own)
    info : what was found, for reports (``noise_deg``, ``noisy``, ``radius_mm``, counts)
    """

    edge_vertices: np.ndarray
    edge_faces: np.ndarray
    edge_feature: np.ndarray
    edge_ends: np.ndarray
    edge_line_dir: np.ndarray
    fitted: np.ndarray
    face_normals: np.ndarray | None = None
    info: dict = field(default_factory=dict)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0)))


def normal_noise_deg(mesh: trimesh.Trimesh) -> float:
    """Median over the (non-degenerate) faces of the angle to the most nearly coplanar edge neighbour,
    deg: 0 for CAD tessellations (flat and ruled faces come in coplanar pairs), several degrees for a
    scan, growing with the vertex noise over the triangle size."""
    adj = mesh.face_adjacency
    if len(adj) == 0:
        return 0.0
    ang = np.degrees(mesh.face_adjacency_angles)
    best = np.full(len(mesh.faces), np.inf)
    np.minimum.at(best, adj[:, 0], ang)
    np.minimum.at(best, adj[:, 1], ang)
    ok = np.isfinite(best) & (mesh.area_faces > 1e-12 * max(mesh.area, 1e-12))
    return float(np.median(best[ok])) if np.any(ok) else 0.0


def boundary_edges(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """Edges used by one face only (open meshes): (B, 2) vertices and (B, 2) faces (second -1)."""
    es = mesh.edges_sorted
    grp = trimesh.grouping.group_rows(es, require_count=1)
    if len(grp) == 0:
        return np.zeros((0, 2), np.int64), np.zeros((0, 2), np.int64)
    return es[grp].astype(np.int64), np.stack([mesh.edges_face[grp], -np.ones(len(grp), np.int64)], 1)


# --------------------------------------------------------------------------------------------------
# clean meshes: facet edges of coarse tessellations
# --------------------------------------------------------------------------------------------------


def _tessellation_edges(mesh: trimesh.Trimesh, ang: np.ndarray, cand: np.ndarray, smooth_angle_deg: float,
                        max_step_deg: float = 50.0, max_sagitta_mm: float | None = None,
                        parallel_deg: float = 25.0) -> np.ndarray:
    """(A,) bool over the face adjacencies: candidate creases (``cand``) that are facet edges of a
    tessellated round surface.

    The flat facets (coplanar face groups) on both sides must be strips along the edge: each has
    another boundary run of the same sense (convex / concave), turning by more than the smooth angle
    and at most ``max_step_deg``, within ``parallel_deg`` of parallel (cone facets converge), at a
    width w whose chord height ``w/2 tan(theta/4)`` is at most ``max_sagitta_mm``, and the two strips'
    widths within a factor 2 of each other (a tessellation's facets are alike; a chamfer is a
    narrow strip between wide faces)."""
    out = np.zeros(len(ang), bool)
    cand = cand & (ang <= max_step_deg)
    if not np.any(cand):
        return out
    if max_sagitta_mm is None:
        max_sagitta_mm = max(1.0, 0.01 * float(np.linalg.norm(mesh.extents)))
    adj = mesh.face_adjacency
    F = len(mesh.faces)
    flat = ang < 0.5
    g = sparse.coo_matrix((np.ones(int(flat.sum())), (adj[flat, 0], adj[flat, 1])), shape=(F, F))
    _, facet = connected_components(g, directed=False)
    V = mesh.vertices
    ae = mesh.face_adjacency_edges
    p0, p1 = V[ae[:, 0]], V[ae[:, 1]]
    mid = 0.5 * (p0 + p1)
    t = _unit(p1 - p0)
    convex = mesh.face_adjacency_convex
    runs = np.nonzero((ang > smooth_angle_deg) & (ang <= max_step_deg))[0]
    inc_facet = np.concatenate([facet[adj[runs, 0]], facet[adj[runs, 1]]])
    inc_other = np.concatenate([facet[adj[runs, 1]], facet[adj[runs, 0]]])
    inc_adj = np.concatenate([runs, runs])
    order = np.argsort(inc_facet, kind="stable")
    inc_facet, inc_other, inc_adj = inc_facet[order], inc_other[order], inc_adj[order]
    cos_par = np.cos(np.radians(parallel_deg))

    def strip_width(fa: int, other: int, a: int) -> float:
        """Width of facet ``fa`` as a strip along adjacency ``a`` (to facet ``other``), or inf."""
        lo, hi = np.searchsorted(inc_facet, [fa, fa + 1])
        b = inc_adj[lo:hi]
        ok = ((inc_other[lo:hi] != other) & (convex[b] == convex[a])
              & (np.abs(t[b] @ t[a]) > cos_par))
        if not np.any(ok):
            return np.inf
        b = b[ok]
        d = mid[b] - p0[a]
        w = np.linalg.norm(d - np.outer(d @ t[a], t[a]), axis=1)
        w = w[w > 1e-6 * max(float(np.linalg.norm(mesh.extents)), 1.0)]
        return float(w.min()) if len(w) else np.inf

    tan4 = np.tan(np.radians(ang) / 4.0)
    for a in np.nonzero(cand)[0]:
        f0, f1 = facet[adj[a, 0]], facet[adj[a, 1]]
        w0 = strip_width(f0, f1, a)
        if not np.isfinite(w0) or 0.5 * w0 * tan4[a] > max_sagitta_mm:
            continue
        w1 = strip_width(f1, f0, a)
        if not np.isfinite(w1) or 0.5 * w1 * tan4[a] > max_sagitta_mm:
            continue
        out[a] = max(w0, w1) <= 2.0 * min(w0, w1)
    return out


# --------------------------------------------------------------------------------------------------
# noisy meshes: denoised normals, patches, creases between patches
# --------------------------------------------------------------------------------------------------


def _filtered_normals(mesh: trimesh.Trimesh, iterations: int, sigma_deg: float) -> np.ndarray:
    """Bilateral filter of the face normals over faces sharing a vertex: each pass replaces a normal
    by the area-weighted mean of its own and its neighbours', each neighbour weighted by
    exp(-angle^2 / 2 sigma^2) so that faces across a crease hardly count."""
    N = mesh.face_normals.copy()
    A = mesh.area_faces
    pairs = mesh.face_neighborhood
    if len(pairs) == 0:
        return N
    i = np.concatenate([pairs[:, 0], pairs[:, 1]])
    j = np.concatenate([pairs[:, 1], pairs[:, 0]])
    s2 = 2.0 * np.radians(sigma_deg) ** 2
    F = len(N)
    for k in range(iterations + 1):
        c = np.clip(np.einsum("ij,ij->i", N[i], N[j]), -1.0, 1.0)
        # the first pass is a plain area-weighted mean: it rights thin faces flipped by the noise,
        # which the range weight would otherwise keep apart for good
        w = (np.exp(-np.arccos(c) ** 2 / s2) if k else np.ones_like(c)) * A[j]
        W = sparse.csr_matrix((w, (i, j)), shape=(F, F))
        N = _unit(A[:, None] * N + W @ N)
    return N


def _ball_pairs(tree: cKDTree, points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(query index, face index) pairs of the faces whose centroid is within ``radius`` of each point."""
    if len(points) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    m = cKDTree(points).sparse_distance_matrix(tree, radius, output_type="coo_matrix")
    # a face exactly at the point has distance 0 and is not stored: add the pairs at distance 0
    z, zi = tree.query(points, distance_upper_bound=1e-12)
    hit = np.isfinite(z)
    return (np.concatenate([m.row, np.nonzero(hit)[0]]).astype(np.int64),
            np.concatenate([m.col, zi[hit]]).astype(np.int64))


def _grouped_mean(q: np.ndarray, vals: np.ndarray, w: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean of ``vals`` (M, 3) grouped by ``q`` into n rows, and the summed weights."""
    ws = np.bincount(q, weights=w, minlength=n)
    out = np.stack([np.bincount(q, weights=w * vals[:, k], minlength=n) for k in range(3)], 1)
    return out / np.maximum(ws, 1e-300)[:, None], ws


def _crease_zone(mesh, Nf, tree, radius: float, feature_angle_deg: float) -> np.ndarray:
    """(F,) bool: faces near a place where the denoised normals within ``radius`` turn like a crease.

    The surface is probed at one face per cube of radius/3; at each probe the second eigenvalue of
    the area-weighted scatter of the normals in the ball, sin^2(theta/2) for two halves theta
    apart, tells a crease (both sides in the ball) from a curved surface (normals spread by about
    radius / curvature radius) without asking which way the crease runs. Faces within radius/2
    of a probe above 0.8 x the feature angle are the zone: the probes' balls join into a tube
    along every crease that no path from one side to the other avoids."""
    C, A = mesh.triangles_center, mesh.area_faces
    cell = np.floor((C - C.min(0)) / (radius / 3.0)).astype(np.int64)
    _, probe = np.unique(cell, axis=0, return_index=True)
    q, f = _ball_pairs(tree, C[probe], radius)
    n = len(probe)
    w = A[f]
    S = np.zeros((n, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            S[:, a, b] = S[:, b, a] = np.bincount(q, weights=w * Nf[f, a] * Nf[f, b], minlength=n)
    tot = np.bincount(q, weights=w, minlength=n)
    lam = np.linalg.eigvalsh(S / np.maximum(tot, 1e-300)[:, None, None])[:, 1]
    hot = probe[lam > np.sin(np.radians(0.4 * feature_angle_deg)) ** 2]
    zone = np.zeros(len(C), bool)
    if len(hot):
        _, near = _ball_pairs(tree, C[hot], 0.5 * radius)
        zone[near] = True
    return zone


def _spread(adj, Nf, lab, origin, cos_min: float) -> None:
    """Give unlabelled faces (``lab`` < 0) the label of an edge neighbour, ring by ring, the one whose
    ``origin`` normal is closest to the face's and within ``cos_min``; updates lab and origin."""
    while True:
        todo = lab < 0
        if not np.any(todo):
            return
        e0 = todo[adj[:, 0]] & ~todo[adj[:, 1]]
        e1 = todo[adj[:, 1]] & ~todo[adj[:, 0]]
        dst = np.concatenate([adj[e0, 0], adj[e1, 1]])
        src = np.concatenate([adj[e0, 1], adj[e1, 0]])
        sim = np.einsum("ij,ij->i", Nf[dst], origin[src])
        ok = sim > cos_min
        dst, src, sim = dst[ok], src[ok], sim[ok]
        if len(dst) == 0:
            return
        order = np.lexsort((-sim, dst))      # per face, the most similar neighbour first
        dst, src = dst[order], src[order]
        first = np.r_[True, dst[1:] != dst[:-1]]
        lab[dst[first]] = lab[src[first]]
        origin[dst[first]] = origin[src[first]]


def _patches(mesh, Nf, cut_faces: np.ndarray, min_area_mm2: float, min_width_mm: float) -> np.ndarray:
    """Label per face: connected regions of faces outside ``cut_faces``; faces of the cut and of
    small or thin regions then join the neighbouring kept region whose normal is closest, a ring at
    a time (a band around a crease splits down its middle)."""
    adj = mesh.face_adjacency
    F = len(mesh.faces)
    keep = ~cut_faces[adj[:, 0]] & ~cut_faces[adj[:, 1]]
    g = sparse.coo_matrix((np.ones(int(keep.sum())), (adj[keep, 0], adj[keep, 1])), shape=(F, F))
    _, lab = connected_components(g, directed=False)
    lab = lab.astype(np.int64)
    lab[cut_faces] = -1
    # region area and boundary length (edges to other regions or the cut): thin regions are bands
    A = mesh.area_faces
    good = lab >= 0
    area = np.bincount(lab[good], weights=A[good], minlength=int(lab.max()) + 1 if good.any() else 0)
    el = np.linalg.norm(np.diff(mesh.vertices[mesh.face_adjacency_edges], axis=1)[:, 0], axis=1)
    diff = lab[adj[:, 0]] != lab[adj[:, 1]]
    perim = np.zeros(len(area))
    for side in (0, 1):
        ls = lab[adj[diff, side]]
        ok = ls >= 0
        perim += np.bincount(ls[ok], weights=el[diff][ok], minlength=len(area))
    width = 2.0 * area / np.maximum(perim, 1e-12)
    small = (area < min_area_mm2) | (width < min_width_mm)
    if len(area) and np.all(small):           # nothing big enough: keep the biggest region
        small[np.argmax(area)] = False
    if len(area):                             # else every face lies in the cut (a ball): all go on below
        lab = np.where(good & ~small[np.maximum(lab, 0)], lab, -1)
    # hand the rest out ring by ring to the neighbour whose patch normal is closest; a face takes a
    # patch only within 60 deg of the normal where that patch's spread started, so a patch never
    # floods over a crease into a region that was cut away (a fillet inside the crease zone)
    origin = Nf.copy()
    _spread(adj, Nf, lab, origin, np.cos(np.radians(60.0)))
    rest = np.nonzero(lab < 0)[0]
    if len(rest):                              # cut off from every kept patch: patches of their own,
        g2 = sparse.coo_matrix((np.ones(len(adj)), (adj[:, 0], adj[:, 1])), shape=(F, F)).tocsr()
        _, l2 = connected_components(g2[rest][:, rest], directed=False)
        big = np.bincount(l2, weights=A[rest]) >= min_area_mm2
        lab[rest] = np.where(big[l2], lab.max() + 1 + l2, -1)
        _spread(adj, Nf, lab, origin, -1.0)   # small ones join a neighbour whatever its normal
        left = lab < 0
        lab[left] = lab.max() + 1 + np.arange(int(left.sum()))
    # majority smoothing: a face whose edge neighbours mostly (2 or 3 of them) carry one other label
    # takes it, so that a patch boundary has no one-face teeth (a tooth triples the crease's length)
    for _ in range(10):
        nb = np.full((F, 3), -1, np.int64)
        cnt = np.zeros(F, np.int64)
        for s, o in ((0, 1), (1, 0)):
            f, g = adj[:, s], adj[:, o]
            order = np.argsort(f, kind="stable")
            f, g = f[order], g[order]
            slot = np.arange(len(f)) - np.searchsorted(f, f)
            ok = slot + cnt[f] < 3
            nb[f[ok], (slot + cnt[f])[ok]] = lab[g[ok]]
            np.add.at(cnt, f, 1)
        a, b, c = nb[:, 0], nb[:, 1], nb[:, 2]
        maj = np.where((a == b) | (a == c), a, np.where(b == c, b, -1))
        change = (maj >= 0) & (maj != lab)
        if not np.any(change):
            break
        lab[change] = maj[change]
    return lab


def _chains(ev: np.ndarray, n_vertices: int) -> np.ndarray:
    """Connected component (through shared vertices) of each edge."""
    if len(ev) == 0:
        return np.zeros(0, np.int64)
    g = sparse.coo_matrix((np.ones(len(ev)), (ev[:, 0], ev[:, 1])), shape=(n_vertices, n_vertices))
    _, lab = connected_components(g, directed=False)
    return lab[ev[:, 0]]


def _local_planes(mesh, lab, Nf, tree, pts, pairs_lab, radius, max_dev_deg=20.0):
    """For each point and each of its two patch labels (P, 2): the plane (unit normal, offset) of the
    patch's faces within ``radius`` (area weighted; faces turned more than ``max_dev_deg`` from the
    patch's local mean, e.g. still in the rounded band of a scanned edge, left out); weight 0 when
    the patch has no face there."""
    C, A, N = mesh.triangles_center, mesh.area_faces, mesh.face_normals
    q, f = _ball_pairs(tree, pts, radius)
    n = len(pts)
    out_n = np.zeros((n, 2, 3))
    out_d = np.zeros((n, 2))
    out_w = np.zeros((n, 2))
    for s in (0, 1):
        sel = lab[f] == pairs_lab[q, s]
        qs, fs = q[sel], f[sel]
        mean_n, _ = _grouped_mean(qs, Nf[fs], A[fs], n)
        mean_n = _unit(mean_n)
        near = np.einsum("ij,ij->i", Nf[fs], mean_n[qs]) > np.cos(np.radians(max_dev_deg))
        qs, fs = qs[near], fs[near]
        nn, w = _grouped_mean(qs, N[fs], A[fs], n)
        cc, _ = _grouped_mean(qs, C[fs], A[fs], n)
        nn = _unit(nn)
        out_n[:, s], out_d[:, s], out_w[:, s] = nn, np.einsum("ij,ij->i", nn, cc), w
    return out_n, out_d, out_w


def _noisy_feature_edges(mesh: trimesh.Trimesh, noise_deg: float, smooth_angle_deg: float,
                         feature_angle_deg: float, radius_mm: float | None, min_chain_mm: float | None):
    """The noisy-mesh branch of :func:`feature_edges` (see the module docstring): edge vertices,
    faces, crease flags, ends (E, 2, 3) mm, line directions, fitted flags, denoised normals, info."""
    adj = mesh.face_adjacency
    ae = mesh.face_adjacency_edges
    V = mesh.vertices
    h = float(np.median(mesh.edges_unique_length))
    r = float(radius_mm) if radius_mm else 3.0 * h * max(1.0, noise_deg / 10.0)
    iters = int(np.clip(round((r / h) ** 2), 4, 30))
    Nf = _filtered_normals(mesh, iters, sigma_deg=max(15.0, 2.0 * noise_deg))
    fang = _angle_deg(Nf[adj[:, 0]], Nf[adj[:, 1]])
    resid = float(np.median(fang))
    tree = cKDTree(mesh.triangles_center)
    cut_faces = _crease_zone(mesh, Nf, tree, r, feature_angle_deg)
    lab = _patches(mesh, Nf, cut_faces, min_area_mm2=(2.0 * r) ** 2, min_width_mm=r)
    # creases: boundaries between patches whose local planes turn by more than the feature angle
    bnd = np.nonzero(lab[adj[:, 0]] != lab[adj[:, 1]])[0]
    mid = 0.5 * (V[ae[bnd, 0]] + V[ae[bnd, 1]])
    pl = np.stack([lab[adj[bnd, 0]], lab[adj[bnd, 1]]], 1)
    pn, pd, pw = _local_planes(mesh, lab, Nf, tree, mid, pl, 1.5 * r)
    turn = _angle_deg(pn[:, 0], pn[:, 1])
    crease = (turn > feature_angle_deg) & (pw > 0).all(1)
    # short chains are speckle, not features
    L = np.linalg.norm(V[ae[bnd, 1]] - V[ae[bnd, 0]], axis=1)
    min_len = float(min_chain_mm) if min_chain_mm is not None else max(3.0, 3.0 * r)
    idx = np.nonzero(crease)[0]
    ch = _chains(ae[bnd[idx]], len(V))
    if len(idx):
        chain_len = np.bincount(ch, weights=L[idx])
        crease[idx[chain_len[ch] < min_len]] = False
    # the line where the two planes meet: crease edges are drawn on it
    n0, n1 = pn[:, 0], pn[:, 1]
    t = _unit(np.cross(n0, n1))
    M = np.stack([n0, n1, t], 1)
    rhs = np.stack([pd[:, 0], pd[:, 1], np.einsum("ij,ij->i", t, mid)], 1)
    ok = crease & (np.abs(np.linalg.det(M)) > 1e-3)
    x0 = np.zeros_like(mid)
    x0[ok] = np.linalg.solve(M[ok], rhs[ok][:, :, None])[:, :, 0]
    a, b = V[ae[bnd, 0]], V[ae[bnd, 1]]
    ends = np.stack([a, b], 1)
    proj = x0[:, None, :] + np.einsum("ij,ikj->ik", t, ends - x0[:, None, :])[:, :, None] * t[:, None, :]
    ok &= np.linalg.norm(proj - ends, axis=2).max(1) <= r
    ends[ok] = proj[ok]
    tdir = _unit(b - a)
    sign = np.where(np.einsum("ij,ij->i", t, tdir) < 0, -1.0, 1.0)
    tdir[ok] = (t * sign[:, None])[ok]
    # silhouette-only: the rest of the surface where the denoised normals still turn (curved
    # patches); flat patches' faces are never a silhouette except where they meet another patch
    smooth_lim = max(smooth_angle_deg, 2.0 * resid)
    silh = np.nonzero((fang > smooth_lim) & (lab[adj[:, 0]] == lab[adj[:, 1]]))[0]
    nb = bnd[~crease]
    sel = np.concatenate([bnd[crease], nb, silh])
    n_c = int(crease.sum())
    feat = np.zeros(len(sel), bool)
    feat[:n_c] = True
    ends_all = np.concatenate([ends[crease], V[ae[nb]], V[ae[silh]]])
    dir_all = np.concatenate([tdir[crease], _unit(V[ae[nb, 1]] - V[ae[nb, 0]]),
                              _unit(V[ae[silh, 1]] - V[ae[silh, 0]])])
    fitted = np.zeros(len(sel), bool)
    fitted[:n_c] = ok[crease]
    info = {"radius_mm": r, "edge_mm": h, "filter_iterations": iters, "residual_deg": resid,
            "patches": len(np.unique(lab)), "crease_chains": len(np.unique(ch[crease[idx]])) if len(idx) else 0}
    return (ae[sel].astype(np.int64), adj[sel].astype(np.int64), feat, ends_all, dir_all, fitted, Nf, info)


# --------------------------------------------------------------------------------------------------
# entry point
# --------------------------------------------------------------------------------------------------


def feature_edges(mesh: trimesh.Trimesh, *, smooth_angle_deg: float = 2.0, feature_angle_deg: float = 30.0,
                  noisy: bool | None = None, radius_mm: float | None = None,
                  min_chain_mm: float | None = None) -> FeatureEdges:
    """Crease, boundary and silhouette-only edges of ``mesh`` (obj frame, mm).

    Parameters
    ----------
    smooth_angle_deg : faces closer to coplanar than this never give an edge
    feature_angle_deg : a crease turns the surface by more than this
    noisy : treat the mesh as a scan (None: decide by :func:`normal_noise_deg` > ``NOISY_MESH_DEG``)
    radius_mm : neighbourhood over which a noisy mesh's normals are compared (default three median
        edge lengths, more when the normals are very noisy)
    min_chain_mm : shorter crease chains of a noisy mesh are dropped (default max(3 mm, 3 radius))

    A clean mesh's creases are its face adjacencies above ``feature_angle_deg`` less the facet edges
    of coarsely tessellated round surfaces; a noisy mesh's are the boundaries between its smooth
    patches (see the module docstring).
    """
    noise = normal_noise_deg(mesh)
    is_noisy = noise > NOISY_MESH_DEG if noisy is None else bool(noisy)
    bv, bf = boundary_edges(mesh)
    V = mesh.vertices
    if is_noisy:
        ev, ef, feat, ends, dirs, fitted, Nf, info = _noisy_feature_edges(
            mesh, noise, smooth_angle_deg, feature_angle_deg, radius_mm, min_chain_mm)
    else:
        ang = np.degrees(mesh.face_adjacency_angles)
        keep = ang > smooth_angle_deg
        crease = ang > feature_angle_deg
        facet_edge = _tessellation_edges(mesh, ang, crease, smooth_angle_deg)
        ev = mesh.face_adjacency_edges[keep].astype(np.int64)
        ef = mesh.face_adjacency[keep].astype(np.int64)
        feat = (crease & ~facet_edge)[keep]
        ends = V[ev]
        dirs = _unit(ends[:, 1] - ends[:, 0])
        fitted = np.zeros(len(ev), bool)
        Nf = None
        info = {"facet_edges": int(facet_edge.sum())}
    info.update({"noise_deg": noise, "noisy": is_noisy})
    return FeatureEdges(
        edge_vertices=np.concatenate([ev, bv]), edge_faces=np.concatenate([ef, bf]),
        edge_feature=np.concatenate([feat, np.ones(len(bv), bool)]),
        edge_ends=np.concatenate([ends, V[bv]]),
        edge_line_dir=np.concatenate([dirs, _unit(V[bv[:, 1]] - V[bv[:, 0]])]),
        fitted=np.concatenate([fitted, np.zeros(len(bv), bool)]), face_normals=Nf, info=info)
