"""Profile planner: shorter and faster moves over only what is really in the way (issue 8, item 2).

The reference method lifts the sensor above the highest point of the whole xy box between two
points. This planner keeps the straight xy line of the move and looks only at the corridor the
sensor body sweeps: the obstacle heights within ``radius_mm + lateral_margin_mm`` of the xy
segment, as a step function along the move (one value per step, each an upper bound over its
step's capsule; see :meth:`ObstacleSource.profile_mm`). Required focal-plane height per step:
``Z_k = H_k + clearance - working distance``.

In the vertical plane of the move, with ``s`` the distance along the xy line, the path from
``(0, z0)`` to ``(L, z1)`` must stay above the step function. The shortest such path is the upper
convex hull of the two end points and the corners of the steps (a string pulled taut over the
obstacles): it climbs straight up at the start only when the start is below its own step, ramps
diagonally over the obstacles that matter and descends onto the target. The hull is concave, so its
height rises and then falls once: its total climb and descent equal the unavoidable minimum
(max(H) above each end), and every segment is as short as the obstacles allow. Under the time model
of app/planning/path.py (``max_i |d_i| / v_i`` per segment) this makes it as fast as a straight
xy move whenever the ramps are no steeper than ``v_z / v_xy``; the tests compare it with a dynamic
programme on a grid.

Detours (``ProfileOptions(speeds=...)``): when a move must climb above the higher of its two ends,
the planner also tries going around: the xy area where something would force that climb
(``blocked_xy`` of the obstacle source, grown by the corridor radius) is avoided by the fastest
route of a visibility graph over its corners (edge cost ``max(|dx|/v_x, |dy|/v_y)``, Dijkstra),
flown at the higher end's height, each leg again as a taut path. The faster of "over" and "around"
under the axis speeds is kept; so with a slow z axis the sensor goes round a tall block, with a fast
one it hops over.

Vertical segments at the two ends rely on the scene being 2.5-D (nothing overhangs a measuring
position), as the reference method does. All segments are meant to run as coordinated straight
moves (G1 at :func:`app.planning.path.segment_feed_mm_min`), so the swept volume is exactly the
segment's; the path is marked ``coordinated=True``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from numpy.typing import ArrayLike
from scipy.sparse.csgraph import dijkstra
from shapely.geometry import LineString, Point
from shapely.geometry import box as shapely_box

from app.planning.obstacles import ObstacleSource
from app.planning.path import AxisSpeeds, PlannedMove, PlannedPath, ProbeParams, as_points, pt, segment_times_s


@dataclass(frozen=True)
class ProfileOptions:
    """step_mm : length of one profile step along the xy line (finer: tighter ramps, slower).
    max_steps : cap on steps per move (long moves get longer steps).
    speeds    : with axis speeds (and an obstacle source that has ``blocked_xy``), every move that
                must climb above its higher end also gets a detour candidate: the fastest xy route
                (visibility graph, time-weighted with the axis speeds) around everything that forces
                that climb, flown at the higher end's height. The faster of the two is kept.
    max_detour_factor : detour routes are searched within an ellipse whose xy length is at most this
                factor times the straight xy distance."""

    step_mm: float = 1.0
    max_steps: int = 4000
    speeds: AxisSpeeds | None = None
    max_detour_factor: float = 2.5

    def __post_init__(self) -> None:
        if not np.isfinite(self.step_mm) or self.step_mm <= 0:
            raise ValueError(f"step_mm must be > 0, got {self.step_mm}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {self.max_steps}")


def upper_hull(s: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Upper convex hull (K, 2) of points (s, z) sorted by s, left to right (Andrew's monotone chain).
    Points sharing an s keep only their highest z; collinear middle points are dropped."""
    order = np.lexsort((-z, s))
    s, z = s[order], z[order]
    keep = np.ones(len(s), dtype=bool)
    keep[1:] = s[1:] != s[:-1]  # first of each s is the highest
    s, z = s[keep], z[keep]
    hull: list[tuple[float, float]] = []
    for p in zip(s.tolist(), z.tolist()):
        while len(hull) >= 2:
            (ox, oy), (ax, ay) = hull[-2], hull[-1]
            if (ax - ox) * (p[1] - oy) - (ay - oy) * (p[0] - ox) >= 0:
                hull.pop()
            else:
                break
        hull.append(p)
    return np.asarray(hull, dtype=float)


def taut_path_sz(L_mm: float, z0_mm: float, z1_mm: float, required_z_mm: np.ndarray) -> np.ndarray:
    """(K, 2) vertices (s, z) of the shortest path from (0, z0) to (L, z1) above the step function
    whose n equal steps over [0, L] have the heights ``required_z_mm`` (n,)."""
    Z = np.asarray(required_z_mm, dtype=float)
    n = len(Z)
    edges = np.linspace(0.0, L_mm, n + 1)
    # runs of equal steps: only their two outer corners can be hull vertices
    new_run = np.r_[True, Z[1:] != Z[:-1]]
    first = np.flatnonzero(new_run)
    last = np.r_[first[1:] - 1, n - 1]
    s = np.concatenate([[0.0, L_mm], edges[first], edges[last + 1]])
    z = np.concatenate([[z0_mm, z1_mm], Z[first], Z[first]])
    hull = upper_hull(s, z)
    if hull[0, 1] > z0_mm:
        hull = np.vstack([[0.0, z0_mm], hull])
    if hull[-1, 1] > z1_mm:
        hull = np.vstack([hull, [L_mm, z1_mm]])
    return hull


def _straight_move(index, start, target, obstacles, probe, options) -> PlannedMove:
    """Taut path over the profile of the straight xy line from start to target."""
    a = np.asarray(start, dtype=float)
    b = np.asarray(target, dtype=float)
    L = float(np.linalg.norm(b[:2] - a[:2]))
    if L < 1e-9:
        return PlannedMove(index, pt(a), pt(b), "profile", (pt(a), pt(b)) if pt(a) != pt(b) else (pt(a),),
                           float("-inf"), float("-inf"))
    n = int(min(options.max_steps, max(1, np.ceil(L / options.step_mm))))
    H = obstacles.profile_mm(index, a[:2], b[:2], probe.radius_mm + probe.lateral_margin_mm, n)
    Z = H + probe.clearance_mm - probe.working_distance_mm
    sz = taut_path_sz(L, float(a[2]), float(b[2]), Z)
    u = (b[:2] - a[:2]) / L
    wps = []
    for s, z in sz:
        wps.append(pt((a[0] + s * u[0], a[1] + s * u[1], z)))
    wps[0], wps[-1] = pt(a), pt(b)
    return PlannedMove(index, pt(a), pt(b), "profile", tuple(wps), float(H.max()), float(Z.max()))


def _xy_time(P: np.ndarray, Q: np.ndarray, speeds: AxisSpeeds) -> np.ndarray:
    v = speeds.as_array_mm_s()[:2]
    return np.max(np.abs(Q - P) / v, axis=-1)


def visibility_route(a_xy: ArrayLike, b_xy: ArrayLike, blocked, speeds: AxisSpeeds, max_factor: float = 2.5):
    """Fastest xy polyline from a to b that does not enter ``blocked`` (shapely geometry), bending only
    at its (slightly grown, simplified) corners; edge cost ``max(|dx|/v_x, |dy|/v_y)``. Returns the
    (K, 2) via points between a and b, or None when there is no such route within the ellipse of
    ``max_factor`` times the straight distance."""
    a = np.asarray(a_xy, dtype=float)[:2]
    b = np.asarray(b_xy, dtype=float)[:2]
    L = float(np.linalg.norm(b - a))
    if blocked.is_empty or not blocked.intersects(LineString([a, b])):
        return np.zeros((0, 2))
    reach = max_factor * L
    mid, half = (a + b) / 2, reach / 2 + 1.0
    window = shapely_box(mid[0] - half, mid[1] - half, mid[0] + half, mid[1] + half)
    local = blocked.intersection(window)
    grown = local.buffer(0.5, join_style="mitre").simplify(1.0)
    parts = getattr(grown, "geoms", [grown])
    corners = [np.asarray(g.exterior.coords)[:-1] for g in parts if g.geom_type == "Polygon" and not g.is_empty]
    if not corners:
        return None
    V = np.vstack(corners)
    V = V[np.linalg.norm(V - a, axis=1) + np.linalg.norm(V - b, axis=1) <= reach]
    nodes = np.vstack([a, b, V])
    n = len(nodes)
    if n > 160:  # keep it cheap: the corners nearest the straight line
        d = np.linalg.norm(V - a, axis=1) + np.linalg.norm(V - b, axis=1)
        nodes = np.vstack([a, b, V[np.argsort(d)[:158]]])
        n = len(nodes)
    iu, ju = np.triu_indices(n, 1)
    lines = shapely.linestrings(np.stack([nodes[iu], nodes[ju]], axis=1))
    shapely.prepare(local)
    free = ~shapely.intersects(local, lines)
    W = np.zeros((n, n))
    cost = _xy_time(nodes[iu[free]], nodes[ju[free]], speeds) + 1e-9
    W[iu[free], ju[free]] = cost
    W[ju[free], iu[free]] = cost
    dist, pred = dijkstra(W, directed=False, indices=0, return_predecessors=True)
    if not np.isfinite(dist[1]):
        return None
    route = []
    k = pred[1]
    while k != 0:
        route.append(nodes[k])
        k = pred[k]
    return np.asarray(route[::-1]).reshape(-1, 2)


def plan_move_profile(
    index: int,
    start: ArrayLike,
    target: ArrayLike,
    obstacles: ObstacleSource,
    probe: ProbeParams,
    options: ProfileOptions = ProfileOptions(),
) -> PlannedMove:
    """One move of the profile planner (see the module doc), with the detour candidate when
    ``options.speeds`` is given. Points in mm, focal-plane heights."""
    direct = _straight_move(index, start, target, obstacles, probe, options)
    if options.speeds is None or not hasattr(obstacles, "blocked_xy"):
        return direct
    a = np.asarray(start, dtype=float)
    b = np.asarray(target, dtype=float)
    z_level = max(a[2], b[2])
    if direct.safe_height_mm <= z_level + 1e-9:
        return direct  # nothing forces a climb above the higher end
    level_h = z_level - probe.clearance_mm + probe.working_distance_mm
    try:
        # the profile of a step looks (radius + half a step) around its centre: block at least that
        blocked = obstacles.blocked_xy(level_h, probe.radius_mm + probe.lateral_margin_mm + options.step_mm / 2.0)
    except ValueError:
        return direct
    if blocked.is_empty or blocked.contains(Point(a[:2])) or blocked.contains(Point(b[:2])):
        return direct
    route = visibility_route(a[:2], b[:2], blocked, options.speeds, options.max_detour_factor)
    if route is None or len(route) == 0:
        return direct
    stops = [a] + [np.array([v[0], v[1], z_level]) for v in route] + [b]
    wps: list = []
    for p, q in zip(stops[:-1], stops[1:]):
        for w in _straight_move(index, p, q, obstacles, probe, options).waypoints:
            if not wps or wps[-1] != w:
                wps.append(w)
    t_direct = float(np.sum(segment_times_s(direct.waypoints, options.speeds)))
    t_detour = float(np.sum(segment_times_s(wps, options.speeds)))
    if t_detour >= t_direct - 1e-9:
        return direct
    return PlannedMove(index, direct.start, direct.target, "profile_detour", tuple(wps),
                       direct.obstacle_height_mm, direct.safe_height_mm)


def plan_path_profile(
    points: ArrayLike,
    obstacles: ObstacleSource,
    probe: ProbeParams,
    options: ProfileOptions = ProfileOptions(),
) -> PlannedPath:
    """Plan the moves through ``points`` (N, 3, mm, focal-plane heights) with the profile planner.

    ``obstacles``: any source of app/planning/obstacles.py; a :class:`HeightGrid` from the scene
    meshes or a :class:`RegionMap` gives real profiles, per-move / part-top sources give flat ones.
    Returns a path with ``coordinated=True``.
    """
    P = as_points(points)
    moves = tuple(plan_move_profile(i, P[i], P[i + 1], obstacles, probe, options) for i in range(len(P) - 1))
    return PlannedPath("profile", moves, coordinated=True)
