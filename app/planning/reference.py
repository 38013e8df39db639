"""The reference method for collision-safe travel between measuring points (issue 8, item 1).

For each move from a start point to a target point (focal-plane heights, see app/planning/path.py):

1. obstacle height ``H`` = highest point inside the axis-aligned xy box spanned by start and target
   (axes that do not move in a coordinated way may leave the straight line, but never that box);
2. safe height ``S = H + clearance - working distance``;
3. one of four patterns, comparing the start height ``z0`` and target height ``z1`` with ``S``
   (a height equal to ``S`` counts as safe):

   ==========================  =================  ===================================================
   z0 >= S, z1 >= S            ``straight``       straight to the target
   z0 >= S, z1 <  S            ``over_then_down`` horizontal to above the target, then down
   z0 <  S, z1 >= S            ``up_then_over``   up to the target height, then horizontal
   z0 <  S, z1 <  S            ``up_over_down``   up to S, horizontal, down
   ==========================  =================  ===================================================

   Shortening variants (options): ``diagonal_then_down`` replaces ``over_then_down`` by a diagonal to
   the point above the target at S, then down; ``up_then_diagonal`` replaces ``up_then_over`` by
   up to S, then a diagonal to the target. Both diagonals run at or above S, so they stay safe.
   ``orthogonal=True`` makes every segment move either z alone or xy alone: a straight move that
   changes both becomes "z up first, then xy" when rising and "xy first, then z down" when sinking.

Example (the reference's own): working distance 30, clearance 5, obstacles at +6 -> S = -19.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from app.planning.obstacles import ObstacleSource
from app.planning.path import PlannedMove, PlannedPath, Point, ProbeParams, as_points, pt

PATTERNS = ("straight", "over_then_down", "up_then_over", "up_over_down")
VARIANTS = ("diagonal_then_down", "up_then_diagonal")


@dataclass(frozen=True)
class ReferenceOptions:
    """Switches of the reference method.

    diagonal_down : use ``diagonal_then_down`` instead of ``over_then_down``.
    up_diagonal   : use ``up_then_diagonal`` instead of ``up_then_over``.
    orthogonal    : every segment moves z alone or xy alone (excludes the two diagonal variants).
    box_margin_mm : grow the obstacle box by this much on every side; 0 is the reference exactly.
                    Set it to the sensor radius (+ lateral margin) when the sensor has a size.
    """

    diagonal_down: bool = False
    up_diagonal: bool = False
    orthogonal: bool = False
    box_margin_mm: float = 0.0

    def __post_init__(self) -> None:
        if self.orthogonal and (self.diagonal_down or self.up_diagonal):
            raise ValueError(
                "orthogonal moves exclude the diagonal shortening variants; switch off either "
                "orthogonal or diagonal_down/up_diagonal"
            )
        if not np.isfinite(self.box_margin_mm) or self.box_margin_mm < 0:
            raise ValueError(f"box_margin_mm must be >= 0, got {self.box_margin_mm}")


def choose_pattern(z0_mm: float, z1_mm: float, safe_height_mm: float) -> str:
    """One of :data:`PATTERNS` from the start and target heights and the safe height (mm)."""
    start_safe = z0_mm >= safe_height_mm
    target_safe = z1_mm >= safe_height_mm
    if start_safe and target_safe:
        return "straight"
    if start_safe:
        return "over_then_down"
    if target_safe:
        return "up_then_over"
    return "up_over_down"


def _dedupe(points: list[Point]) -> tuple[Point, ...]:
    out: list[Point] = []
    for p in points:
        if not out or out[-1] != p:
            out.append(p)
    return tuple(out)


def move_waypoints(
    start: ArrayLike, target: ArrayLike, safe_height_mm: float, options: ReferenceOptions = ReferenceOptions()
) -> tuple[str, tuple[Point, ...]]:
    """Pattern name and waypoints (start .. target inclusive) of one move for a given safe height."""
    a = np.asarray(start, dtype=float)
    b = np.asarray(target, dtype=float)
    x0, y0, z0 = a
    x1, y1, z1 = b
    S = float(safe_height_mm)
    pattern = choose_pattern(z0, z1, S)
    if pattern == "straight":
        if options.orthogonal and z1 > z0:
            wps = [a, (x0, y0, z1), b]
        elif options.orthogonal:
            wps = [a, (x1, y1, z0), b]
        else:
            wps = [a, b]
    elif pattern == "over_then_down":
        if options.diagonal_down:
            pattern = "diagonal_then_down"
            wps = [a, (x1, y1, S), b]
        else:
            wps = [a, (x1, y1, z0), b]
    elif pattern == "up_then_over":
        if options.up_diagonal:
            pattern = "up_then_diagonal"
            wps = [a, (x0, y0, S), b]
        else:
            wps = [a, (x0, y0, z1), b]
    else:
        wps = [a, (x0, y0, S), (x1, y1, S), b]
    return pattern, _dedupe([pt(p) for p in wps])


def plan_path_reference(
    points: ArrayLike,
    obstacles: ObstacleSource,
    probe: ProbeParams,
    options: ReferenceOptions = ReferenceOptions(),
) -> PlannedPath:
    """Plan the moves through ``points`` (N, 3) in order with the reference method.

    points    : focal-plane positions in mm, planning frame (z up).
    obstacles : any obstacle source of app/planning/obstacles.py; move i is asked for the highest
                point in the xy box of points i and i+1 (grown by ``options.box_margin_mm``).
    Returns a :class:`PlannedPath` with ``coordinated=False`` (rapids may dog-leg inside the box).
    """
    P = as_points(points)
    moves = []
    for i in range(len(P) - 1):
        a, b = P[i], P[i + 1]
        H = obstacles.box_max_mm(i, a[:2], b[:2], options.box_margin_mm)
        S = probe.safe_height_mm(H)
        pattern, wps = move_waypoints(a, b, S, options)
        moves.append(PlannedMove(i, pt(a), pt(b), pattern, wps, float(H), float(S)))
    return PlannedPath("reference", tuple(moves), coordinated=False)
