"""A part held between vise jaws (or pushed against a stop, an angle plate) touches a located fixture
face to face: that face fixes the part's position along its normal as the seat fixes its height.

One image sees a part on parallels of unknown height only up to a slide along the line of sight
(raised by dz it looks the same moved towards the camera); a jaw face across that slide pins it.
Frames: table (mm); a face is the plane ``n . x = d`` with ``n`` horizontal, pointing out of the
fixture towards the part.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from app.geometry.transforms import transform_points

#: a fixture face counts as a clamping face from this area (mm^2): a jaw is 30 x 100 mm and more,
#: the small vertical faces of a handle or a screw head are not
MIN_FACE_AREA_MM2 = 400.0
#: faces within this of vertical (|n_z|) can clamp
MAX_NORMAL_Z = 0.05
#: a part this close to a fixture face (mm) before the contact fit touches it: the flat fit of a part
#: on parallels of unknown height slides along the line of sight (devset setup_026: 0.4 mm from its
#: jaw); further off, the fixture itself may be misplaced (setup_006: a vise 2.6 mm off, held there,
#: put the part 1.6 mm off instead of 0.8)
MAX_GAP_MM = 1.5
#: a flat side of the part held against a jaw face cannot turn out of the jaw's plane (about the
#: table normal, nor about the jaw's horizontal axis): 1 sigma of that turn (a machined side's
#: squareness and the jaw's flatness), on top of the located fixture's own turn
FLUSH_SIGMA_DEG = 0.05
#: a part side counts as held flush when at the start it lies within this of the jaw's plane (the
#: jaws' starts put it there; a side turned further off is not against the face)
FLUSH_MAX_DEG = 2.0
#: a guided fixture (a vise's moving jaw in the body's ways) turns on its carrier only by the guide's
#: play: 1 sigma about the table normal and about the horizontal axis across the guide, on top of
#: the located carrier's own turn (a ways' play of 0.02-0.05 mm over a 50-100 mm long jaw; set from
#: that, not fitted)
GUIDE_SIGMA_DEG = 0.05
#: a part side is a flat that can be held from this area (mm^2): a pin's or a chamfer's facets are not
FLUSH_MIN_AREA_MM2 = 100.0


@dataclass(frozen=True)
class Face:
    """A planar face in the table frame: unit normal ``n``, offset ``d`` (``n . x = d``), its
    vertices ``pts`` (k, 3) and the variance (mm^2) of its offset from its fixture's pose."""

    name: str
    n: np.ndarray
    d: float
    pts: np.ndarray
    var_mm2: float = 0.0
    #: variance (rad^2) of the face's turn about the table normal and about its horizontal axis
    turn_var_rad2: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class SideContact:
    """A part face against a fixture face: the part's extreme point along ``n`` lies on ``n . x = d``
    within ``sigma_mm``; ``gap_mm`` is how far the part's face was from it before the fit. Where a
    flat side of the part lies against it, ``flat_obj`` is that side's outward normal (obj frame),
    held opposite ``n`` within ``turn_sigma_rad`` (about the table normal, about the face's
    horizontal axis). A guide's hold (:func:`guide_hold`) holds the turn alone."""

    name: str
    n: np.ndarray
    d: float
    sigma_mm: float
    gap_mm: float
    flat_obj: np.ndarray | None = None
    turn_sigma_rad: tuple[float, float] = (float("nan"), float("nan"))
    #: False: the contact holds the turn only (:func:`guide_hold`), not the place along ``n``
    holds_place: bool = True


@dataclass(frozen=True)
class Flats:
    """The part's plane sides that can be held (obj frame): outward unit normals (k, 3), a point on
    each (k, 3) and their areas (k,) mm^2."""

    normals: np.ndarray
    origins: np.ndarray
    areas: np.ndarray


def part_flats(mesh: trimesh.Trimesh, min_area_mm2: float = FLUSH_MIN_AREA_MM2) -> Flats:
    """The plane sides of ``mesh`` (its facets, and single triangles) of at least ``min_area_mm2``."""
    normals, origins, areas = [], [], []
    in_facet = np.zeros(len(mesh.faces), bool)
    for fi, (n, o, a) in enumerate(zip(mesh.facets_normal, mesh.facets_origin, mesh.facets_area)):
        in_facet[mesh.facets[fi]] = True
        if a >= min_area_mm2:
            normals.append(n)
            origins.append(o)
            areas.append(a)
    big = np.nonzero(~in_facet & (mesh.area_faces >= min_area_mm2))[0]
    normals += list(mesh.face_normals[big])
    origins += list(mesh.triangles_center[big])
    areas += list(mesh.area_faces[big])
    return Flats(np.asarray(normals, float).reshape(-1, 3), np.asarray(origins, float).reshape(-1, 3),
                 np.asarray(areas, float))


def along_face(n: np.ndarray) -> np.ndarray:
    """A vertical face's horizontal axis: the table normal crossed with its normal ``n``, unit."""
    u = np.cross([0.0, 0.0, 1.0], n)
    return u / max(np.linalg.norm(u), 1e-12)


def _turn_var(cov: np.ndarray, n: np.ndarray) -> tuple[float, float]:
    """Variance (rad^2) of a vertical plane's turn (normal ``n``, table frame) when its fixture turns
    with rotation-vector covariance ``cov[3:, 3:]`` (a 6x6 pose covariance): about the table normal
    and about the plane's horizontal axis."""
    u = along_face(n)
    return float(cov[5, 5]), float(u @ cov[3:, 3:] @ u)


def _turn_sigma(sigma_deg: float, turn_var: tuple[float, float]) -> tuple[float, float]:
    """1 sigma (rad) of a held turn: its own ``sigma_deg`` and the holder's ``turn_var`` (rad^2)."""
    s2 = np.radians(sigma_deg) ** 2
    return tuple(float(np.sqrt(s2 + max(v, 0.0))) for v in turn_var)


def _faces(mesh: trimesh.Trimesh, T: np.ndarray, name: str, vertical: bool, min_area: float) -> list[Face]:
    out = []
    R = T[:3, :3]
    for fi, (n_obj, area) in enumerate(zip(mesh.facets_normal, mesh.facets_area)):
        n = R @ np.asarray(n_obj, float)
        if area < min_area or (vertical and abs(n[2]) > MAX_NORMAL_Z):
            continue
        pts = transform_points(T, mesh.vertices[np.unique(mesh.faces[mesh.facets[fi]].ravel())])
        out.append(Face(name=name, n=n, d=float(n @ pts.mean(axis=0)), pts=pts))
    return out


def fixture_faces(mesh: trimesh.Trimesh, T_table_fix: np.ndarray, name: str,
                  cov_origin: np.ndarray | None = None) -> list[Face]:
    """The vertical faces of a located fixture that can hold a part (table frame), each with the
    variance of its offset that the fixture's own pose covariance ``cov_origin`` (6x6 over (origin
    x, y, z mm, rotation vector rad), table axes; None: exact) gives it."""
    faces = _faces(mesh, np.asarray(T_table_fix, float), name, vertical=True, min_area=MIN_FACE_AREA_MM2)
    if cov_origin is None:
        return faces
    o = np.asarray(T_table_fix, float)[:3, 3]
    cov = np.asarray(cov_origin, float)
    out = []
    for f in faces:
        # d(n . p) for a move dt and a turn w of the fixture about its origin: n . dt + ((c - o) x n) . w
        J = np.concatenate([f.n, np.cross(f.pts.mean(axis=0) - o, f.n)])
        JJ = np.outer(J, J)
        var = float(np.sum(np.where(JJ != 0.0, cov * JJ, 0.0)))
        turn = _turn_var(cov, f.n)        # the face turns with the fixture
        if np.isfinite(var):      # a face whose place is not known (NaN) holds nothing
            # (nor flush where its turn is not known: inf)
            out.append(Face(name=f.name, n=f.n, d=f.d, pts=f.pts, var_mm2=max(var, 0.0),
                            turn_var_rad2=tuple(max(v, 0.0) if np.isfinite(v) else np.inf for v in turn)))
    return out


def _overlap(a: np.ndarray, b: np.ndarray, n: np.ndarray, tol_mm: float = 0.5) -> bool:
    """Do the two point sets' extents meet when seen along ``n`` (horizontal across, and height)?"""
    for axis in (along_face(n), np.array([0.0, 0.0, 1.0])):
        pa, pb = a @ axis, b @ axis
        if min(pa.max(), pb.max()) - max(pa.min(), pb.min()) < -tol_mm:
            return False
    return True


def side_contacts(faces: list[Face], hull_obj: np.ndarray, T_table_obj: np.ndarray,
                  contact_sigma_mm: float, max_gap_mm: float = MAX_GAP_MM, flats: Flats | None = None,
                  flush_sigma_deg: float = FLUSH_SIGMA_DEG) -> list[SideContact]:
    """Fixture faces that the part at ``T_table_obj`` (its convex hull's vertices ``hull_obj``, obj
    frame) stands against: its extreme points towards the face are within ``max_gap_mm`` of it and
    within its outline (a flat side, or a boss's line, against a jaw). Each contact's sigma is the
    contact's own (``contact_sigma_mm``: a burr, the jaw's flatness) and the fixture's pose along the
    normal. At most one contact per normal direction (the nearest). Of the part's ``flats``, the
    largest that lies against the face (within :data:`FLUSH_MAX_DEG` of its plane, at the part's
    extreme towards it) is held flush: its turn within ``flush_sigma_deg`` and the fixture's own."""
    if not faces:
        return []
    T = np.asarray(T_table_obj, float)
    P = transform_points(T, hull_obj)
    N = at = None                         # the flats' normals and points, table frame
    if flats is not None and len(flats.areas):
        N, at = flats.normals @ T[:3, :3].T, transform_points(T, flats.origins)
    best: dict = {}
    for f in faces:
        ext = P @ f.n
        gap = float(ext.min() - f.d)
        if abs(gap) > max_gap_mm or not _overlap(f.pts, P[ext < ext.min() + 0.5], f.n):
            continue
        key = tuple(np.round(f.n, 1))
        if key not in best or abs(gap) < abs(best[key].gap_mm):
            flat, turn = None, (float("nan"), float("nan"))
            if N is not None and np.all(np.isfinite(f.turn_var_rad2)):
                against = (N @ -f.n >= np.cos(np.radians(FLUSH_MAX_DEG))) & (np.abs(at @ f.n - ext.min()) <= 0.5)
                if against.any():
                    k = int(np.argmax(np.where(against, flats.areas, -1.0)))
                    flat = flats.normals[k]
                    turn = _turn_sigma(flush_sigma_deg, f.turn_var_rad2)
            best[key] = SideContact(name=f.name, n=f.n, d=f.d,
                                    sigma_mm=float(np.sqrt(contact_sigma_mm ** 2 + f.var_mm2)), gap_mm=gap,
                                    flat_obj=flat, turn_sigma_rad=turn)
    return list(best.values())


def guide_hold(carrier: str, R_table_obj: np.ndarray, axis_table: np.ndarray,
               carrier_cov: np.ndarray | None, sigma_deg: float = GUIDE_SIGMA_DEG) -> SideContact | None:
    """The turn a guided fixture keeps on its located carrier, as a contact that holds the turn alone:
    its rotation ``R_table_obj`` on the guide (the carrier's turned by the guide's ``T_carrier_obj``),
    held about the table normal and about the horizontal axis across the guide's axis ``axis_table``
    (unit, table frame) within ``sigma_deg`` and the carrier's own turn (``carrier_cov``: its pose's
    6x6 over origin mm and rotation vector rad, table axes, without the table's share that both
    share; None: exact). A vise's moving jaw fitted freely turned up to 0.19 deg off its body (devset
    setup_006, the body 0.02 deg), and the part held flush against it turned with it. None for a
    guide that is not horizontal (within 60 deg of the table normal: a slide up an angle plate), whose
    turn this does not describe."""
    a = np.asarray(axis_table, float)
    a = a / max(float(np.linalg.norm(a)), 1e-12)
    if abs(a[2]) > 0.5:
        return None
    turn_var = _turn_var(np.zeros((6, 6)) if carrier_cov is None else np.asarray(carrier_cov, float), -a)
    if not all(np.isfinite(v) for v in turn_var):      # the carrier's turn not known: nothing held
        return None
    return SideContact(name=carrier, n=-a, d=0.0, sigma_mm=float("inf"), gap_mm=0.0,
                       flat_obj=np.asarray(R_table_obj, float).T @ a,
                       turn_sigma_rad=_turn_sigma(sigma_deg, turn_var), holds_place=False)


def side_gaps(P_table: np.ndarray, contacts) -> np.ndarray:
    """(gap / sigma) of each contact that holds a place for the part's hull points ``P_table`` (table
    frame): its extreme point along the face normal against the face (0 when touching)."""
    return np.array([(float((P_table @ c.n).min()) - c.d) / c.sigma_mm for c in contacts if c.holds_place])


def side_turns(R_table_obj: np.ndarray, contacts) -> np.ndarray:
    """(turn / sigma) of each flat side held against its face (:attr:`SideContact.flat_obj`): the small
    rotation that would lay it back against the face, about the table normal and about the face's
    horizontal axis (0 when flush); two per held flat, none for a contact without one."""
    out = []
    for c in contacts:
        if c.flat_obj is None:
            continue
        w = np.cross(R_table_obj @ c.flat_obj, -c.n)       # takes the side's normal onto -n
        out += [w[2] / c.turn_sigma_rad[0], float(w @ along_face(c.n)) / c.turn_sigma_rad[1]]
    return np.asarray(out, float)


def side_offsets(T: np.ndarray, hull_obj: np.ndarray, contacts) -> np.ndarray:
    """:func:`side_gaps` of the hull ``hull_obj`` (obj frame) placed at ``T``."""
    return side_gaps(transform_points(T, hull_obj), contacts) if contacts else np.zeros(0)
