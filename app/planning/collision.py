"""Independent collision check: the swept sensor body against the scene meshes (issue 8, item 2).

Independent of every planner: it never looks at a height map, a region map or a safe height. It
takes the located meshes at their poses (``T_table_obj``) and the path's segments, and tests the
volume the body sweeps along each segment for intersection with each mesh using FCL (python-fcl).

The body is a stack of vertical cylinders given relative to the focal point (z offsets in mm;
a sensor with working distance w and length l is one cylinder from +w to +w+l; a touch probe can be
stylus + body). Each cylinder is a regular 16-gon prism *circumscribing* the circle, so the test is
conservative. The volume swept by a convex body under a straight translation ``d`` is exactly the
convex hull of the body at the start and at the end (the Minkowski sum of the body with the segment),
so one convex-vs-mesh test per cylinder and segment is exact for that prism: no sampling gaps.

Segments that run as non-coordinated rapids (``PlannedPath.coordinated == False``) are first turned
into the dog-leg polyline the axes really follow (each axis at its own top speed,
:func:`app.planning.path.noncoordinated_polyline`).

FCL tests surfaces; a swept body entirely inside a mesh (or a mesh inside the swept body) does not
cross a surface, so those two cases are caught with a point-in-mesh / point-in-hull test whenever
the bounding boxes allow them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import fcl
import numpy as np
import trimesh
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull, QhullError

from app.geometry.transforms import check_pose, transform_points
from app.planning.path import AxisSpeeds, PlannedPath, Point, ProbeParams, noncoordinated_polyline, pt

N_SIDES = 16


@dataclass(frozen=True)
class BodyCylinder:
    """Vertical cylinder of the sensor body: radius and z range relative to the focal point (mm)."""

    radius_mm: float
    z_from_mm: float
    z_to_mm: float


@dataclass(frozen=True)
class ProbeBody:
    cylinders: tuple[BodyCylinder, ...]

    @staticmethod
    def from_probe(probe: ProbeParams, shrink_mm: float = 0.0) -> ProbeBody:
        """One cylinder of the probe's radius from its lower end (focal point + working distance) up
        ``length_mm``; ``shrink_mm`` makes it smaller on every side (for touching moves)."""
        r = max(probe.radius_mm - shrink_mm, 0.01)
        z0 = probe.working_distance_mm + shrink_mm
        return ProbeBody((BodyCylinder(r, z0, probe.working_distance_mm + probe.length_mm),))

    def points_at(self, p: ArrayLike) -> list[np.ndarray]:
        """Corner points (2*N_SIDES, 3) of each cylinder's circumscribed prism at focal point p."""
        p = np.asarray(p, dtype=float).reshape(3)
        out = []
        for c in self.cylinders:
            P = _unit_prism(c.radius_mm / np.cos(np.pi / N_SIDES), c.z_from_mm, c.z_to_mm)
            out.append(P + p)
        return out


@lru_cache(maxsize=64)
def _unit_prism(R: float, z_from: float, z_to: float) -> np.ndarray:
    th = (np.arange(N_SIDES) + 0.5) * 2 * np.pi / N_SIDES
    ring = np.stack([R * np.cos(th), R * np.sin(th)], axis=1)
    P = np.vstack([np.column_stack([ring, np.full(N_SIDES, z_from)]), np.column_stack([ring, np.full(N_SIDES, z_to)])])
    P.setflags(write=False)
    return P


@dataclass(frozen=True)
class CollisionHit:
    """Segment ``segment_index`` (from ``start`` to ``end``, mm) of the checked polyline hits mesh
    ``obstacle`` (its name)."""

    segment_index: int
    start: Point
    end: Point
    obstacle: str


@dataclass(frozen=True)
class CollisionReport:
    ok: bool
    hits: tuple[CollisionHit, ...]
    n_segments: int

    def reason(self) -> str:
        if self.ok:
            return f"no collision on {self.n_segments} segments"
        h = self.hits[0]
        return (f"{len(self.hits)} of {self.n_segments} segments collide; first: segment {h.segment_index} "
                f"from {h.start} to {h.end} hits {h.obstacle}")


class Scene:
    """The located meshes as FCL objects (built once, then many segment checks).

    meshes : trimesh meshes in their obj frames (mm); poses : T_table_obj (4, 4) each; names : labels.
    """

    def __init__(self, meshes: Sequence[trimesh.Trimesh], poses: Sequence[ArrayLike], names: Sequence[str] | None = None):
        if len(meshes) != len(poses):
            raise ValueError(f"{len(meshes)} meshes but {len(poses)} poses; give one pose per mesh")
        self.names = list(names) if names else [f"mesh_{k}" for k in range(len(meshes))]
        self.meshes: list[trimesh.Trimesh] = []
        self.objects: list[fcl.CollisionObject] = []
        lo, hi = [], []
        for k, (m, T) in enumerate(zip(meshes, poses)):
            V = transform_points(check_pose(T, f"T_table_obj of {self.names[k]}"), m.vertices)
            posed = trimesh.Trimesh(V, m.faces, process=False)
            self.meshes.append(posed)
            bvh = fcl.BVHModel()
            bvh.beginModel(len(V), len(m.faces))
            bvh.addSubModel(V, np.asarray(m.faces, dtype=np.int64))
            bvh.endModel()
            self.objects.append(fcl.CollisionObject(bvh, fcl.Transform()))
            lo.append(V.min(axis=0))
            hi.append(V.max(axis=0))
        self.lo = np.asarray(lo).reshape(-1, 3)
        self.hi = np.asarray(hi).reshape(-1, 3)

    def hit_by_hull(self, pts: np.ndarray) -> list[int]:
        """Indices of meshes that intersect the convex hull of ``pts`` (K, 3)."""
        plo, phi = pts.min(axis=0), pts.max(axis=0)
        cand = np.flatnonzero(np.all(self.lo <= phi, axis=1) & np.all(self.hi >= plo, axis=1))
        if len(cand) == 0:
            return []
        try:
            hull = ConvexHull(pts)
        except QhullError:  # flat (zero-thickness) body: thicken by a micron
            hull = ConvexHull(np.vstack([pts, pts + 1e-3]))
            pts = hull.points
        faces = np.hstack([np.full((len(hull.simplices), 1), 3), hull.simplices]).ravel()
        obj = fcl.CollisionObject(fcl.Convex(hull.points, len(hull.simplices), faces), fcl.Transform())
        hits = []
        for k in cand:
            if fcl.collide(self.objects[k], obj, fcl.CollisionRequest(), fcl.CollisionResult()):
                hits.append(int(k))
                continue
            # no surface crossing: one may still lie inside the other
            if np.all(self.lo[k] <= plo) and np.all(self.hi[k] >= phi):
                if self.meshes[k].is_watertight and bool(self.meshes[k].contains(pts[:1])[0]):
                    hits.append(int(k))
                    continue
            if np.all(plo <= self.lo[k]) and np.all(phi >= self.hi[k]):
                v = self.meshes[k].vertices[0]
                if np.all(hull.equations[:, :3] @ v + hull.equations[:, 3] <= 1e-9):
                    hits.append(int(k))
        return hits

    def check_segment(self, p: ArrayLike, q: ArrayLike, body: ProbeBody) -> list[int]:
        """Meshes hit by ``body`` moving in a straight line from focal point p to q (mm)."""
        hits: set[int] = set()
        for a, b in zip(body.points_at(p), body.points_at(q)):
            hits.update(self.hit_by_hull(np.vstack([a, b])))
        return sorted(hits)

    def check_polyline(self, waypoints: ArrayLike, body: ProbeBody) -> CollisionReport:
        """Check every segment of a (M, 3) polyline of focal points; a single point is checked too."""
        W = np.asarray(waypoints, dtype=float).reshape(-1, 3)
        hits = []
        segs = list(zip(W[:-1], W[1:])) if len(W) > 1 else [(W[0], W[0])]
        for k, (p, q) in enumerate(segs):
            for idx in self.check_segment(p, q, body):
                hits.append(CollisionHit(k, pt(p), pt(q), self.names[idx]))
        return CollisionReport(not hits, tuple(hits), len(segs))


def executed_polyline(path: PlannedPath, speeds: AxisSpeeds) -> np.ndarray:
    """(K, 3) polyline the machine really follows: the waypoints for coordinated paths, the dog-leg
    of every segment for paths that may run as non-coordinated rapids."""
    W = np.asarray(path.waypoints, dtype=float)
    if path.coordinated or len(W) < 2:
        return W
    out = [W[0]]
    for p, q in zip(W[:-1], W[1:]):
        out.extend(noncoordinated_polyline(p, q, speeds)[1:])
    return np.asarray(out)


def check_path(path: PlannedPath, scene: Scene, body: ProbeBody, speeds: AxisSpeeds = AxisSpeeds()) -> CollisionReport:
    """Collision check of a planned path as it is executed (see :func:`executed_polyline`)."""
    return scene.check_polyline(executed_polyline(path, speeds), body)
