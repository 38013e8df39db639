"""Independent check of a probing program against the true scene (issue 18, item 5).

Independent of the planners: it reads the G-code text back (its own parser), samples every move
and measures exact distances from the probe's ball, stylus and body to true obstacles given as
primitives (boxes turned about z, vertical cylinders), never looking at a height map or a located
pose. Frames: obstacles in the table frame (z up, mm); the program in its own frame,
``T_table_prog`` maps it to the table.

The probe at tip position ``p`` (the ball's lowest point): ball = sphere of ``ball_radius_mm``
centred at ``p + r e_z``; stylus = vertical cylinder of ``stylus_radius_mm`` from the ball centre
up to ``p + stylus_length_mm e_z``; body = vertical cylinder of ``body_radius_mm`` from there up
``body_length_mm``. Distances between a vertical cylinder and a box turned about z (or another
vertical cylinder) are exact: both are products of an xy shape and a z interval, so the distance is
``hypot(xy distance, z gap)``.

Rules:
* travel moves (G0/G1 not ending or starting at a touch): every part of the probe keeps
  ``clearance_mm`` from every obstacle;
* a G38.2 move trips where the ball first meets anything (found by sampling, then bisection); it
  must meet the workpiece (a *hit*), and before it trips the ball and stylus must keep the clearance
  from every obstacle of role ``fixture`` or ``other`` and must not touch a ``support`` (what the
  part stands on) nor (the stylus) the workpiece; the body keeps the clearance from everything.
  The next move starts where it tripped;
* a dry run's G1 onto the nominal contact is checked like a touch up to its end.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

ROLES = ("workpiece", "support", "fixture", "other")


@dataclass(frozen=True)
class Box:
    """A box turned by ``yaw_deg`` about z: centre (x, y), half extents (hx, hy), z from z0 to z1."""

    centre_xy: tuple[float, float]
    half_xy: tuple[float, float]
    z0: float
    z1: float
    yaw_deg: float = 0.0

    def xy_distance(self, P: np.ndarray) -> np.ndarray:
        c, s = np.cos(np.radians(self.yaw_deg)), np.sin(np.radians(self.yaw_deg))
        d = P - np.asarray(self.centre_xy)
        local = np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)
        q = np.maximum(np.abs(local) - np.asarray(self.half_xy), 0.0)
        return np.hypot(q[:, 0], q[:, 1])


@dataclass(frozen=True)
class VCylinder:
    """A vertical cylinder: axis at (x, y), radius, z from z0 to z1."""

    centre_xy: tuple[float, float]
    radius: float
    z0: float
    z1: float

    def xy_distance(self, P: np.ndarray) -> np.ndarray:
        return np.maximum(np.linalg.norm(P - np.asarray(self.centre_xy), axis=1) - self.radius, 0.0)


@dataclass(frozen=True)
class TrueObstacle:
    name: str
    role: str
    parts: tuple  # Box | VCylinder

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ValueError(f"role must be one of {ROLES}, got {self.role!r}")


@dataclass(frozen=True)
class ProbeShape:
    ball_radius_mm: float = 1.5
    stylus_radius_mm: float = 1.0
    stylus_length_mm: float = 30.0
    body_radius_mm: float = 15.0
    body_length_mm: float = 80.0


def _gap(z0: np.ndarray, z1: np.ndarray, b0: float, b1: float) -> np.ndarray:
    return np.maximum(np.maximum(b0 - z1, z0 - b1), 0.0)


def part_distances(tips: np.ndarray, ob: TrueObstacle, probe: ProbeShape) -> dict[str, np.ndarray]:
    """Distance (N,) from the ball, the stylus and the body at each tip position to an obstacle (mm;
    0 when they touch or overlap)."""
    P = np.asarray(tips, dtype=float).reshape(-1, 3)
    r = probe.ball_radius_mm
    cz = P[:, 2] + r
    out = {"ball": np.full(len(P), np.inf), "stylus": np.full(len(P), np.inf), "body": np.full(len(P), np.inf)}
    for g in ob.parts:
        dxy = g.xy_distance(P[:, :2])
        # ball: distance of its centre to the solid, minus r (exact for both primitive kinds)
        dz = np.maximum(np.maximum(g.z0 - cz, cz - g.z1), 0.0)
        out["ball"] = np.minimum(out["ball"], np.maximum(np.hypot(dxy, dz) - r, 0.0))
        s0, s1 = cz, P[:, 2] + probe.stylus_length_mm
        ds = np.hypot(np.maximum(dxy - probe.stylus_radius_mm, 0.0), _gap(s0, s1, g.z0, g.z1))
        out["stylus"] = np.minimum(out["stylus"], ds)
        b0, b1 = s1, s1 + probe.body_length_mm
        db = np.hypot(np.maximum(dxy - probe.body_radius_mm, 0.0), _gap(b0, b1, g.z0, g.z1))
        out["body"] = np.minimum(out["body"], db)
    return out


_WORD = re.compile(r"([A-Z])([-+]?\d*\.?\d+)")


@dataclass(frozen=True)
class Move:
    line_no: int
    word: str  # "G0", "G1", "G38.2"
    start: np.ndarray  # program frame; NaN where not known
    end: np.ndarray


def parse_moves(gcode: str) -> list[Move]:
    """Straight moves of a program (G0, G1, G38.2; absolute, mm), modal coordinates carried over.
    Raises ValueError on anything that would move the machine in a way this check cannot follow
    (G53, G91, arcs, G10, G92, spindle or coolant on)."""
    pos = np.full(3, np.nan)
    motion = None
    out = []
    for k, raw in enumerate(gcode.splitlines(), 1):
        line = re.sub(r"\([^)]*\)", "", raw).split(";")[0].strip().upper()
        if not line or line == "%":
            continue
        words = line.split()
        gs = [w for w in words if w.startswith("G")]
        for w in words:
            if w in ("G53", "G91", "G2", "G3", "G02", "G03", "G10", "G92", "M3", "M4", "M7", "M8", "G28", "G30"):
                raise ValueError(f"line {k}: {w} is not allowed in a probing program ({raw!r})")
        for g in gs:
            if g in ("G0", "G00", "G1", "G01", "G38.2"):
                motion = {"G00": "G0", "G01": "G1"}.get(g, g)
        axes = {m.group(1): float(m.group(2)) for w in words for m in [_WORD.fullmatch(w)] if m and m.group(1) in "XYZ"}
        if not axes:
            continue
        if motion is None:
            raise ValueError(f"line {k}: coordinates without a motion word ({raw!r})")
        end = pos.copy()
        for i, a in enumerate("XYZ"):
            if a in axes:
                end[i] = axes[a]
        out.append(Move(k, motion, pos.copy(), end))
        pos = end
    return out


@dataclass
class TouchResult:
    line_no: int
    hit: bool
    obstacle: str
    tip: np.ndarray
    error_mm: float = np.nan  # distance of the trip point from the nominal contact tip, when given


@dataclass
class ProgramCheck:
    violations: list[tuple[int, str, str, float]] = field(default_factory=list)  # (line, part, obstacle, distance)
    touches: list[TouchResult] = field(default_factory=list)
    min_travel_clearance_mm: float = np.inf
    path_length_mm: float = 0.0
    n_samples: int = 0

    @property
    def ok(self) -> bool:
        return not self.violations and all(t.hit for t in self.touches)


def _samples(a: np.ndarray, b: np.ndarray, step_mm: float) -> np.ndarray:
    n = max(int(np.ceil(np.linalg.norm(b - a) / step_mm)), 1)
    t = np.linspace(0.0, 1.0, n + 1)[:, None]
    return a + t * (b - a)


def check_program(
    gcode: str,
    obstacles: Sequence[TrueObstacle],
    *,
    T_table_prog: ArrayLike | None = None,
    probe: ProbeShape = ProbeShape(),
    clearance_mm: float = 5.0,
    step_mm: float = 0.25,
    nominal_contacts: Sequence[ArrayLike] = (),
    tol_mm: float = 0.05,
) -> ProgramCheck:
    """Check every move of ``gcode`` against the true ``obstacles`` (see the module doc).
    ``tol_mm``: slack for sampling (a sampled distance may miss the true minimum by up to half a
    step times the slope, so ``clearance - tol`` is the limit). ``nominal_contacts``: the expected
    contact tip (table frame) per touch, in order, to report each touch's error."""
    T = np.eye(4) if T_table_prog is None else np.asarray(T_table_prog, dtype=float)
    R, t = T[:3, :3], T[:3, 3]
    moves = parse_moves(gcode)
    out = ProgramCheck()
    tripped_at = None
    k_touch = 0
    nominal = [np.asarray(c, dtype=float) for c in nominal_contacts]
    for m in moves:
        leaving = tripped_at is not None  # the retract from a touch starts on the part
        a = R @ m.start + t if tripped_at is None else tripped_at
        b = R @ m.end + t
        tripped_at = None
        if np.isnan(a).any() or np.isnan(b).any():
            continue  # from an unknown position (the first retract): nothing to check
        leaving = leaving or any(np.linalg.norm(a - c) < 1e-3 for c in nominal)
        approaching = m.word == "G38.2" or (m.word == "G1" and any(np.linalg.norm(b - c) < 1e-3 for c in nominal))
        P = _samples(a, b, step_mm)
        if approaching:
            P, res = _trip(P, obstacles, probe, m, tol_mm)
            if k_touch < len(nominal):
                res.error_mm = float(np.linalg.norm(res.tip - nominal[k_touch]))
            out.touches.append(res)
            if m.word == "G38.2":
                tripped_at = res.tip
            elif np.linalg.norm(res.tip - b) > tol_mm:  # a dry run does not stop where it meets something
                out.violations.append((m.line_no, "ball", res.obstacle, -float(np.linalg.norm(res.tip - b))))
            k_touch += 1
        touching = approaching or leaving
        out.n_samples += len(P)
        out.path_length_mm += float(np.linalg.norm(P[-1] - P[0]))
        for ob in obstacles:
            d = part_distances(P, ob, probe)
            for part, dist in d.items():
                lo = float(dist.min())
                if touching and part in ("ball", "stylus"):
                    if ob.role == "workpiece" and part == "ball":
                        continue  # the contact itself
                    if ob.role in ("workpiece", "support"):
                        if lo <= 0.0:
                            out.violations.append((m.line_no, part, ob.name, lo))
                    elif lo < clearance_mm - tol_mm:
                        out.violations.append((m.line_no, part, ob.name, lo))
                    continue
                if not touching:
                    out.min_travel_clearance_mm = min(out.min_travel_clearance_mm, lo)
                if lo < clearance_mm - tol_mm:
                    out.violations.append((m.line_no, part, ob.name, lo))
    return out


def _trip(P: np.ndarray, obstacles, probe, m: Move, tol_mm: float):
    """Samples up to where the ball first meets an obstacle, and the touch result (a dry run's G1
    that meets nothing stops at its end as planned)."""

    def touched(p):
        best = None
        for ob in obstacles:
            d = float(part_distances(p[None], ob, probe)["ball"][0])
            if d <= 0.0 and best is None:
                best = ob
        return best

    ball = np.min([part_distances(P, ob, probe)["ball"] for ob in obstacles], axis=0)
    hit = np.flatnonzero(ball <= 0.0)
    if len(hit):
        k = int(hit[0])
        if k == 0:  # already touching at the start
            first = touched(P[0])
            return P[:1], TouchResult(m.line_no, first.role == "workpiece", first.name, P[0])
        lo, hi = P[k - 1], P[k]
        for _ in range(30):
            mid = (lo + hi) / 2
            if touched(mid) is None:
                lo = mid
            else:
                hi = mid
        first = touched(hi)
        return np.vstack([P[:k], lo]), TouchResult(m.line_no, first.role == "workpiece", first.name, hi)
    if m.word == "G38.2":
        return P, TouchResult(m.line_no, False, "nothing (G38.2 ended without contact)", P[-1])
    return P, TouchResult(m.line_no, True, "dry run: stopped at the nominal contact", P[-1])


__all__ = ["Box", "VCylinder", "TrueObstacle", "ProbeShape", "ROLES", "Move", "parse_moves", "part_distances",
           "TouchResult", "ProgramCheck", "check_program"]
