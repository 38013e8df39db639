"""Planning use cases: safe travel paths (plain requests or a located setup's scene) and probing programs.

The maths is in app/planning/; this module only gathers the located scene (meshes at T_table_obj,
inflated by their uncertainty) from a setup and turns planner errors into 422 answers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlmodel import Session, select

from app.config import get_settings
from app.geometry.mesh import load_mesh
from app.geometry.transforms import inv, transform_points
from app.machine import ControllerError, SLOT_P_NUMBERS, WorkOffset, make_controller, parse_controller_settings
from app.machine.nc_files import DIALECTS, SLOTS
from app.planning.detour_emit import DETOUR_DIALECTS, SUFFIX
from app.planning.probing import ProbingParams, choose_touch_points, parse_probe_results, refine_offset
from app.planning.probing_safety import (ProbingRefused, assumed_in_zones, assumed_unlocated, drawn_zones,
                                         plan_probing_program, table_z_max_mm)
from app.planning.request import plan_request
from app.services import library
from app.services.errors import Conflict, Invalid, Unavailable
from app.services.export import plausibility, require_confirmed
from app.services.machines import get_machine
from app.services.setup_result import LocatedObject
from app.services.setups import get_setup, library_candidates, revise, setup_result
from app.store.files import FileStore
from app.store.models import Export


@dataclass
class Scene:
    """The located objects of a setup that have a library model, in one order: their meshes (model frame,
    mm), poses ``T_table_obj`` (4x4, mm) and names; the largest translational 1-sigma of them (mm); the
    first workpiece, its index in these lists and in the result's objects (None without one)."""

    meshes: list
    poses: list[np.ndarray]
    names: list[str]
    sigma_mm: float
    workpiece: LocatedObject | None
    workpiece_index: int | None
    workpiece_result_index: int | None = None


def setup_scene(session: Session, files: FileStore, setup_id: int) -> Scene:
    """The :class:`Scene` of a located setup."""
    s = get_setup(session, setup_id)
    if s.status != "located" or not s.result:
        raise Invalid(f"setup {setup_id} is {s.status}; paths need a located setup")
    result = setup_result(s)
    at = [i for i, o in enumerate(result.objects) if o.model_id]  # index in the result
    objs = [result.objects[i] for i in at]
    cands = {(c.model_id, c.revision): c for c in library_candidates(
        session, files, [{"model_id": o.model_id, "revision": o.revision} for o in objs])}
    sig = 0.0
    for o in objs:
        sig = max([sig, *(v for k, v in o.sigma.items() if k.endswith("_mm") and v is not None)])
    wi = next((i for i, o in enumerate(objs) if o.kind == "workpiece"), None)
    return Scene([cands[(o.model_id, o.revision)].mesh for o in objs], [o.pose for o in objs],
                 [o.name for o in objs], sig, None if wi is None else objs[wi], wi, None if wi is None else at[wi])


def plan(session: Session, files: FileStore, request: dict[str, Any]) -> dict:
    """Plan a path for a REST request; ``obstacles: {"setup_id": n}`` uses that setup's located scene."""
    req = dict(request)
    ob = req.get("obstacles")
    if isinstance(ob, dict) and "meshes" in ob:
        raise Invalid("obstacles.meshes with file paths is for the CLI; over REST give setup_id, regions, "
                      "part_top_mm or per_move_mm")
    if isinstance(ob, dict) and "setup_id" in ob:
        scene = setup_scene(session, files, int(ob["setup_id"]))
        meshes, poses, names, sig = scene.meshes, scene.poses, scene.names, scene.sigma_mm
        if not meshes:
            raise Invalid(f"setup {ob['setup_id']} has no located objects to plan around")
        req["obstacles"] = {"meshes": [{"mesh": m, "T_table_obj": p.tolist(), "name": n}
                                       for m, p, n in zip(meshes, poses, names)],
                            "uncertainty_mm": float(ob.get("uncertainty_mm", 3.0 * sig))}
    try:
        return plan_request(req)
    except ValueError as exc:
        raise Invalid(str(exc)) from None


#: query parameters of the probing program: a closed set, each value checked below
PROGRAM_PARAMS = ("dialect", "dry_run", "wcs", "clearance_mm", "no_go", "detour")
#: dialects the probing program is written in (the NC-file dialects of app.machine.nc_files otherwise)
PROBE_DIALECTS = ("linuxcnc",)
#: how the travel is written: "straight" every move written out (profile planner), "subroutine" one call
#: per move of the detour subroutine the controller evaluates (reference method; app/planning/detour_*.py)
DETOURS = ("straight", "subroutine")
#: dialects of the detour subroutine
SUBROUTINE_DIALECTS = DETOUR_DIALECTS
CLEARANCE_RANGE_MM = (1.0, 20.0)


def controller_slots(controller: dict | None, dialect: str) -> tuple[str, ...]:
    """Work-offset slots the machine's controller holds (a closed set): a file controller's dialect's
    slots, an OPC UA controller's one slot unless its node ids carry {slot}/{p}, LinuxCNC's nine; without
    a controller, the slots of the requested dialect."""
    if not controller:
        return SLOTS.get(dialect, ())
    c = parse_controller_settings(controller)
    if c.kind == "file":
        return SLOTS[c.dialect]
    if c.kind == "opcua":
        ids = " ".join(v or "" for v in c.nodes.model_dump().values())
        return tuple(SLOT_P_NUMBERS) if ("{slot}" in ids or "{p}" in ids) else (c.slot,)
    return SLOTS["linuxcnc"]


def check_detour(detour: str) -> str:
    """The detour form from its closed set, or Invalid (code unknown_detour) naming the ones there are."""
    t = str(detour).lower()
    if t not in DETOURS:
        raise Invalid(f"detour {str(detour)[:40]!r} is unknown; use one of {', '.join(DETOURS)} (straight: every "
                      "move written out; subroutine: the controller evaluates the detour per move)",
                      code="unknown_detour")
    return t


def check_program_params(machine, *, dialect: str, wcs: str, clearance_mm: float,
                         detour: str = "straight") -> tuple[str, str, float]:
    """(dialect, slot, clearance) from the closed sets, or Invalid with a reason code: unknown_detour,
    unknown_dialect, dialect_not_supported, dialect_mismatch, wcs_not_a_slot, clearance_out_of_range."""
    t = check_detour(detour)
    d = str(dialect).lower()
    if d not in DIALECTS:
        raise Invalid(f"dialect {str(dialect)[:40]!r} is unknown; use one of {', '.join(DIALECTS)}",
                      code="unknown_dialect")
    allowed = SUBROUTINE_DIALECTS if t == "subroutine" else PROBE_DIALECTS
    if d not in allowed:
        raise Invalid(f"probing programs with detour={t} are written for {', '.join(allowed)} only, not {d}"
                      + ("; detour=subroutine is written for every dialect" if t == "straight" else ""),
                      code="dialect_not_supported")
    ctrl = machine.controller or {}
    if ctrl.get("kind") == "file" and ctrl.get("dialect") != d:
        raise Invalid(f"machine {machine.id} reads {ctrl.get('dialect')} files; a {d} program would not run there",
                      code="dialect_mismatch")
    slots = tuple(x for x in controller_slots(ctrl, d) if x in SLOTS[d])
    slot = str(wcs).upper()
    if slot not in slots:
        raise Invalid(f"wcs {wcs!r} is not a work-offset slot of machine {machine.id}'s controller; use one of "
                      f"{', '.join(slots)}", code="wcs_not_a_slot")
    c = float(clearance_mm)
    lo, hi = CLEARANCE_RANGE_MM
    if not np.isfinite(c) or not lo <= c <= hi:
        raise Invalid(f"clearance_mm must be a finite number in [{lo}, {hi}] mm, got {clearance_mm!r}",
                      code="clearance_out_of_range")
    return d, slot, c


def program_suffix(dialect: str) -> str:
    """File name suffix of a probing program in ``dialect`` (checked before: one of the closed set)."""
    return SUFFIX.get(str(dialect).lower(), ".ngc")


def probing_program(session: Session, files: FileStore, settings, setup_id: int, *, dry_run: bool,
                    wcs: str = "G54", dialect: str = "linuxcnc", clearance_mm: float = 5.0,
                    no_go: str | None = None, detour: str = "straight") -> str:
    """Probing program for the confirmed workpiece of a setup (the datum frame in slot ``wcs``), in
    ``dialect``; ``detour="subroutine"``: the travel as calls of the detour subroutine."""
    return probing_plan(session, files, settings, setup_id, dry_run=dry_run, wcs=wcs, dialect=dialect,
                        clearance_mm=clearance_mm, no_go=no_go, detour=detour).gcode


def _unlocated(session: Session, files: FileStore, s) -> list[tuple[str, float]]:
    """(name, height as modelled in mm) of every object asked for but not located."""
    asked = {int(m["model_id"]): m.get("revision") for m in (s.models or [])}
    out = []
    for nf in (s.result or {}).get("not_found") or []:
        if not nf.get("name"):
            continue
        h = None
        mid = nf.get("model_id")
        if mid is not None:
            rev = library.get_revision(session, int(mid), asked.get(int(mid)))
            h = float(load_mesh(files.read(rev.glb_sha256), "model.glb", "mm").extents[2])
        out.append((str(nf["name"]), h if h is not None else float("inf")))
    return out


def table_xy(session: Session, files: FileStore, machine) -> tuple[float, float, float, float]:
    """The table model's xy bounds in the table frame (mm)."""
    rev = library.get_revision(session, machine.table_model_id, machine.table_revision)
    b = load_mesh(files.read(rev.glb_sha256), "model.glb", "mm").bounds
    return float(b[0, 0]), float(b[0, 1]), float(b[1, 0]), float(b[1, 1])


def _frame_of(session: Session, machine, s, slot: str, off: dict) -> str:
    """The header's frame sentence; with a live controller, Conflict unless a verified export of this
    revision to ``slot`` exists and the controller holds it now (read back)."""
    want = WorkOffset(off["x_mm"], off["y_mm"], off["z_mm"], off["c_deg"])
    what = (f"{slot} = datum of {off.get('object')}, setup {s.id} revision {s.result_revision}: {want} "
            "(machine coordinates)")
    kind = (machine.controller or {}).get("kind")
    if kind not in ("linuxcnc", "opcua"):
        return what + "; not read back here: load this revision's offset into " + slot + " before running"
    done = session.exec(select(Export).where(Export.setup_id == s.id, Export.slot == slot,
                                            Export.result_revision == s.result_revision,
                                            Export.status == "written")).first()
    if done is None:
        raise Conflict(f"the program runs in {slot}, which must hold the datum of setup {s.id} revision "
                       f"{s.result_revision}: export it to {slot} (verified) first", code="frame_not_exported")
    controller = make_controller(machine.controller)
    try:
        now = controller.read_offset(slot)
    except ControllerError as exc:
        raise Unavailable(f"{exc}; the program's frame {slot} could not be read back") from None
    finally:
        controller.close()
    if not want.agrees_with(now, controller.rounding_mm, controller.rounding_deg):
        raise Conflict(f"{slot} on the controller is {now}, not the exported {want}; export again",
                       code="frame_mismatch")
    return what + f"; verified export {done.id}, read back now"


def probing_plan(session: Session, files: FileStore, settings, setup_id: int, *, dry_run: bool = True,
                 wcs: str = "G54", dialect: str = "linuxcnc", clearance_mm: float = 5.0, check_frame: bool = True,
                 no_go: str | None = None, detour: str = "straight"):
    """The probing program with its touches and safe travel paths: ProbingProgram (travel in the
    table frame, G-code in the datum frame of slot ``wcs``).

    Gates (each refusal a 409/422 with a reason code): the parameters' closed sets; the export's
    gates (confirmed revision, tilt, uncertainty PASS, offset inside the travel); then the planner's
    (app.planning.probing_safety.plan_probing_program: objects asked for but not located, touches
    blocked, retract height and every move inside the travel); the frame (with a live controller:
    a verified export of this revision, read back now; ``check_frame=False`` skips that for drawing the
    plan, and ``settings=None`` takes the process's settings)."""
    if settings is None:
        settings = get_settings()
    s = get_setup(session, setup_id)
    machine = get_machine(session, s.machine_id)
    d, slot, clearance = check_program_params(machine, dialect=dialect, wcs=wcs, clearance_mm=clearance_mm,
                                              detour=detour)
    zones = []
    if no_go is not None:
        try:
            zones = drawn_zones(no_go, table_xy(session, files, machine),
                                table_z_max_mm(machine.T_machine_table, machine.travel_mm))
        except ValueError as exc:
            raise Invalid(str(exc), code="no_go_invalid") from None
    require_confirmed(s, "probed")
    _, off = plausibility(s, machine, settings, use="probing program")
    scene = setup_scene(session, files, setup_id)
    meshes, poses, names, sig, wp = scene.meshes, scene.poses, scene.names, scene.sigma_mm, scene.workpiece
    if wp is None:
        raise Invalid(f"setup {setup_id} has no located workpiece to probe", code="no_workpiece")
    unlocated = _unlocated(session, files, s)
    unknown = [n for n, h in unlocated if not np.isfinite(h)]
    if unknown:
        raise Invalid(f"objects {', '.join(unknown)} were asked for but not located and their size is not known; "
                      "locate them before probing", code="obstacle_not_located")
    tops = [float(transform_points(p, m.vertices)[:, 2].max()) for m, p in zip(meshes, poses)]
    support = max([0.0, *tops])
    if unlocated and zones:  # the operator drew where they are
        assumed = assumed_in_zones(unlocated, zones, support)
    elif unlocated:
        assumed = [*assumed_unlocated(unlocated, table_xy(session, files, machine), support), *zones]
    else:
        assumed = zones
    frame = (_frame_of(session, machine, s, slot, off) if check_frame
             else f"{slot} = datum of {off.get('object')} (drawing only, not read back)")
    try:
        return plan_probing_program(
            meshes, poses, names, scene.workpiece_index, wp.datum,
            sigma_mm=sig, assumed=assumed, T_machine_table=np.asarray(machine.T_machine_table, dtype=float),
            travel_mm=machine.travel_mm, T_prog_table=program_frame(machine, off), slot=slot, clearance_mm=clearance,
            dry_run=dry_run, frame_text=frame, title=f"setupcam probing, setup {setup_id}",
            unknown_note="" if s.models else "objects not asked for in the setup are not known to the planner",
            # a rotary table: the frame is the table at the export angle, so the program runs only there
            axis_at=(machine.rotary_axis["name"], float(machine.rotary_axis["export_at_deg"]))
            if machine.rotary_axis else None,
            dialect=d, detour=check_detour(detour))
    except ProbingRefused as exc:
        raise Invalid(f"probing program refused: {exc}", code=exc.code) from None


def program_frame(machine, off: dict) -> np.ndarray:
    """``T_prog_table``: the frame the export writes into the slot, X, Y, Z, C of the datum in machine
    coordinates (its small tilt dropped, as the export drops it), seen from the table frame."""
    T_machine_prog = WorkOffset(off["x_mm"], off["y_mm"], off["z_mm"], off["c_deg"]).to_pose()
    return inv(T_machine_prog) @ np.asarray(machine.T_machine_table, dtype=float)


def _touches(session: Session, files: FileStore, setup_id: int):
    scene = setup_scene(session, files, setup_id)
    wp, i = scene.workpiece, scene.workpiece_index
    if wp is None:
        raise Invalid(f"setup {setup_id} has no located workpiece to probe")
    params = ProbingParams()
    return choose_touch_points(scene.meshes[i], scene.poses[i], wp.datum, params), params, scene


#: what a touch may differ from the truth besides the located error (probe repeatability, rounding), mm
PROBE_TOLERANCE_MM = 0.05


def apply_probe_results(session: Session, files: FileStore, settings, setup_id: int, text: str,
                        by: str | None) -> Any:
    """Refine the confirmed workpiece pose from the probing program's results (least squares) and make
    it a new result revision; it must be confirmed again before export (the usual safety gate).

    The workpiece records ``probe_before`` (its pose before) and ``probe_residuals_mm`` (per touch,
    distance of the measured contact from its refined face). A residual beyond ``max_residual_mm``
    (the part does not fit the model there: burr, wrong face, probe not calibrated) still makes a new
    revision, with the pose unchanged, the fit kept as ``probe_fit_T_table_obj`` and ``probe_fail``
    set: the result is FAIL (uncertainty check) and neither exported nor probed again until an
    operator adjusts the pose or the setup is located anew. ``probe_deviation_mm`` (per touch, the
    measured face's distance from where the confirmed pose put it) beyond ``probe_expected_mm``
    (3 sigma of the confirmed pose + PROBE_TOLERANCE_MM) also marks the result FAIL, with the refined
    pose kept: the localisation was wrong by more than it stated (adjusting accepts it)."""
    s = get_setup(session, setup_id)
    if s.confirmed_revision is None or s.confirmed_revision != s.result_revision:
        raise Conflict(f"setup {setup_id}: probe results belong to the confirmed revision the program was made "
                       "from; confirm, generate the program, probe, then send the results")
    try:
        tips = parse_probe_results(text)
        touches, params, scene = _touches(session, files, setup_id)
        wp, datum = scene.workpiece, scene.workpiece.datum
        T_table_datum = wp.pose @ datum
        off = (s.result or {}).get("offset") or {}
        if not off:
            raise ValueError("the setup has no workpiece offset, so no program frame")
        machine = get_machine(session, s.machine_id)
        # the log holds tips in the program frame: the datum slot the program ran in
        T_prog_table = program_frame(machine, off)
        ref = refine_offset(touches, tips, T_table_datum, ball_radius_mm=params.ball_radius_mm,
                            T_prog_table=T_prog_table)
    except ValueError as exc:
        raise Invalid(f"probe results: {exc}") from None
    failed = bool(ref.reason) and bool(ref.residuals_mm)  # a fit exists, but the part does not fit it
    if ref.reason and not failed:
        raise Invalid(f"probe results not used: {ref.reason}", code="probe_results_unusable")
    # per touch, how far the measured face lies from where the confirmed pose put it (along its normal)
    tips_table = transform_points(inv(T_prog_table), tips)
    deviation = [float(np.dot(np.asarray(t.normal), tip + [0, 0, params.ball_radius_mm] - np.asarray(t.contact))
                       - params.ball_radius_mm) for t, tip in zip(touches, tips_table)]
    sig = wp.sigma
    expected = 3.0 * max(float(sig.get(k) or 0.0) for k in ("x_mm", "y_mm", "z_mm")) + PROBE_TOLERANCE_MM
    off_by = max(abs(v) for v in deviation)
    beyond = off_by > expected  # the pose was wrong by more than it said: the probe is right, the result FAIL
    T_fit = ref.T_table_datum @ np.linalg.inv(datum)
    worst = float(np.max(np.abs(ref.residuals_mm))) if ref.residuals_mm else 0.0
    result = setup_result(s)
    index = scene.workpiece_result_index
    o = result.objects[index].model_copy(deep=True)
    o.clear_probe_fail()
    o.probed, o.probe_before = True, {"T_table_obj": wp.T_table_obj, "sigma": wp.sigma}
    o.probe_residuals_mm, o.probe_deviation_mm, o.probe_expected_mm = list(ref.residuals_mm), deviation, expected
    if beyond and not failed:
        o.probe_fail = (f"a touch found the part {off_by:.3f} mm from the confirmed pose, beyond its "
                        f"expected error {expected:.3f} mm (3 sigma + {PROBE_TOLERANCE_MM} mm): the "
                        "localisation understated its error; check the setup, adjust to accept")
    if failed:
        o.probe_fail, o.probe_fit_T_table_obj = ref.reason, T_fit.tolist()
        o.flags = [*o.flags, "probing FAIL"]
    else:  # the refined pose (also when it is FAIL for being far from the confirmed one)
        o = o.moved_to(T_fit, sigma={**o.sigma, "x_mm": max(worst, 0.005), "y_mm": max(worst, 0.005),
                                     "z_mm": max(worst, 0.005)},
                       flags=[*o.flags, "refined by probing"])
    what = (f"probing FAIL: {ref.reason}" if failed else
            f"refined by probing, FAIL: {off_by:.3f} mm off > {expected:.3f} mm" if beyond else "refined by probing")
    return revise(session, files, settings, s, result.replace(index, o),
                  note=f"{what} (dx {ref.dx_mm:+.3f}, dy {ref.dy_mm:+.3f}, dz {ref.dz_mm:+.3f} mm, "
                       f"dC {ref.dc_deg:+.4f} deg)", by=by, action="setup.probe_results", object_index=index)
