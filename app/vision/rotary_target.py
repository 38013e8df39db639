"""Circular targets for rotary-axis angle checks: description and validation (printing them:
:mod:`app.vision.printables.rotary_target`).

A target is black on white, printed flat and fixed to the rotary table. It carries several
*groups* of concentric circles at known positions plus an optional orientation mark. JSON form::

    {"groups": [{"center_mm": [x, y], "circle_radii_mm": [r, ...]}, ...],
     "mark_mm": [x, y],                      # optional orientation mark (a black dot)
     "mark_radius_mm": 2.5,                  # optional, default 2.5
     "disc_radius_mm": 75.0}                 # optional outline of the printed disc / plate

Target frame ``tgt``: x right, y up on the printed sheet, z out of the printed face, origin where
the layout puts it (the default target: the disc centre). ``circle_radii_mm`` lists EVERY printed
circle edge of a group. Paint rule, from the outside in: the outermost radius bounds a black
region, the next one a white region, and so on, so radii (12, 8, 4) print a black ring
12..8 mm, a white ring 8..4 mm and a black disc of 4 mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


class TargetError(ValueError):
    """A target description that cannot be used; the message says what and how to fix it."""


@dataclass(frozen=True)
class CircleGroup:
    """Concentric circles of one group.

    center_mm : (x, y) of the common centre in the target frame, mm.
    circle_radii_mm : every printed edge radius, mm, sorted from the largest to the smallest.
    """

    center_mm: tuple[float, float]
    circle_radii_mm: tuple[float, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"center_mm": list(self.center_mm), "circle_radii_mm": list(self.circle_radii_mm)}


@dataclass(frozen=True)
class RotaryTarget:
    """A validated target layout (see the module docstring for frame and paint rule)."""

    groups: tuple[CircleGroup, ...]
    mark_mm: tuple[float, float] | None = None
    mark_radius_mm: float = 2.5
    disc_radius_mm: float | None = None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"groups": [g.to_dict() for g in self.groups]}
        if self.mark_mm is not None:
            out["mark_mm"] = list(self.mark_mm)
            out["mark_radius_mm"] = self.mark_radius_mm
        if self.disc_radius_mm is not None:
            out["disc_radius_mm"] = self.disc_radius_mm
        return out

    @property
    def centers_mm(self) -> np.ndarray:
        """Group centres, shape (G, 2), mm in the target frame."""
        return np.array([g.center_mm for g in self.groups], dtype=float)

    def extent_mm(self) -> float:
        """Radius (mm, about the target origin) of a circle that holds everything printed."""
        r = max(math.hypot(*g.center_mm) + g.circle_radii_mm[0] for g in self.groups)
        if self.mark_mm is not None:
            r = max(r, math.hypot(*self.mark_mm) + self.mark_radius_mm)
        if self.disc_radius_mm is not None:
            r = max(r, self.disc_radius_mm)
        return r


def _xy(value: Any, what: str) -> tuple[float, float]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise TargetError(f"{what} must be two numbers [x, y] in mm, got {value!r}") from None
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise TargetError(f"{what} must be two finite numbers [x, y] in mm, got {value!r}")
    return float(arr[0]), float(arr[1])


def target_from_dict(data: Any, min_gap_mm: float = 0.5) -> RotaryTarget:
    """Validate a target description (the JSON form in the module docstring).

    Raises
    ------
    TargetError
        With a sentence naming the faulty group or field, the value seen and what is allowed.
    """
    if not isinstance(data, dict):
        raise TargetError(f"target must be a JSON object with 'groups', got {type(data).__name__}")
    unknown = set(data) - {"groups", "mark_mm", "mark_radius_mm", "disc_radius_mm"}
    if unknown:
        raise TargetError(f"target has unknown keys {sorted(unknown)}; allowed: groups, mark_mm, "
                          "mark_radius_mm, disc_radius_mm")
    raw_groups = data.get("groups")
    if not isinstance(raw_groups, list) or len(raw_groups) < 4:
        n = len(raw_groups) if isinstance(raw_groups, list) else 0
        raise TargetError(f"target needs at least 4 circle groups to measure a "
                          f"rotation and the plane's pose, got {n}")
    groups = []
    for i, g in enumerate(raw_groups):
        if not isinstance(g, dict) or "center_mm" not in g or "circle_radii_mm" not in g:
            raise TargetError(f"group {i} must have 'center_mm' and 'circle_radii_mm'")
        c = _xy(g["center_mm"], f"group {i} center_mm")
        try:
            radii = np.asarray(g["circle_radii_mm"], dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise TargetError(f"group {i} circle_radii_mm must be a list of numbers in mm") from None
        if radii.size < 1 or not np.all(np.isfinite(radii)) or np.any(radii <= 0):
            raise TargetError(f"group {i} circle_radii_mm must be positive numbers in mm, "
                              f"got {g['circle_radii_mm']!r}")
        radii = np.sort(radii)[::-1]
        gaps = -np.diff(radii)
        if gaps.size and gaps.min() < min_gap_mm:
            raise TargetError(f"group {i}: circle radii {radii.tolist()} are {gaps.min():.3f} mm apart; "
                              f"edges closer than {min_gap_mm} mm cannot be told apart, spread them")
        groups.append(CircleGroup(c, tuple(float(r) for r in radii)))
    for i in range(len(groups)):
        for j in range(i + 1, len(groups)):
            d = math.dist(groups[i].center_mm, groups[j].center_mm)
            need = groups[i].circle_radii_mm[0] + groups[j].circle_radii_mm[0] + min_gap_mm
            if d < need:
                raise TargetError(f"groups {i} and {j} overlap: centres {d:.2f} mm apart, need at "
                                  f"least {need:.2f} mm (sum of outer radii + {min_gap_mm} mm)")
    centers = np.array([g.center_mm for g in groups])
    cc = centers - centers.mean(axis=0)
    if np.linalg.svd(cc, compute_uv=False)[-1] < 1e-6 * max(1.0, np.abs(cc).max()):
        raise TargetError("group centres are collinear; the plane's pose cannot be measured, "
                          "place the groups around a circle")
    mark = None
    mark_r = float(data.get("mark_radius_mm", 2.5))
    if not math.isfinite(mark_r) or mark_r <= 0:
        raise TargetError(f"mark_radius_mm must be a positive number of mm, got {mark_r}")
    if data.get("mark_mm") is not None:
        mark = _xy(data["mark_mm"], "mark_mm")
        for i, g in enumerate(groups):
            if math.dist(mark, g.center_mm) < g.circle_radii_mm[0] + mark_r + min_gap_mm:
                raise TargetError(f"mark_mm {list(mark)} touches group {i}; move it at least "
                                  f"{g.circle_radii_mm[0] + mark_r + min_gap_mm:.2f} mm from that centre")
    disc = data.get("disc_radius_mm")
    if disc is not None:
        disc = float(disc)
        t = RotaryTarget(tuple(groups), mark, mark_r, None)
        if not math.isfinite(disc) or disc < t.extent_mm():
            raise TargetError(f"disc_radius_mm {disc} is smaller than the printed layout "
                              f"({t.extent_mm():.2f} mm); enlarge the disc")
    return RotaryTarget(tuple(groups), mark, mark_r, disc)


def default_target() -> RotaryTarget:
    """A 150 mm disc: 4 groups of 5 concentric edges (18 .. 4 mm) on a 52 mm radius + a mark.

    More edges per group mean more edge pixels and a better angle (the measurement is limited by
    image noise); 4 groups keep the reference method's "6 lines of 4 centres".
    """
    groups = []
    for k in range(4):
        a = math.radians(45.0 + 90.0 * k)
        groups.append({"center_mm": [round(52.0 * math.cos(a), 6), round(52.0 * math.sin(a), 6)],
                       "circle_radii_mm": [18.0, 14.5, 11.0, 7.5, 4.0]})
    return target_from_dict({"groups": groups, "mark_mm": [0.0, 25.0], "mark_radius_mm": 2.5,
                             "disc_radius_mm": 75.0})
