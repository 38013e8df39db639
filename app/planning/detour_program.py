"""A probing program whose travel is one call of the detour subroutine per move (issue 16, part 3).

The same touches, start and retract as :func:`app.planning.probing.probing_gcode`, but the linking
moves are not written out: the program calls the subroutine of app/planning/detour_subroutine.py
with each target, and the controller decides the detour (reference method) itself. The Python
planner's path for the same, quantised, numbers is returned with the text (``travel``), so the
caller can check it (machine travel) and tests can compare it with what a controller does.

Frames: touches and obstacles come in the table frame; the program is written in the program frame
``prog`` (``T_prog_table``, no tilt), and the obstacle boxes are the bounding rectangles of the
footprints *in the program frame* (axis-aligned there, where the controller's move box is). mm.

Touch moves per dialect: LinuxCNC ``G38.2`` (results by ``PROBEOPEN``), Fanuc ``G31`` skip (contact
in ``#5061..#5063`` saved to ``#501..``), Sinumerik ``MEAS=1 G1`` (``$AA_MW`` saved to ``R10..``),
HEIDENHAIN touch probe cycle 4 MEASURING IN 3-D (contact in ``Q50..``). The dry run replaces each by a
feed move to the nominal contact.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from app.geometry.transforms import check_pose, inv, tilt_deg, transform_points
from app.planning.detour_emit import (
    assemble,
    check_dialect,
    comment,
    emit_call,
    emit_feed,
    emit_rapid,
    emit_subroutine,
    num,
    quantise_inputs,
    quantise_point,
)
from app.planning.detour_subroutine import BoxObstacles, ObstacleBox, build_detour
from app.planning.path import PlannedMove, PlannedPath, ProbeParams, pt
from app.planning.reference import ReferenceOptions, plan_path_reference


def program_boxes(obstacles: Sequence, T_prog_table: ArrayLike, base_height_mm: float = 0.0) -> BoxObstacles:
    """Bounding rectangles in the program frame of obstacles given by ``footprint_xy_mm`` / ``top_mm``
    in the table frame (KnownObstacle); footprint-less ones (taken to be inside drawn zones) skipped.
    ``base_height_mm``: the table top (table z), moved into the program frame too."""
    T = check_pose(T_prog_table, "T_prog_table")
    out = []
    for o in obstacles:
        xy = np.asarray(o.footprint_xy_mm, dtype=float).reshape(-1, 2)
        if len(xy) < 3:
            continue
        P = transform_points(T, np.column_stack([xy, np.full(len(xy), float(o.top_mm))]))
        out.append(ObstacleBox(float(P[:, 0].min()), float(P[:, 1].min()), float(P[:, 0].max()), float(P[:, 1].max()),
                               float(P[:, 2].max()), str(getattr(o, "name", ""))))
    base = float(transform_points(T, [[0.0, 0.0, float(base_height_mm)]])[0, 2])
    return BoxObstacles(tuple(out), base)


def _modal(dialect: str, slot: str) -> list[str]:
    """Units, absolute, plane, feed per minute, no radius compensation, exact stop, the work offset."""
    from app.machine.base import slot_number

    if dialect == "linuxcnc":
        return [f"G21 G90 G17 G94 G40 G61 {slot}"]
    if dialect == "fanuc":
        return ["G21 G90 G17 G94 G40 G61", slot]
    if dialect == "siemens":
        return ["G71 G90 G17 G94 G40 G60", slot]
    return ["CYCL DEF 247 DATUM SETTING ~", f"  Q339=+{slot_number(slot)} ;DATUM NUMBER"]


def _touch(dialect: str, k: int, approach, end, feed: float) -> list[str]:
    """The probing move of touch ``k`` from ``approach`` towards ``end`` (program frame) and where its
    result goes."""
    x, y, z = (num(dialect, v) for v in end)
    f = f"F{feed:.0f}"
    if dialect == "linuxcnc":
        return [f"G38.2 X{x} Y{y} Z{z} {f}"]
    if dialect == "fanuc":
        r = 501 + 3 * k
        return [f"G31 X{x} Y{y} Z{z} {f}", f"#{r}=#5061", f"#{r + 1}=#5062", f"#{r + 2}=#5063"]
    if dialect == "siemens":
        r = 10 + 3 * k
        return [f"MEAS=1 G1 X{x} Y{y} Z{z} {f}", "STOPRE", f"R{r}=$AA_MW[X]", f"R{r + 1}=$AA_MW[Y]",
                f"R{r + 2}=$AA_MW[Z]"]
    d = np.asarray(end, dtype=float) - np.asarray(approach, dtype=float)
    dist = float(np.linalg.norm(d))
    u = d / dist
    q = 50 + 3 * k
    return ["TCH PROBE 4.0 MEASURING IN 3-D", f"TCH PROBE 4.1 Q{q}",
            f"TCH PROBE 4.2 IX{u[0]:+.4f} IY{u[1]:+.4f} IZ{u[2]:+.4f}",
            f"TCH PROBE 4.3 ABST{dist:+.4f} {f} MB{dist:.4f} REFERENCE SYSTEM:0"]


def detour_probing_program(
    dialect: str,
    touches: Sequence,
    obstacles: Sequence,
    travel_probe: ProbeParams,
    start_table: ArrayLike,
    *,
    params,
    T_prog_table: ArrayLike | None = None,
    wcs: str = "G54",
    dry_run: bool = False,
    title: str = "setupcam probing",
    header: Sequence[str] = (),
    retract_z_mm: float | None = None,
    options: ReferenceOptions | None = None,
    base_height_mm: float = 0.0,
):
    """The probing program in ``dialect`` with the detour subroutine: ProbingProgram whose ``gcode``
    is the file's text and whose ``travel`` holds the Python planner's path per move (table frame).

    ``obstacles``: KnownObstacle-like (footprint and top, table frame). ``options``: the reference
    method's switches; by default the box margin is the probe's radius plus its lateral margin.
    ``header``: comment texts (LinuxCNC ``(..)`` comments are unwrapped and rewritten per dialect)."""
    from app.machine.nc_files import SLOTS
    from app.planning.probing import ProbingProgram

    d = check_dialect(dialect)
    slot = str(wcs).upper()
    if slot not in SLOTS[d]:
        raise ValueError(f"{d} cannot run in {wcs!r}; use one of {', '.join(SLOTS[d])}")
    T = np.eye(4) if T_prog_table is None else check_pose(T_prog_table, "T_prog_table")
    if tilt_deg(T) > 1e-6:
        raise ValueError("T_prog_table must not tilt: the program frame's z has to be the table's z")
    opt = options or ReferenceOptions(box_margin_mm=travel_probe.radius_mm + travel_probe.lateral_margin_mm)
    boxes, probe, opt = quantise_inputs(d, program_boxes(obstacles, T, base_height_mm), travel_probe, opt)
    sub = build_detour(boxes, probe, opt)
    start = np.asarray(start_table, dtype=float).reshape(3)
    retract = float(start[2] if retract_z_mm is None else retract_z_mm)
    if not np.all(np.isfinite(start)) or not np.isfinite(retract) or retract < start[2]:
        raise ValueError("start must be finite and the retract height not below it")

    def prog(p):
        return quantise_point(d, transform_points(T, np.asarray(p, dtype=float).reshape(1, 3))[0])

    p0 = prog(start)
    z_retract = prog((start[0], start[1], retract))[2]
    main = [comment(d, ln.strip()[1:-1] if ln.startswith("(") else ln) for ln in header]
    main += [comment(d, f"{title}{' - DRY RUN: probe moves as feed moves to the nominal contact' if dry_run else ''}"),
             comment(d, f"travel: one call per move of the detour subroutine, {len(sub.boxes.boxes)} obstacle boxes "
                        f"baked in, margin {opt.box_margin_mm:g} mm, clearance {probe.clearance_mm:g} mm"),
             comment(d, "units mm, positions are the probe tip, probe tool and length offset active"),
             *_modal(d, slot), emit_rapid(d, (0.0, 0.0, z_retract), "Z"), emit_rapid(d, p0, "XY"),
             emit_feed(d, p0, 5000.0, "Z")]
    if d == "linuxcnc" and not dry_run:
        main.append("(PROBEOPEN setupcam_probe.txt)")
    stops = [p0] + [prog(t.approach_tip) for t in touches] + [p0]
    T_table_prog = inv(T)
    travel = []
    for i in range(len(stops) - 1):
        path = plan_path_reference([stops[i], stops[i + 1]], boxes, probe, opt)
        travel.append(_to_table(path, T_table_prog))
        main.append(comment(d, f"travel to {'touch ' + touches[i].name if i < len(touches) else 'start'}"))
        main += emit_call(d, stops[i + 1])
        if i < len(touches):
            t = touches[i]
            if dry_run:
                main.append(emit_feed(d, prog(t.contact_tip), params.probe_feed_mm_min))
            else:
                main += _touch(d, i, stops[i + 1], prog(t.probe_end_tip), params.probe_feed_mm_min)
            main.append(emit_feed(d, stops[i + 1], params.probe_feed_mm_min * 5))
    if d == "linuxcnc" and not dry_run:
        main.append("(PROBECLOSE)")
    main.append(emit_rapid(d, (0.0, 0.0, z_retract), "Z"))
    text = assemble(d, title.replace(" ", "_").replace(",", ""), main, emit_subroutine(d, sub))
    return ProbingProgram(tuple(touches), tuple(travel), text, dry_run)


def _to_table(path: PlannedPath, T_table_prog: np.ndarray) -> PlannedPath:
    """A path planned in the program frame, its points in the table frame (heights unchanged in
    meaning: the frames differ by a turn about z and a shift)."""

    def tab(p):
        return pt(transform_points(T_table_prog, [p])[0])

    moves = tuple(PlannedMove(m.index, tab(m.start), tab(m.target), m.pattern, tuple(tab(p) for p in m.waypoints),
                              m.obstacle_height_mm, m.safe_height_mm) for m in path.moves)
    return PlannedPath(path.method, moves, path.coordinated)


__all__ = ["detour_probing_program", "program_boxes"]
