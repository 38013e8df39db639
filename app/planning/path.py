"""Types shared by the path planners: probe parameters, axis speeds, planned moves and paths.

Frames and units: every point is ``(x, y, z)`` in mm in one Cartesian frame whose z axis points up
(the table frame, or the machine frame when ``T_machine_table`` has no rotation about x/y). A point's
z is the height of the sensor's *focal plane* (the reference method's convention): the lower end of
the sensor body sits ``working_distance_mm`` above it. For a touch probe the working distance is 0
and z is the height of the stylus tip.

Time model (both planners): a straight segment from ``p`` to ``q`` takes
``max(|dx| / v_x, |dy| / v_y, |dz| / v_z)``. That is the time of a rapid with independent
(non-coordinated) axes, each running at its own top speed, and equally of a coordinated linear move
whose feed is chosen so that the slowest axis runs at its limit. Acceleration is not modelled; a
fixed ``overhead_s`` per segment can stand in for the stop at each waypoint.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

Point = tuple[float, float, float]


@dataclass(frozen=True)
class ProbeParams:
    """The moving sensor or probe.

    working_distance_mm : lower end of the sensor to its focal plane (0 for a touch probe's tip).
    clearance_mm        : wanted gap between the sensor's lower end and any obstacle below it.
    radius_mm           : radius of the sensor body seen from above (a vertical cylinder). The
                          reference method has no lateral size (0); the collision check and the
                          profile planner use it.
    length_mm           : height of that cylinder above its lower end (the holder above is assumed
                          to clear everything).
    lateral_margin_mm   : extra sideways distance kept to obstacles (e.g. the located parts'
                          position uncertainty).
    """

    working_distance_mm: float
    clearance_mm: float
    radius_mm: float = 0.0
    length_mm: float = 100.0
    lateral_margin_mm: float = 0.0

    def __post_init__(self) -> None:
        for name in ("working_distance_mm", "clearance_mm", "radius_mm", "length_mm", "lateral_margin_mm"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"probe {name} must be a finite number >= 0, got {v}")
        if self.length_mm <= 0:
            raise ValueError(f"probe length_mm must be > 0, got {self.length_mm}")

    def safe_height_mm(self, obstacle_height_mm: float) -> float:
        """Lowest focal-plane height at which the sensor clears an obstacle top by the clearance:
        ``obstacle height + clearance - working distance`` (the reference's formula)."""
        return float(obstacle_height_mm) + self.clearance_mm - self.working_distance_mm


@dataclass(frozen=True)
class AxisSpeeds:
    """Top speed of each linear axis in mm/min (rapid traverse or the allowed travel feed)."""

    x_mm_min: float = 10000.0
    y_mm_min: float = 10000.0
    z_mm_min: float = 5000.0

    def __post_init__(self) -> None:
        for name in ("x_mm_min", "y_mm_min", "z_mm_min"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"axis speed {name} must be a finite number > 0, got {v}")

    def as_array_mm_s(self) -> np.ndarray:
        """(3,) speeds in mm/s."""
        return np.array([self.x_mm_min, self.y_mm_min, self.z_mm_min], dtype=float) / 60.0


@dataclass(frozen=True)
class PlannedMove:
    """One move between two consecutive points.

    pattern      : how the move goes ("straight", "over_then_down", "up_then_over", "up_over_down",
                   the shortening variants "diagonal_then_down", "up_then_diagonal", or "profile"
                   for the profile planner).
    waypoints    : the polyline from start to target inclusive, points in mm.
    obstacle_height_mm : obstacle height the decision used (for the profile planner: the highest
                   point under the move's corridor).
    safe_height_mm : focal-plane height that clears that obstacle height.
    """

    index: int
    start: Point
    target: Point
    pattern: str
    waypoints: tuple[Point, ...]
    obstacle_height_mm: float
    safe_height_mm: float


@dataclass(frozen=True)
class PlannedPath:
    """A whole path: the moves in order and the flattened waypoint list.

    method      : "reference" or "profile".
    coordinated : True when every segment must run as a coordinated straight move (G1 at the
                  feed from :func:`segment_feed_mm_min`); False when the segments may run as rapids
                  with independent axes (the reference method only assumes the box around each
                  segment is free).
    """

    method: str
    moves: tuple[PlannedMove, ...]
    coordinated: bool

    @property
    def waypoints(self) -> tuple[Point, ...]:
        """All waypoints in order, the shared point of consecutive moves listed once."""
        out: list[Point] = []
        for m in self.moves:
            for p in m.waypoints:
                if not out or out[-1] != p:
                    out.append(p)
        return tuple(out)

    def to_dict(self) -> dict:
        """Plain JSON-ready form (mm)."""
        return {
            "method": self.method,
            "coordinated": self.coordinated,
            "waypoints_mm": [list(p) for p in self.waypoints],
            "moves": [
                {
                    "index": m.index,
                    "pattern": m.pattern,
                    "start_mm": list(m.start),
                    "target_mm": list(m.target),
                    "obstacle_height_mm": m.obstacle_height_mm,
                    "safe_height_mm": m.safe_height_mm,
                    "waypoints_mm": [list(p) for p in m.waypoints],
                }
                for m in self.moves
            ],
        }


def as_points(points: ArrayLike, name: str = "points") -> np.ndarray:
    """Validate a point list: (N, 3) finite mm values, N >= 1. Raises ValueError with a sentence."""
    try:
        P = np.asarray(points, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected a list of [x, y, z] in mm ({exc})") from None
    if P.ndim != 2 or P.shape[1] != 3 or len(P) == 0:
        raise ValueError(f"{name}: expected shape (N, 3) with N >= 1, got {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError(f"{name}: contains NaN or infinity")
    return P


def pt(p: ArrayLike) -> Point:
    """A point as a plain tuple of three Python floats (rounded to 1e-9 mm so equal points compare equal)."""
    a = np.asarray(p, dtype=float).reshape(3)
    return (round(float(a[0]), 9), round(float(a[1]), 9), round(float(a[2]), 9))


def segment_times_s(waypoints: ArrayLike, speeds: AxisSpeeds) -> np.ndarray:
    """(M-1,) time of each segment of an (M, 3) polyline: ``max_i |d_i| / v_i`` (see module doc)."""
    W = np.asarray(waypoints, dtype=float).reshape(-1, 3)
    if len(W) < 2:
        return np.zeros(0)
    d = np.abs(np.diff(W, axis=0))
    return np.max(d / speeds.as_array_mm_s(), axis=1)


def path_length_mm(path: PlannedPath) -> float:
    """Euclidean length of the path's polyline in mm."""
    W = np.asarray(path.waypoints, dtype=float)
    return float(np.sum(np.linalg.norm(np.diff(W, axis=0), axis=1))) if len(W) > 1 else 0.0


def path_time_s(path: PlannedPath, speeds: AxisSpeeds, overhead_s: float = 0.0) -> float:
    """Travel time of the path in s with the axis speeds, plus ``overhead_s`` per non-empty segment."""
    t = segment_times_s(path.waypoints, speeds)
    return float(np.sum(t) + overhead_s * np.count_nonzero(t > 0))


def segment_feed_mm_min(p: ArrayLike, q: ArrayLike, speeds: AxisSpeeds) -> float:
    """Feed (mm/min along the path) of a coordinated straight move from p to q at which the slowest
    axis just reaches its limit: ``|q - p| / max_i(|d_i| / v_i)``."""
    d = np.abs(np.asarray(q, dtype=float) - np.asarray(p, dtype=float))
    length = float(np.linalg.norm(d))
    if length == 0:
        return float(min(speeds.x_mm_min, speeds.y_mm_min, speeds.z_mm_min))
    t_min = float(np.max(d / (speeds.as_array_mm_s() * 60.0)))
    return length / t_min


def noncoordinated_polyline(p: ArrayLike, q: ArrayLike, speeds: AxisSpeeds) -> np.ndarray:
    """(K, 3) polyline actually followed by a rapid from p to q whose axes start together and each
    run at its own top speed (a "dog-leg"): breakpoints where an axis arrives. Starts at p, ends at q."""
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    d = q - p
    v = speeds.as_array_mm_s()
    t_axis = np.abs(d) / v
    times = np.unique(np.concatenate([[0.0], t_axis]))
    pts = [p + np.sign(d) * np.minimum(v * t, np.abs(d)) for t in times]
    return np.asarray(pts)
