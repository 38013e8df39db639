"""The reference detour (app/planning/reference.py) as a subroutine the controller evaluates itself
(issue 16, part 3): the decision logic as a tiny program (an intermediate representation, IR) that the
per-dialect emitters of app/planning/detour_emit.py turn into LinuxCNC O-word, HEIDENHAIN LBL, Fanuc
macro B and Sinumerik PROC text, and that :func:`evaluate` runs in Python.

What the subroutine does for a call with a target ``(TX, TY, TZ)`` (program frame, mm, focal-plane /
tip heights, z up):

1. the start ``(SX, SY, SZ)`` is the controller's current programmed position (read, not passed: a
   start that disagreed with where the machine is would make the first segment unplanned);
2. the move box ``[min(SX, TX) - M, max(SX, TX) + M] x [min(SY, TY) - M, max(SY, TY) + M]`` with the
   box margin ``M`` (sensor radius + lateral margin);
3. the obstacle height ``H``: the base height, raised to the top of every obstacle box whose closed xy
   rectangle meets the move box (the obstacle boxes are *baked in* as constants: see docs/design.md,
   "The detour as a controller subroutine", for why not parameters);
4. ``S = (H + clearance) - working distance`` (the reference's formula, in the same order of operations
   as :meth:`ProbeParams.safe_height_mm`, so float rounding agrees too);
5. the pattern from ``SZ >= S`` and ``TZ >= S`` and the options (diagonal variants, orthogonal), with the
   same waypoints as :func:`app.planning.reference.move_waypoints`, as rapid moves.

:class:`BoxObstacles` is the obstacle source the Python planner uses for the same scene, so
``plan_path_reference(points, boxes, probe, options)`` is what the controller must reproduce.
Frames: every number is in the program frame the subroutine runs in (table frame shifted/turned about z).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from app.planning.path import Point, ProbeParams
from app.planning.reference import ReferenceOptions

# ------------------------------------------------------------------------------------------ obstacles


@dataclass(frozen=True)
class ObstacleBox:
    """An axis-aligned obstacle: xy rectangle ``[x0, x1] x [y0, y1]`` and its top ``top_mm`` (mm, the
    frame the subroutine runs in)."""

    x0: float
    y0: float
    x1: float
    y1: float
    top_mm: float
    name: str = ""

    def __post_init__(self) -> None:
        vals = (self.x0, self.y0, self.x1, self.y1, self.top_mm)
        if not all(np.isfinite(v) for v in vals):
            raise ValueError(f"obstacle box {self.name or vals}: every number must be finite")
        if self.x1 < self.x0 or self.y1 < self.y0:
            raise ValueError(f"obstacle box {self.name or vals}: x1 >= x0 and y1 >= y0 required")


@dataclass(frozen=True)
class BoxObstacles:
    """Obstacle source of axis-aligned boxes (app/planning/obstacles.py protocol, ``box_max_mm`` only):
    the highest top among boxes whose closed rectangle meets the move box, never below ``base_height_mm``.
    This is exactly what the emitted subroutine computes."""

    boxes: tuple[ObstacleBox, ...]
    base_height_mm: float = 0.0

    def box_max_mm(self, move_index: int, a_xy: ArrayLike, b_xy: ArrayLike, margin_mm: float = 0.0) -> float:
        ax, ay = (float(v) for v in np.asarray(a_xy, dtype=float)[:2])
        bx, by = (float(v) for v in np.asarray(b_xy, dtype=float)[:2])
        m = float(margin_mm)
        lx, hx = (ax - m, bx + m) if ax <= bx else (bx - m, ax + m)
        ly, hy = (ay - m, by + m) if ay <= by else (by - m, ay + m)
        h = float(self.base_height_mm)
        for b in self.boxes:
            if hx >= b.x0 and lx <= b.x1 and hy >= b.y0 and ly <= b.y1 and b.top_mm > h:
                h = float(b.top_mm)
        return h

    def profile_mm(self, move_index, a_xy, b_xy, radius_mm, n_steps) -> np.ndarray:
        """Conservative profile: the box maximum over the segment's box grown by the radius."""
        return np.full(n_steps, self.box_max_mm(move_index, a_xy, b_xy, radius_mm))

    def quantised(self, decimals: int) -> BoxObstacles:
        """The same boxes with every number rounded outward to ``decimals`` (what a dialect can write):
        rectangles grow, tops rise, so the rounded scene is never smaller."""
        q = 10.0**decimals

        def down(v):
            return float(np.floor(v * q + 1e-6) / q)

        def up(v):
            return float(np.ceil(v * q - 1e-6) / q)

        return BoxObstacles(tuple(ObstacleBox(down(b.x0), down(b.y0), up(b.x1), up(b.y1), up(b.top_mm), b.name)
                                  for b in self.boxes), round(float(self.base_height_mm), decimals))


def boxes_from_footprints(obstacles: Sequence, base_height_mm: float = 0.0) -> BoxObstacles:
    """Bounding rectangles of obstacles with ``footprint_xy_mm`` and ``top_mm`` (e.g.
    app.planning.probing_safety.KnownObstacle) in their own frame; ones without a footprint are skipped
    (an object the operator says is inside drawn zones)."""
    out = []
    for o in obstacles:
        xy = np.asarray(o.footprint_xy_mm, dtype=float).reshape(-1, 2)
        if len(xy) < 3:
            continue
        out.append(ObstacleBox(float(xy[:, 0].min()), float(xy[:, 1].min()), float(xy[:, 0].max()),
                               float(xy[:, 1].max()), float(o.top_mm), str(getattr(o, "name", ""))))
    return BoxObstacles(tuple(out), float(base_height_mm))


# ------------------------------------------------------------------------------------------------ IR


@dataclass(frozen=True)
class Num:
    value: float


@dataclass(frozen=True)
class Var:
    """A variable: ``TX TY TZ`` are the parameters (target), ``SX SY SZ LX HX LY HY H S`` locals."""

    name: str


@dataclass(frozen=True)
class Pos:
    """The controller's current programmed position on ``axis`` (x, y or z; program frame)."""

    axis: str

    def __post_init__(self) -> None:
        if self.axis not in ("x", "y", "z"):
            raise ValueError(f"position axis must be x, y or z, got {self.axis!r}")


@dataclass(frozen=True)
class Bin:
    """``a + b`` or ``a - b`` (op "+" / "-"); operands are Num or Var."""

    op: str
    a: Num | Var
    b: Num | Var


Expr = Num | Var | Pos | Bin


@dataclass(frozen=True)
class Cmp:
    """``a op b`` with op one of ``>= <= > <``."""

    op: str
    a: Num | Var
    b: Num | Var


@dataclass(frozen=True)
class Assign:
    var: Var
    expr: Expr


@dataclass(frozen=True)
class If:
    cond: Cmp
    then: tuple
    orelse: tuple = ()


@dataclass(frozen=True)
class Move:
    """A rapid to the given coordinates (Var or None for an axis that stays)."""

    x: Var | None
    y: Var | None
    z: Var | None


@dataclass(frozen=True)
class Comment:
    text: str


PARAMS = ("TX", "TY", "TZ")
LOCALS = ("SX", "SY", "SZ", "LX", "HX", "LY", "HY", "H", "S")


@dataclass(frozen=True)
class DetourSubroutine:
    """The subroutine: its body (IR statements) and what was baked in (for the header comments)."""

    body: tuple
    boxes: BoxObstacles
    probe: ProbeParams
    options: ReferenceOptions
    margin_mm: float


def _v(n: str) -> Var:
    return Var(n)


def _pattern_block(opt: ReferenceOptions) -> tuple:
    """The four patterns (and variants) as IR, the same waypoints as reference.move_waypoints."""
    TX, TY, TZ, SZ, S = _v("TX"), _v("TY"), _v("TZ"), _v("SZ"), _v("S")
    if opt.orthogonal:
        straight = (If(Cmp(">", TZ, SZ), (Comment("straight, rising: z first"), Move(None, None, TZ), Move(TX, TY, None)),
                       (Comment("straight, level or sinking: xy first"), Move(TX, TY, None), Move(None, None, TZ))),)
    else:
        straight = (Comment("straight"), Move(TX, TY, TZ))
    if opt.diagonal_down:
        over = (Comment("diagonal_then_down"), Move(TX, TY, S), Move(None, None, TZ))
    else:
        over = (Comment("over_then_down"), Move(TX, TY, None), Move(None, None, TZ))
    if opt.up_diagonal:
        up = (Comment("up_then_diagonal"), Move(None, None, S), Move(TX, TY, TZ))
    else:
        up = (Comment("up_then_over"), Move(None, None, TZ), Move(TX, TY, None))
    up_over = (Comment("up_over_down"), Move(None, None, S), Move(TX, TY, None), Move(None, None, TZ))
    return (If(Cmp(">=", SZ, S), (If(Cmp(">=", TZ, S), straight, over),), (If(Cmp(">=", TZ, S), up, up_over),)),)


def build_detour(boxes: BoxObstacles, probe: ProbeParams, options: ReferenceOptions | None = None,
                 margin_mm: float | None = None) -> DetourSubroutine:
    """The subroutine for one scene: ``boxes`` baked in, ``probe`` (clearance, working distance) and
    ``options`` (patterns; ``margin_mm`` defaults to ``options.box_margin_mm``)."""
    options = options or ReferenceOptions()
    m = float(options.box_margin_mm if margin_mm is None else margin_mm)
    if not np.isfinite(m) or m < 0:
        raise ValueError(f"box margin must be a finite number >= 0, got {m}")
    SX, SY, SZ, TX, TY = _v("SX"), _v("SY"), _v("SZ"), _v("TX"), _v("TY")
    LX, HX, LY, HY, H, S = _v("LX"), _v("HX"), _v("LY"), _v("HY"), _v("H"), _v("S")
    M = Num(m)
    body: list = [Comment("start: the current programmed position"),
                  Assign(SX, Pos("x")), Assign(SY, Pos("y")), Assign(SZ, Pos("z")),
                  Comment(f"move box grown by the margin {m:g} mm"),
                  If(Cmp("<=", SX, TX), (Assign(LX, Bin("-", SX, M)), Assign(HX, Bin("+", TX, M))),
                     (Assign(LX, Bin("-", TX, M)), Assign(HX, Bin("+", SX, M)))),
                  If(Cmp("<=", SY, TY), (Assign(LY, Bin("-", SY, M)), Assign(HY, Bin("+", TY, M))),
                     (Assign(LY, Bin("-", TY, M)), Assign(HY, Bin("+", SY, M)))),
                  Comment("obstacle height: base, raised by every obstacle box the move box meets"),
                  Assign(H, Num(boxes.base_height_mm))]
    for k, b in enumerate(boxes.boxes):
        if b.top_mm <= boxes.base_height_mm:
            continue  # cannot raise H
        top = Num(b.top_mm)
        inner: tuple = (If(Cmp(">", top, H), (Assign(H, top),)),)
        for cond in (Cmp("<=", LY, Num(b.y1)), Cmp(">=", HY, Num(b.y0)), Cmp("<=", LX, Num(b.x1)),
                     Cmp(">=", HX, Num(b.x0))):
            inner = (If(cond, inner),)
        body += [Comment(f"box {k + 1} {b.name}"[:60].strip()), *inner]
    body += [Comment(f"safe height S = H + clearance {probe.clearance_mm:g} - working distance "
                     f"{probe.working_distance_mm:g}"),
             Assign(S, Bin("+", H, Num(probe.clearance_mm))), Assign(S, Bin("-", S, Num(probe.working_distance_mm))),
             *_pattern_block(options)]
    return DetourSubroutine(tuple(body), boxes, probe, options, m)


# ------------------------------------------------------------------------------------------ evaluate


def _val(e, env: dict, pos: list) -> float:
    if isinstance(e, Num):
        return float(e.value)
    if isinstance(e, Var):
        if e.name not in env:
            raise ValueError(f"variable {e.name} read before it is set")
        return env[e.name]
    if isinstance(e, Pos):
        return pos["xyz".index(e.axis)]
    if isinstance(e, Bin):
        a, b = _val(e.a, env, pos), _val(e.b, env, pos)
        return a + b if e.op == "+" else a - b
    raise TypeError(f"not an expression: {e!r}")


def _test(c: Cmp, env: dict, pos: list) -> bool:
    a, b = _val(c.a, env, pos), _val(c.b, env, pos)
    return {">=": a >= b, "<=": a <= b, ">": a > b, "<": a < b}[c.op]


def evaluate(sub: DetourSubroutine | Sequence, start: ArrayLike, target: ArrayLike) -> list[Point]:
    """Run the IR in Python from ``start`` with parameters ``target``: the visited points, start first,
    consecutive duplicates dropped (what the controller's rapids reach)."""
    body = sub.body if isinstance(sub, DetourSubroutine) else tuple(sub)
    pos = [float(v) for v in np.asarray(start, dtype=float).reshape(3)]
    env = dict(zip(PARAMS, (float(v) for v in np.asarray(target, dtype=float).reshape(3))))
    out: list[Point] = [tuple(pos)]

    def run(stmts):
        for s in stmts:
            if isinstance(s, Assign):
                env[s.var.name] = _val(s.expr, env, pos)
            elif isinstance(s, If):
                run(s.then if _test(s.cond, env, pos) else s.orelse)
            elif isinstance(s, Move):
                for k, c in enumerate((s.x, s.y, s.z)):
                    if c is not None:
                        pos[k] = _val(c, env, pos)
                if tuple(pos) != out[-1]:
                    out.append(tuple(pos))
            elif not isinstance(s, Comment):
                raise TypeError(f"not a statement: {s!r}")

    run(body)
    return out


__all__ = [
    "LOCALS",
    "PARAMS",
    "Assign",
    "Bin",
    "BoxObstacles",
    "Cmp",
    "Comment",
    "DetourSubroutine",
    "If",
    "Move",
    "Num",
    "ObstacleBox",
    "Pos",
    "Var",
    "boxes_from_footprints",
    "build_detour",
    "evaluate",
]
