"""Where the table sits in machine coordinates, from jogged points, the way a setter finds it.

The table frame (DESIGN): origin at the front-left corner of the table's top face, x along the front
edge, y along the left edge, z up. The setter touches (jogs the spindle or a probe to):

1. the corner: the origin, so ``T_machine_table``'s translation is that point;
2. optionally a point on the front (x) edge: the edge's direction gives the rotation C about machine Z;
3. optionally a point on the left (y) edge: a second estimate of C (the edge is at C + 90°), which also
   checks that the points were read right.

The table is taken level (rotation about Z only, like the work offsets this service writes); heights of
points 2 and 3, when given, only report how far the top drops along an edge. All in mm and degrees,
machine coordinates; C counter-clockwise seen from +Z, from machine +X to the table's x edge.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: a second point closer than this to the corner gives too rough an angle (1 mm of error = 1.1°)
MIN_SPAN_MM = 50.0
#: the x and y edges may disagree by this much before the points are refused as misread (degrees)
MAX_EDGE_DISAGREEMENT_DEG = 1.0


class TableFrameError(ValueError):
    """The points cannot give a table frame; the message says which point and why."""


@dataclass(frozen=True)
class TableFrameFit:
    """``T_machine_table`` (4x4, mm) with the angle and what the points say about their own quality."""

    T_machine_table: np.ndarray
    c_deg: float
    notes: tuple[str, ...]
    #: |ΔC| between the x-edge and y-edge estimates (degrees), None with fewer than three points
    edge_disagreement_deg: float | None
    #: C's change per mm of error at the points used (degrees per mm), None with the corner alone
    c_sensitivity_deg_per_mm: float | None


def _xy(point, name: str) -> np.ndarray:
    p = np.asarray(point, dtype=float).reshape(-1)
    if p.size not in (2, 3) or not np.all(np.isfinite(p)):
        raise TableFrameError(f"{name}: give X and Y (and Z) in mm, got {point!r}")
    return p


def _edge_angle(corner: np.ndarray, point: np.ndarray, name: str) -> tuple[float, float]:
    """(angle of corner -> point about +Z in degrees, span in mm)."""
    d = point[:2] - corner[:2]
    span = float(np.hypot(*d))
    if span < MIN_SPAN_MM:
        raise TableFrameError(f"{name} is {span:.1f} mm from the corner; jog to a point on that edge at least "
                              f"{MIN_SPAN_MM:.0f} mm away (the farther, the better the angle)")
    return math.degrees(math.atan2(d[1], d[0])), span


def _wrap(angle_deg: float) -> float:
    return (angle_deg + 180.0) % 360.0 - 180.0


def table_frame_from_points(corner, x_point=None, y_point=None, c_deg: float | None = None) -> TableFrameFit:
    """The table's pose from a jogged corner (x, y, z) and optional edge points (x, y[, z]); see module doc.
    ``c_deg``: the angle as typed, used only when no edge point is given.

    Raises TableFrameError when a point is too close to the corner or the two edges disagree by more than
    MAX_EDGE_DISAGREEMENT_DEG (a point on the wrong edge, or a number typed wrong).
    """
    o = _xy(corner, "point 1 (the corner)")
    if o.size != 3:
        raise TableFrameError("point 1 (the corner): give X, Y and Z in mm; its Z is the table top")
    notes: list[str] = []
    estimates: list[tuple[float, float]] = []   # (C in degrees, span in mm)
    heights: list[tuple[str, float, float]] = []
    for name, point, turn in (("point 2 (front edge)", x_point, 0.0), ("point 3 (left edge)", y_point, 90.0)):
        if point is None:
            continue
        p = _xy(point, name)
        angle, span = _edge_angle(o, p, name)
        estimates.append((_wrap(angle - turn), span))
        if p.size == 3:
            heights.append((name, float(p[2] - o[2]), span))
    disagreement = None
    if not estimates:
        sensitivity = None
        if c_deg is None or not math.isfinite(c_deg):
            c_deg = 0.0
            notes.append("C = 0: the table is taken square to the machine; jog to a point on the front edge to "
                         "measure it")
        else:
            c_deg = _wrap(float(c_deg))
            notes.append(f"C = {c_deg:.4f}° as typed; jog to a point on the front edge to measure it")
    else:
        if len(estimates) == 2:
            disagreement = abs(_wrap(estimates[0][0] - estimates[1][0]))
            if disagreement > MAX_EDGE_DISAGREEMENT_DEG:
                raise TableFrameError(
                    f"the front edge (point 2) gives C = {estimates[0][0]:.3f}° but the left edge (point 3) "
                    f"C = {estimates[1][0]:.3f}°: {disagreement:.2f}° apart. Is point 3 on the left edge and "
                    "point 2 on the front edge, and are the numbers read right?")
        # angles weighted by span²: an angle's error from a position error falls with the span
        w = np.array([s ** 2 for _, s in estimates])
        ref = estimates[0][0]
        c_deg = _wrap(ref + float(np.sum(w * [_wrap(c - ref) for c, _ in estimates]) / w.sum()))
        sensitivity = math.degrees(1.0 / math.sqrt(float(w.sum())))
        notes.append(f"C = {c_deg:.4f}° from {len(estimates) + 1} points; 1 mm of error at the edge point(s) moves "
                     f"C by {sensitivity:.3f}°")
        if disagreement is not None:
            notes.append(f"the front and left edges agree within {disagreement:.3f}° (squareness and reading)")
    for name, dz, span in heights:
        if abs(dz) > 0.01:
            notes.append(f"{name} is {dz:+.3f} mm above the corner ({dz / span * 1000:+.2f} mm per m): "
                         "the table is taken level at the corner's height")
    c = math.radians(c_deg)
    T = np.eye(4)
    T[:2, :2] = [[math.cos(c), -math.sin(c)], [math.sin(c), math.cos(c)]]
    T[:3, 3] = o
    return TableFrameFit(T, c_deg, tuple(notes), disagreement, sensitivity)
