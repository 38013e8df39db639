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


@dataclass(frozen=True)
class Face:
    """A planar face in the table frame: unit normal ``n``, offset ``d`` (``n . x = d``), its
    vertices ``pts`` (k, 3) and the variance (mm^2) of its offset from its fixture's pose."""

    name: str
    n: np.ndarray
    d: float
    pts: np.ndarray
    var_mm2: float = 0.0


@dataclass(frozen=True)
class SideContact:
    """A part face against a fixture face: the part's extreme point along ``n`` lies on ``n . x = d``
    within ``sigma_mm``; ``gap_mm`` is how far the part's face was from it before the fit."""

    name: str
    n: np.ndarray
    d: float
    sigma_mm: float
    gap_mm: float


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
    out = []
    for f in faces:
        # d(n . p) for a move dt and a turn w of the fixture about its origin: n . dt + ((c - o) x n) . w
        J = np.concatenate([f.n, np.cross(f.pts.mean(axis=0) - o, f.n)])
        JJ = np.outer(J, J)
        var = float(np.sum(np.where(JJ != 0.0, np.asarray(cov_origin, float) * JJ, 0.0)))
        if np.isfinite(var):      # a face whose place is not known (NaN) holds nothing
            out.append(Face(name=f.name, n=f.n, d=f.d, pts=f.pts, var_mm2=max(var, 0.0)))
    return out


def _overlap(a: np.ndarray, b: np.ndarray, n: np.ndarray, tol_mm: float = 0.5) -> bool:
    """Do the two point sets' extents meet when seen along ``n`` (horizontal across, and height)?"""
    u = np.cross([0.0, 0.0, 1.0], n)
    u /= max(np.linalg.norm(u), 1e-12)
    for axis in (u, np.array([0.0, 0.0, 1.0])):
        pa, pb = a @ axis, b @ axis
        if min(pa.max(), pb.max()) - max(pa.min(), pb.min()) < -tol_mm:
            return False
    return True


def side_contacts(faces: list[Face], hull_obj: np.ndarray, T_table_obj: np.ndarray,
                  contact_sigma_mm: float, max_gap_mm: float = MAX_GAP_MM) -> list[SideContact]:
    """Fixture faces that the part at ``T_table_obj`` (its convex hull's vertices ``hull_obj``, obj
    frame) stands against: its extreme points towards the face are within ``max_gap_mm`` of it and
    within its outline (a flat side, or a boss's line, against a jaw). Each contact's sigma is the
    contact's own (``contact_sigma_mm``: a burr, the jaw's flatness) and the fixture's pose along the
    normal. At most one contact per normal direction (the nearest)."""
    if not faces:
        return []
    P = transform_points(np.asarray(T_table_obj, float), hull_obj)
    best: dict = {}
    for f in faces:
        ext = P @ f.n
        gap = float(ext.min() - f.d)
        if abs(gap) > max_gap_mm or not _overlap(f.pts, P[ext < ext.min() + 0.5], f.n):
            continue
        key = tuple(np.round(f.n, 1))
        if key not in best or abs(gap) < abs(best[key].gap_mm):
            best[key] = SideContact(name=f.name, n=f.n, d=f.d,
                                    sigma_mm=float(np.sqrt(contact_sigma_mm ** 2 + f.var_mm2)), gap_mm=gap)
    return list(best.values())


def side_gaps(P_table: np.ndarray, contacts) -> np.ndarray:
    """(gap / sigma) of each contact for the part's hull points ``P_table`` (table frame): its extreme
    point along the face normal against the face (0 when touching)."""
    return np.array([(float((P_table @ c.n).min()) - c.d) / c.sigma_mm for c in contacts])


def side_offsets(T: np.ndarray, hull_obj: np.ndarray, contacts) -> np.ndarray:
    """:func:`side_gaps` of the hull ``hull_obj`` (obj frame) placed at ``T``."""
    return side_gaps(transform_points(T, hull_obj), contacts) if contacts else np.zeros(0)
