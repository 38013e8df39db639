"""Starts for a part held between two located jaw faces: its stance follows the jaws.

A vise holds a part with two of its faces against two facing jaw faces: the part's turn about the
table normal is the jaws', its place across the jaws is the fixed jaw's, and the jaws' opening is its
width across them. Only the place along the jaws and the height (the seat, a parallel) are open. The
plane search (:mod:`.search`) knows none of this and looks everywhere at every turn; for a small part
deep between the jaws, partly hidden by them, its coarse correlation does not rank the part's cell
high enough (devset setup_034: the true pose scores best of all in the image, the nearest start the
search kept was 4 mm and 10 deg away). Here the few poses the jaws allow are scored in the image
directly (:func:`.search._image_scorer`, exact perspective) and aligned in the table plane. Where no
opening is located (the moving jaw not found), the fixed jaw alone holds the part: its turn and its
place across the jaw are still given, and any of its sides may face it.

Frames and units: table frame, mm and rad; a face as in :mod:`.clamping` (``n . x = d``, ``n``
horizontal, pointing out of its fixture towards the part).
"""

from __future__ import annotations

import numpy as np
import trimesh

from app.geometry.model_edges import PreparedModel
from app.geometry.transforms import make_pose, transform_points
from app.vision.object_pose.clamping import Face, along_face
from app.vision.object_pose.edge_image import EdgeImage
from app.vision.object_pose.planar_fit import planar_fit, sample_subset
from app.vision.object_pose.search import Hyp, _image_scorer, _spread_picks, edge_faces_of

#: two faces hold a part between them when their normals are this close to opposite (cos)
OPPOSITE_COS = -0.995
#: a part fits a jaw opening when its width across the jaws is within this of the opening (mm):
#: the jaws close on it, a located jaw is within a few tenths of its place
WIDTH_TOL_MM = 1.5
#: the faces and the part must share at least this much height and length (mm)
MIN_OVERLAP_MM = 3.0
#: a jaw is at least this tall (mm; a vise's jaws are 35 mm, the edges of its ways 8 mm: two of those
#: facing each other are a slot, not an opening that holds a part)
JAW_MIN_HEIGHT_MM = 20.0
#: a side of the part (a direction it can be held across) is a hull facet at least this large (mm^2)
MIN_SIDE_AREA_MM2 = 20.0
#: a lone jaw face (no opposite face located) has its foot at least this far above the table (mm;
#: the fixture's outer walls stand on the table)
LONE_MIN_Z_MM = 5.0


def _shared_extent(a: Face, b: Face, u: np.ndarray) -> tuple[float, float, float, float]:
    """What faces ``a`` and ``b`` share seen across the gap: (lo_u, hi_u) along ``u`` and (lo_z,
    hi_z) in height, mm (empty where lo > hi)."""
    return (max((a.pts @ u).min(), (b.pts @ u).min()), min((a.pts @ u).max(), (b.pts @ u).max()),
            max(a.pts[:, 2].min(), b.pts[:, 2].min()), min(a.pts[:, 2].max(), b.pts[:, 2].max()))


def jaw_openings(faces: tuple[Face, ...] | list[Face], max_gap_mm: float) -> list[tuple[Face, Face, float]]:
    """Pairs of faces that face each other across a gap of at most ``max_gap_mm`` and overlap when
    seen across it (along the jaws by :data:`MIN_OVERLAP_MM`, in height by :data:`JAW_MIN_HEIGHT_MM`):
    ``(a, b, gap mm)``, ``a`` the one listed first (each pair once)."""
    out = []
    for i, a in enumerate(faces):
        for b in faces[i + 1:]:
            if float(a.n @ b.n) > OPPOSITE_COS:
                continue
            gap = -(a.d + b.d)              # a: n.x >= d_a, b: -n.x >= d_b (n = a.n = -b.n)
            if not 0.0 < gap <= max_gap_mm:
                continue
            lo_u, hi_u, lo_z, hi_z = _shared_extent(a, b, along_face(a.n))
            if hi_u - lo_u >= MIN_OVERLAP_MM and hi_z - lo_z >= JAW_MIN_HEIGHT_MM:
                out.append((a, b, float(gap)))
    return out


def _sides(hull_rest: np.ndarray) -> np.ndarray:
    """Horizontal directions (resting frame, unit, one of each opposite pair) across which the part
    can be held: the normals of its convex hull's vertical facets."""
    try:
        hull = trimesh.convex.convex_hull(hull_rest)
    except Exception:  # noqa: BLE001 - a flat point set has no hull and no sides to hold
        return np.zeros((0, 3))
    out: list[np.ndarray] = []
    for n, area in zip(hull.facets_normal, hull.facets_area):
        if area < MIN_SIDE_AREA_MM2 or abs(n[2]) > 0.05:
            continue
        m = np.array([n[0], n[1], 0.0]) / max(np.hypot(n[0], n[1]), 1e-12)
        if not any(abs(float(m @ k)) > 0.999 for k in out):
            out.append(m)
    return np.array(out).reshape(-1, 3)


def _holds(faces, max_gap_mm: float) -> list[tuple]:
    """Where a part can be held: every jaw opening ``(a, gap, lo_u, hi_u, lo_z, hi_z)`` (``u`` along
    face ``a``, the extents both faces share); where there is none, every lone jaw face (a fixed jaw
    whose moving jaw was not located) with ``gap`` None: a vertical face at least
    :data:`JAW_MIN_HEIGHT_MM` tall whose foot stands :data:`LONE_MIN_Z_MM` above the table."""
    pairs: list[tuple] = jaw_openings(tuple(faces), max_gap_mm)
    if not pairs:
        pairs = [(f, f, None) for f in faces
                 if f.pts[:, 2].min() >= LONE_MIN_Z_MM and np.ptp(f.pts[:, 2]) >= JAW_MIN_HEIGHT_MM]
    return [(a, gap, *_shared_extent(a, b, along_face(a.n))) for a, b, gap in pairs]


def clamped_poses(model: PreparedModel, hull_obj: np.ndarray, faces, heights_mm, states,
                  step_mm: float) -> list[tuple[int, float, np.ndarray]]:
    """Every pose the jaws in ``faces`` allow the part (:func:`_holds`): per opening, resting state
    (of ``states``) and side whose width matches the opening within :data:`WIDTH_TOL_MM` (against a
    lone jaw, every side), both ways round, at each of ``heights_mm`` where the part's side meets
    the jaws, against face ``a`` and every ``step_mm`` along the jaws where the part lies within
    them. ``(state, height, T_table_obj)``."""
    out = []
    stances = []                                             # per state: its hull and sides, once
    for st in states:
        T_rest = model.resting_states[st].T_rest_obj
        H = transform_points(T_rest, hull_obj)
        stances.append((st, T_rest, H, _sides(H)))
    for a, gap, lo_u, hi_u, lo_z, hi_z in _holds(faces, float(model.diameter_mm)):
        n, u = a.n, along_face(a.n)
        phi_n = float(np.arctan2(n[1], n[0]))
        for st, T_rest, H, sides in stances:
            for m in sides:
                if gap is not None and abs(float(np.ptp(H @ m)) - gap) > WIDTH_TOL_MM:
                    continue
                for sign in (1.0, -1.0):                     # which of the two sides faces a
                    th = phi_n - float(np.arctan2(sign * m[1], sign * m[0]))
                    c, s = np.cos(th), np.sin(th)
                    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
                    P = H @ R.T
                    across = a.d - float((P @ n).min())      # touching face a
                    pu = P @ u
                    span = (lo_u - pu.min(), hi_u - pu.max())  # the part's whole length within the jaws
                    if span[1] < span[0]:
                        span = (0.5 * (span[0] + span[1]),) * 2
                    along = np.arange(span[0], span[1] + 1e-9, step_mm) if span[1] > span[0] else \
                        np.array([span[0]])
                    for h in heights_mm:
                        if min(hi_z, h + P[:, 2].max()) - max(lo_z, h + P[:, 2].min()) < MIN_OVERLAP_MM:
                            continue
                        for t_u in along:
                            t = across * n + t_u * u + np.array([0.0, 0.0, h])
                            out.append((st, float(h), make_pose(R, t) @ T_rest))
    return out


def clamped_starts(model: PreparedModel, hull_obj: np.ndarray, faces, heights_mm, states, eimg: EdgeImage,
                   K, dist, T_cam_table, px_per_mm: float, n_keep: int = 2) -> list[Hyp]:
    """Starts for the part held between the located jaw faces ``faces``: the poses of
    :func:`clamped_poses` (a step of 2.5 px along the jaws) scored in the image (3 px, exact
    perspective, only the samples that can show), the best ``n_keep`` of every (state, height)
    aligned in the table plane. Empty when no opening fits the part."""
    step = max(2.5 / max(px_per_mm, 1e-9), 0.5)
    poses = clamped_poses(model, hull_obj, faces, heights_mm, states, step)
    if not poses:
        return []
    scorer = _image_scorer(eimg, K, dist, T_cam_table, tau_px=3.0)
    sel = _spread_picks(model.edge_feature[model.sample_edge], 150)
    groups: dict = {}
    for k, (st, h, T) in enumerate(poses):
        groups.setdefault((st, h), []).append(k)
    sub = sample_subset(model, px_per_mm, 4.0, 400)
    templates: dict = {}                 # per state: the template in the resting frame, once
    hyps = []
    for (st, h), ks in groups.items():
        if st not in templates:
            T_rest = model.resting_states[st].T_rest_obj
            templates[st] = (transform_points(T_rest, model.samples_obj[sel]),
                             model.sample_dir_obj[sel] @ T_rest[:3, :3].T,
                             edge_faces_of(model, T_rest, sel), np.linalg.inv(T_rest))
        P, D, shows, inv_rest = templates[st]
        M = [poses[k][2] @ inv_rest for k in ks]             # Trans(x, y, h) @ Rz(theta)
        hx = np.array([q[0, 3] for q in M])
        hy = np.array([q[1, 3] for q in M])
        ht = np.array([np.arctan2(q[1, 0], q[0, 0]) for q in M])
        sc = scorer(hx, hy, ht, P + np.array([0.0, 0.0, h]), D, np.ones(len(sel)), normals=shows)
        for i in np.argsort(-sc)[:n_keep]:
            hyp = Hyp(state=st, T_table_obj=poses[ks[i]][2], votes=float(sc[i]), height_mm=h, source="clamped")
            hyps.append(planar_fit(eimg, model, hyp, T_cam_table, K, dist, sub))
    return hyps
