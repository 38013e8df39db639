"""What a probing program may assume and where it may go (issue 18): obstacles with their source,
objects asked for but not located, retract height, machine travel, safe comment text.

Pure: numbers and shapes in, numbers out. Frames: the table frame (z up, mm) unless a name says
otherwise; ``T_machine_table`` maps it into machine coordinates.

An obstacle the program plans around is a :class:`KnownObstacle`: a footprint (polygon in table
xy) and a top height, with its *source*:

* ``located`` - a located mesh (the planner uses the mesh itself; the footprint is its hull);
* ``assumed`` - an object that was asked for but not located: it may stand anywhere on the table
  (the footprint is the whole table top) and reach as high as the highest located top plus its own
  height as modelled (fixtures stand as modelled). Such an obstacle blocks every touch, so a
  program is refused with its name unless it is located or drawn;
* ``drawn``   - a no-go zone an operator drew (the `no_go` parameter; the probing page draws it).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from typing import Sequence

import cv2
import numpy as np
from numpy.typing import ArrayLike
from shapely.geometry import MultiPoint
from shapely.geometry import Polygon

from app.geometry.transforms import transform_points
from app.planning.obstacles import HeightGrid

SOURCES = ("located", "assumed", "drawn")


@dataclass(frozen=True)
class KnownObstacle:
    """One obstacle of the program's world: ``footprint_xy_mm`` a polygon in table xy, ``top_mm`` its
    highest point (table z), ``source`` one of :data:`SOURCES`, ``note`` where the numbers come from."""

    name: str
    source: str
    footprint_xy_mm: tuple[tuple[float, float], ...]
    top_mm: float
    note: str = ""

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"obstacle source must be one of {SOURCES}, got {self.source!r}")
        if not np.isfinite(self.top_mm):
            raise ValueError(f"obstacle {self.name}: top must be finite, got {self.top_mm}")

    def polygon(self) -> Polygon:
        """The footprint (empty for an object taken to be inside drawn zones)."""
        return Polygon(self.footprint_xy_mm) if len(self.footprint_xy_mm) >= 3 else Polygon()


def assumed_unlocated(
    unlocated: Sequence[tuple[str, float]], table_xy_mm: tuple[float, float, float, float], support_top_mm: float
) -> list[KnownObstacle]:
    """The worst the library allows for objects asked for but not located: each ``(name, height_mm)``
    (its height as modelled) may stand anywhere on the table top ``(xmin, ymin, xmax, ymax)`` and on
    anything located there, so its top is ``support_top_mm + height_mm``."""
    x0, y0, x1, y1 = (float(v) for v in table_xy_mm)
    fp = ((x0, y0), (x1, y0), (x1, y1), (x0, y1))
    return [KnownObstacle(n, "assumed", fp, float(support_top_mm) + float(h),
                          f"asked for, not located: anywhere on the table, up to {support_top_mm:.1f} + {h:.1f} mm")
            for n, h in unlocated]


def drawn_zones(text: str, table_xy_mm: tuple[float, float, float, float], z_max_mm: float) -> list[KnownObstacle]:
    """No-go zones an operator drew: ``"x0,y0,x1,y1,top;..."`` (table frame, mm), each a rectangle
    inside the table with a top in [0, z_max_mm]. ValueError with the reason for anything else (the
    text is data: numbers and separators only, at most 20 zones)."""
    zones = [z for z in str(text).split(";") if z.strip()]
    if not zones or len(zones) > 20:
        raise ValueError("no_go: give 1 to 20 zones as x0,y0,x1,y1,top_mm separated by ';'")
    tx0, ty0, tx1, ty1 = table_xy_mm
    out = []
    for k, z in enumerate(zones, 1):
        parts = z.split(",")
        if len(parts) != 5 or not all(re.fullmatch(r"\s*[-+]?\d+(\.\d+)?\s*", p) for p in parts):
            raise ValueError(f"no_go zone {k}: expected five plain numbers x0,y0,x1,y1,top_mm")
        x0, y0, x1, y1, top = (float(p) for p in parts)
        xa, xb, ya, yb = min(x0, x1), max(x0, x1), min(y0, y1), max(y0, y1)
        if xb - xa <= 0 or yb - ya <= 0:
            raise ValueError(f"no_go zone {k}: the rectangle has no area")
        if xa < tx0 - 1e-6 or ya < ty0 - 1e-6 or xb > tx1 + 1e-6 or yb > ty1 + 1e-6:
            raise ValueError(f"no_go zone {k}: outside the table [{tx0:.0f}, {tx1:.0f}] x [{ty0:.0f}, {ty1:.0f}] mm")
        if not 0.0 <= top <= z_max_mm:
            raise ValueError(f"no_go zone {k}: top {top} mm must be in [0, {z_max_mm:.1f}] mm (the machine's travel)")
        out.append(KnownObstacle(f"drawn zone {k}", "drawn", ((xa, ya), (xb, ya), (xb, yb), (xa, yb)), top,
                                 f"x {xa:.1f}..{xb:.1f}, y {ya:.1f}..{yb:.1f} mm"))
    return out


def assumed_in_zones(unlocated: Sequence[tuple[str, float]], zones: Sequence[KnownObstacle],
                     support_top_mm: float) -> list[KnownObstacle]:
    """Objects not located, taken to be inside the operator's drawn zones (the operator says where
    they are): every zone then reaches at least as high as the highest located top plus the tallest
    such object, and the objects are listed as assumed there (no footprint of their own)."""
    tallest = max((h for _, h in unlocated), default=0.0)
    out = []
    for z in zones:
        out.append(replace(z, top_mm=max(z.top_mm, float(support_top_mm) + tallest)))
    for n, h in unlocated:
        out.append(KnownObstacle(n, "assumed", (), float(support_top_mm) + float(h),
                                 "not located: inside the drawn zones (the operator's word)"))
    return out


def raise_grid(grid: HeightGrid, obstacles: Sequence[KnownObstacle]) -> HeightGrid:
    """A copy of ``grid`` with every cell a footprint touches raised to at least that obstacle's top
    (the grid's own lateral inflation still applies to every query)."""
    img = grid.heights_mm.copy()
    c = grid.cell_mm
    for ob in obstacles:
        if len(ob.footprint_xy_mm) < 3:
            continue
        xy = np.asarray(ob.footprint_xy_mm, dtype=float)
        px = (xy - np.asarray(grid.origin_xy_mm)) / c - 0.5
        layer = np.zeros_like(img, dtype=np.uint8)
        poly = np.round(px * 16.0).astype(np.int32)
        cv2.fillPoly(layer, [poly], 1, lineType=cv2.LINE_8, shift=4)
        cv2.polylines(layer, [poly], True, 1, lineType=cv2.LINE_8, shift=4)
        layer = cv2.dilate(layer, np.ones((3, 3), np.uint8))
        img = np.where(layer > 0, np.maximum(img, np.float32(ob.top_mm)), img).astype(np.float32)
    return HeightGrid(grid.origin_xy_mm, c, img, grid.base_height_mm, grid.inflate_mm)


def retract_height_mm(tallest_top_mm: float, clearance_mm: float, z_max_mm: float, lift_mm: float = 45.0) -> float:
    """Tip height (table z) to travel at between the program's ends: ``lift_mm`` above the tallest
    obstacle, but never above the machine's travel ``z_max_mm`` (table z). ValueError when even
    the tallest obstacle plus the clearance is above the travel."""
    need = float(tallest_top_mm) + float(clearance_mm)
    if need > z_max_mm:
        raise ValueError(f"the tallest obstacle ({tallest_top_mm:.1f} mm) plus the clearance ({clearance_mm:.1f} mm) "
                         f"is above the machine's travel (top at {z_max_mm:.1f} mm over the table)")
    return float(min(need + float(lift_mm), z_max_mm))


def table_z_max_mm(T_machine_table: ArrayLike, travel_mm: dict) -> float:
    """Highest table z the controlled point can reach (machine travel z max, table not tilted)."""
    T = np.asarray(T_machine_table, dtype=float)
    return float(travel_mm["z"][1] - T[2, 3])


def outside_travel(points_table: ArrayLike, T_machine_table: ArrayLike, travel_mm: dict,
                   tol_mm: float = 1e-6) -> list[tuple[int, np.ndarray]]:
    """(index, machine point) of every point outside the machine's travel box. The moves between
    points are straight and the travel a box, so checking the ends checks every point of a move."""
    P = transform_points(np.asarray(T_machine_table, dtype=float), np.asarray(points_table, dtype=float).reshape(-1, 3))
    lo = np.array([travel_mm[a][0] for a in "xyz"], dtype=float) - tol_mm
    hi = np.array([travel_mm[a][1] for a in "xyz"], dtype=float) + tol_mm
    bad = np.flatnonzero(~np.all((P >= lo) & (P <= hi), axis=1))
    return [(int(k), P[k]) for k in bad]


_UNSAFE = re.compile(r"[^A-Za-z0-9 _.,:;=+\-/#%*\[\]<>'!?@&]")


def comment(text: str, max_len: int = 200) -> str:
    """A G-code comment ``(text)`` that cannot end early or run code: parentheses become brackets,
    every other character outside a small printable set (newlines, controls, non-ASCII) becomes _."""
    s = str(text).replace("(", "[").replace(")", "]")
    s = _UNSAFE.sub("_", s)[:max_len]
    return f"({s})"


def header_lines(frame: str, obstacles: Sequence[KnownObstacle], unknown_note: str = "") -> list[str]:
    """The program's first comment lines: the frame, then one line per obstacle with its source."""
    lines = [comment(f"frame: {frame}")]
    by = {s: [o for o in obstacles if o.source == s] for s in SOURCES}
    lines.append(comment("obstacles assumed: " + ", ".join(f"{s} {len(by[s])}" for s in SOURCES)))
    for o in obstacles:
        lines.append(comment(f"obstacle {o.source}: {o.name}, top {o.top_mm:.2f} mm{'; ' + o.note if o.note else ''}"))
    if unknown_note:
        lines.append(comment(unknown_note))
    return lines


class ProbingRefused(ValueError):
    """The program must not be issued: ``code`` (machine-readable) and the reason (the message)."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


def _touch_segments(touches):
    """Per touch: (name, approach tip, probe end tip, lowest tip z) in the table frame."""
    out = []
    for t in touches:
        a, e = np.asarray(t.approach_tip, dtype=float), np.asarray(t.probe_end_tip, dtype=float)
        out.append((t.name, a, e, float(min(a[2], e[2]))))
    return out


def touch_conflicts(touches, obstacles: Sequence[KnownObstacle], workpiece: str, params, clearance_mm: float,
                    ) -> list[tuple[str, str]]:
    """(touch, obstacle) pairs where a touch cannot be made without coming within ``clearance_mm`` of
    an obstacle given by footprint and top (assumed or drawn ones). Per touch the probe comes down
    vertically onto the approach point, then moves to ``overtravel`` beyond the contact: the ball and
    stylus sweep the xy segment approach -> probe end (grown by their radius) from the tip's height
    upward, the body the same segment (grown by its radius) from ``stylus_length_mm`` above the tip
    upward. The workpiece itself only counts for the body."""
    from shapely.geometry import LineString

    out = []
    r_small = max(params.ball_radius_mm, params.stylus_radius_mm)
    for name, a, e, z_tip in _touch_segments(touches):
        seg = LineString([tuple(a[:2]), tuple(e[:2] + 1e-6)])
        near_small = seg.buffer(r_small + clearance_mm)
        near_body = seg.buffer(params.body_radius_mm + clearance_mm)
        for ob in obstacles:
            g = ob.polygon()
            small = ob.name != workpiece and ob.top_mm > z_tip - clearance_mm and g.intersects(near_small)
            body = ob.top_mm > z_tip + params.stylus_length_mm - clearance_mm and g.intersects(near_body)
            if small or body:
                out.append((name, ob.name))
    return out


def object_grids(meshes, poses, grow_mm: float, cell_mm: float = 1.0) -> list:
    """One height raster per located mesh (grown by ``grow_mm``; nothing else in it), for
    :func:`touch_conflicts_grids`."""
    from app.planning.obstacles import height_grid_from_meshes

    return [height_grid_from_meshes([m], [p], cell_mm=cell_mm, uncertainty_mm=grow_mm, base_height_mm=-1e3)
            for m, p in zip(meshes, poses)]


def touch_conflicts_grids(touches, grids, names, workpiece_index: int, params, clearance_mm: float,
                          ) -> list[tuple[str, str]]:
    """Like :func:`touch_conflicts` for located meshes, with each mesh's own height raster
    (:func:`object_grids`) instead of a footprint hull, so that a touch between a vise's jaws or
    beside a strap clamp is judged by what really stands there."""
    segs = _touch_segments(touches)
    r_small = max(params.ball_radius_mm, params.stylus_radius_mm)
    out = []
    for k, (grid, n) in enumerate(zip(grids, names)):
        for name, a, e, z_tip in segs:
            steps = int(np.ceil(np.linalg.norm(e[:2] - a[:2]) / grid.cell_mm)) + 1
            body = grid.profile_mm(0, a[:2], e[:2], params.body_radius_mm + clearance_mm, steps).max()
            hit = body > z_tip + params.stylus_length_mm - clearance_mm
            if k != workpiece_index:
                small = grid.profile_mm(0, a[:2], e[:2], r_small + clearance_mm, steps).max()
                hit = hit or small > z_tip - clearance_mm
            if hit:
                out.append((name, n))
    return out


def _group(name: str) -> str:
    return "top" if name == "z" else ("rot" if name[-1].isdigit() else "single")


def _alternatives(group: str) -> list:
    """Touch placements to try, nearest the default first."""
    f = np.round(np.arange(0.05, 0.951, 0.05), 2)
    if group == "rot":
        pairs = [(float(a), float(b)) for a in f for b in f if b - a >= 0.4 - 1e-9]
        return sorted(pairs, key=lambda p: (abs(p[0] - 0.15) + abs(p[1] - 0.85), p))
    if group == "single":
        return sorted((float(v) for v in f), key=lambda v: (abs(v - 0.5), v))
    uv = [(float(a), float(b)) for a in f[1::2] for b in f[1::2]]
    return sorted(uv, key=lambda p: (np.hypot(p[0] - 0.5, p[1] - 0.5), p))


def side_depths_mm(default_mm: float, min_mm: float, step_mm: float = 0.25) -> list[float]:
    """Depths below a side face's upper edge to try when the default one is blocked, from just above
    the default up to ``min_mm`` (nearest the default first)."""
    out = [float(d) for d in np.arange(default_mm - step_mm, min_mm - 1e-9, -step_mm)]
    return out + [float(min_mm)] if not out or out[-1] > min_mm + 1e-9 else out


def place_touches(choose, conflicts, max_tries: int = 200, depths_mm: Sequence[float] = ()):
    """Touches whose placement keeps clear of obstacles: the default, or, per group of touches
    (the two on the rotation face, the single side touch, the top touch) that conflicts, the first
    alternative placement (nearest the default) whose touches of that group are clear; a side group
    still blocked (a face held by vise jaws) then moves up its face, to the first of ``depths_mm``
    (below the face's upper edge) where it is clear. ``choose``: placement -> touches (may raise
    ValueError); ``conflicts``: touches -> [(touch, obstacle)]. Returns (touches, remaining conflicts,
    placement)."""
    from app.planning.probing import TouchPlacement

    placement = TouchPlacement()
    touches = choose(placement)
    found = conflicts(touches)
    for group, field_name in (("rot", "rot_fracs"), ("single", "single_frac"), ("top", "top_frac")):
        if not any(_group(t) == group for t, _ in found):
            continue
        tries = [{field_name: alt} for alt in _alternatives(group)[:max_tries]]
        if group != "top":
            tries += [{f"{group}_depth_mm": d} for d in depths_mm]
        for change in tries:
            trial = replace(placement, **change)
            try:
                cand = choose(trial)
            except ValueError:
                continue
            if not conflicts([t for t in cand if _group(t.name) == group]):
                placement = trial
                break
    touches = choose(placement)
    return touches, conflicts(touches), placement


def room_above(touches, blocked, grids, names, workpiece_index: int, params, clearance_mm: float,
               grow_mm: float, face_top_mm) -> list[str]:
    """Why side touches blocked by a fixture beside them (a face held by vise jaws) cannot move up
    their face: one sentence (or none) saying, per (touch, obstacle), how far the part stands above
    that obstacle there, and how far it must (ball radius + clearance + edge margin + twice the
    3-sigma growth). ``face_top_mm``: touch name -> table z of its face's upper edge."""
    r_small = max(params.ball_radius_mm, params.stylus_radius_mm)
    by_name = {t.name: t for t in touches}
    need = params.ball_radius_mm + clearance_mm + params.edge_margin_mm + 2.0 * grow_mm
    found = []
    for tname, oname in blocked:
        t = by_name.get(tname)
        if t is None or _group(tname) == "top" or oname not in names or names.index(oname) == workpiece_index:
            continue
        grid = grids[names.index(oname)]
        a, e = np.asarray(t.approach_tip, dtype=float), np.asarray(t.probe_end_tip, dtype=float)
        steps = int(np.ceil(np.linalg.norm(e[:2] - a[:2]) / grid.cell_mm)) + 1
        top = float(grid.profile_mm(0, a[:2], e[:2], r_small + clearance_mm, steps).max()) - grow_mm
        found.append(f"{float(face_top_mm[tname]) - top:.1f} mm above {oname} at touch {tname}")
    if not found:
        return []
    return [f"the part stands {', '.join(found)}; moving a touch up its face into the free band needs {need:.1f} mm "
            f"(ball {params.ball_radius_mm:g} + clearance {clearance_mm:g} + edge margin {params.edge_margin_mm:g} "
            f"+ 2 x 3 sigma {grow_mm:.2f} mm): probe with the part higher in the vise, a smaller clearance, or "
            "set the offset by hand"]


def _face_top(choose, touch_name: str, depth_mm: float) -> float:
    """Table z of the upper edge of the side face a touch is on (its contact at ``depth_mm`` below it)."""
    from app.planning.probing import TouchPlacement

    group = _group(touch_name)
    try:
        ts = choose(TouchPlacement(**{f"{group}_depth_mm": depth_mm}))
    except ValueError:
        return float("nan")
    return next(float(t.contact[2]) + depth_mm for t in ts if t.name == touch_name)


def plan_probing_program(
    meshes: Sequence,
    poses: Sequence[ArrayLike],
    names: Sequence[str],
    workpiece_index: int,
    T_obj_datum: ArrayLike,
    *,
    sigma_mm: float,
    assumed: Sequence[KnownObstacle],
    T_machine_table: ArrayLike,
    travel_mm: dict,
    T_prog_table: ArrayLike,
    slot: str,
    clearance_mm: float,
    dry_run: bool,
    frame_text: str,
    title: str = "setupcam probing",
    params=None,
    method: str = "profile",
    unknown_note: str = "",
    speeds=None,
    axis_at: tuple[str, float] | None = None,
    dialect: str = "linuxcnc",
    detour: str = "straight",
):
    """A probing program planned only around what is known, or :class:`ProbingRefused`.

    meshes/poses/names : the located objects (obj frame meshes, T_table_obj), the workpiece at
    ``workpiece_index``; each is grown by ``3 * sigma_mm`` (its 1-sigma position uncertainty).
    assumed : obstacles not located (see :func:`assumed_unlocated`) or drawn.
    T_prog_table : the program frame (the slot's frame); slot : its name (G54..G59.3).
    Refusal codes: no_touch_points, obstacle_not_located (an assumed obstacle is where a touch goes),
    touch_blocked (a located obstacle is), retract_above_travel, not_plannable, outside_travel.
    axis_at : a rotary table's (axis, degrees) that T_machine_table is for: the program aborts unless
    the axis stands there (app.planning.probing.rotary_guard_lines).
    detour : "straight" (every move written out, ``method`` planner, LinuxCNC) or "subroutine" (the travel
    as calls of the detour subroutine in ``dialect``, reference method around the obstacles' bounding
    boxes in the program frame: app/planning/detour_program.py).
    Returns app.planning.probing.ProbingProgram; its G-code starts with :func:`header_lines`.
    """
    from app.planning.obstacles import height_grid_from_meshes
    from app.planning.path import AxisSpeeds, ProbeParams
    from app.planning.probing import (
        ProbingParams,
        TouchPlacement,
        choose_touch_points,
        gcode_positions,
        probing_gcode,
    )

    params = params or ProbingParams()
    speeds = speeds or AxisSpeeds()
    grow = 3.0 * float(sigma_mm)
    located = []
    tops = []
    for m, p, n in zip(meshes, poses, names):
        V = transform_points(np.asarray(p, dtype=float), m.vertices)
        tops.append(float(V[:, 2].max()))
        hull = MultiPoint([tuple(v) for v in V[:, :2]]).convex_hull.buffer(grow, join_style="mitre")
        located.append(KnownObstacle(n, "located", tuple(map(tuple, np.asarray(hull.exterior.coords)[:-1])),
                                     tops[-1] + grow, f"grown by 3 sigma = {grow:.2f} mm"))
    # the approach starts the clearance away from the face wherever within its uncertainty the face is
    params = replace(params, approach_mm=max(params.approach_mm, clearance_mm + grow))

    def choose(placement):
        return choose_touch_points(meshes[workpiece_index], poses[workpiece_index], T_obj_datum, params, placement)

    try:
        touches = choose(TouchPlacement())
    except ValueError as exc:
        raise ProbingRefused("no_touch_points", str(exc)) from None
    wp = names[workpiece_index]
    # an assumed obstacle whose footprint covers the whole part is in the way wherever a touch goes
    wp_hull = located[workpiece_index].polygon()
    everywhere = [o for o in assumed if o.polygon().contains(wp_hull)]
    hidden = sorted({o for _, o in touch_conflicts(touches, everywhere, wp, params, clearance_mm)})
    if hidden:
        raise ProbingRefused("obstacle_not_located", f"{', '.join(hidden)} asked for but not located; it may stand "
                             "anywhere on the table, where the touches go. Locate it (another image), draw where "
                             "it is (no_go) or remove it from the setup's models")
    grids = object_grids(meshes, poses, grow)
    # a side touch may move up its face as far as the edge margin plus the part's 3-sigma growth
    min_depth = params.edge_margin_mm + grow
    default_depth = max(params.depth_mm, params.ball_radius_mm + params.edge_margin_mm)
    touches, blocked, _ = place_touches(
        choose, lambda ts: (touch_conflicts(ts, assumed, wp, params, clearance_mm)
                            + touch_conflicts_grids(ts, grids, names, workpiece_index, params, clearance_mm)),
        depths_mm=side_depths_mm(default_depth, min_depth) if default_depth > min_depth else ())
    unknown = sorted({o for _, o in blocked if o in {a.name for a in assumed}})
    if unknown:
        raise ProbingRefused("obstacle_not_located", f"every touch placement comes within {clearance_mm} mm of "
                             f"{', '.join(unknown)} (not located or drawn); locate the objects or draw tighter zones")
    if blocked:
        pairs = ", ".join(f"touch {t} by {o}" for t, o in blocked)
        why = room_above(touches, blocked, grids, names, workpiece_index, params, clearance_mm, grow,
                         {t.name: _face_top(choose, t.name, min_depth) for t in touches if _group(t.name) != "top"})
        raise ProbingRefused("touch_blocked", f"a touch cannot be reached with {clearance_mm} mm clearance: {pairs}"
                             + (f" ({'; '.join(why)})" if why else ""))
    tallest = max(o.top_mm for o in [*located, *assumed])
    try:
        retract = retract_height_mm(tallest, clearance_mm, table_z_max_mm(T_machine_table, travel_mm))
    except ValueError as exc:
        raise ProbingRefused("retract_above_travel", str(exc)) from None
    travel = ProbeParams(working_distance_mm=0.0, clearance_mm=clearance_mm, radius_mm=params.body_radius_mm,
                         length_mm=params.stylus_length_mm + params.body_length_mm)
    header = header_lines(frame_text, [*located, *assumed], unknown_note)
    centre = np.asarray(poses[workpiece_index], dtype=float)[:3, 3]
    T_table_prog = np.linalg.inv(np.asarray(T_prog_table, dtype=float))
    try:
        if detour == "subroutine":
            from app.planning.detour_program import detour_probing_program

            if axis_at is not None:
                raise ProbingRefused("not_plannable", "the detour subroutine does not check a rotary table's "
                                     "angle before it moves; on this machine use detour=straight (LinuxCNC), "
                                     "whose program aborts unless the axis stands at the export angle")
            program = detour_probing_program(dialect, touches, [*located, *assumed], travel,
                                             (centre[0], centre[1], retract), params=params, dry_run=dry_run, wcs=slot,
                                             T_prog_table=T_prog_table, header=header, retract_z_mm=retract,
                                             title=title)
        elif detour == "straight":
            grid = raise_grid(height_grid_from_meshes(meshes, poses, uncertainty_mm=grow), assumed)
            program = probing_gcode(touches, grid, travel, (centre[0], centre[1], retract), params=params,
                                    speeds=speeds, dry_run=dry_run, wcs=slot, T_prog_table=T_prog_table,
                                    header=header, retract_z_mm=retract, title=title, method=method, axis_at=axis_at)
        else:
            raise ValueError(f"unknown detour {detour!r}; use 'straight' or 'subroutine'")
    except ValueError as exc:
        raise ProbingRefused("not_plannable", str(exc)) from None
    if detour == "subroutine":  # the planner's path is what the controller will do (tests/planning/test_detour*)
        table_pts = np.array([w for p in program.travel for w in p.waypoints]
                             + [t.probe_end_tip for t in touches] + [(centre[0], centre[1], retract)])
    else:
        pts = np.array([q for _, q in gcode_positions(program.gcode) if not np.isnan(q).any()])
        table_pts = transform_points(T_table_prog, pts)
    bad = outside_travel(table_pts, T_machine_table, travel_mm)
    if bad:
        k, q = bad[0]
        raise ProbingRefused("outside_travel", f"{len(bad)} moves end outside the machine's travel, first at machine "
                             f"X{q[0]:.3f} Y{q[1]:.3f} Z{q[2]:.3f}")
    return replace(program, obstacles=(*located, *assumed), frame=frame_text)


__all__ = [
    "ProbingRefused",
    "touch_conflicts",
    "object_grids",
    "touch_conflicts_grids",
    "place_touches",
    "plan_probing_program",
    "SOURCES",
    "KnownObstacle",
    "assumed_unlocated",
    "drawn_zones",
    "assumed_in_zones",
    "raise_grid",
    "retract_height_mm",
    "table_z_max_mm",
    "outside_travel",
    "comment",
    "header_lines",
]
