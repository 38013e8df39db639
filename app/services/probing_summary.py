"""What the probing page shows (issue 18, items 4 and 6): the choices a setup's probing program can be
made with, and the planned program as data (frame, obstacles with their source, touches, travel).

The plan goes through every gate of the program itself (app.services.planning.probing_plan, the frame
read back from a live controller included), so the page offers exactly what the program endpoint
would give, and shows the same refusal (409/422 with a reason code) otherwise. Frames: points in the
table frame (mm) unless a key says ``_prog`` (the program frame: the slot the program runs in).
"""

from __future__ import annotations

import re

import numpy as np
from shapely.geometry import MultiPoint
from sqlmodel import Session, select

from app.geometry.transforms import transform_points
from app.services.planning import (
    CLEARANCE_RANGE_MM,
    DETOURS,
    PROBE_DIALECTS,
    SUBROUTINE_DIALECTS,
    check_detour,
    program_suffix,
    table_xy,
    check_program_params,
    controller_slots,
    probing_plan,
    program_frame,
    setup_scene,
)
from app.services.machines import get_machine
from app.services.setups import get_setup
from app.store.files import FileStore
from app.store.models import Export


def _round(v, nd: int = 4) -> list:
    return np.round(np.asarray(v, dtype=float), nd).tolist()


def _scene_outline(session: Session, files: FileStore, s, machine) -> dict:
    """The table's xy bounds, the located objects from above (hull, top) and the names asked for but
    not located: enough to draw no-go zones on when no program is on offer."""
    located = []
    if s.status == "located" and s.result:
        sc = setup_scene(session, files, s.id)
        for m, T, n in zip(sc.meshes, sc.poses, sc.names):
            V = transform_points(T, m.vertices)
            hull = MultiPoint([tuple(v) for v in V[:, :2]]).convex_hull
            coords = np.asarray(hull.exterior.coords)[:-1] if hull.geom_type == "Polygon" else np.zeros((0, 2))
            located.append({"name": n, "footprint_xy_mm": _round(coords, 2), "top_mm": round(float(V[:, 2].max()), 3)})
    return {"table_xy_mm": list(table_xy(session, files, machine)), "located": located,
            "not_located": [nf["name"] for nf in (s.result or {}).get("not_found") or [] if nf.get("name")]}


def probing_options(session: Session, files: FileStore, setup_id: int) -> dict:
    """The closed sets the program's parameters come from for this setup's machine (dialects, slots,
    clearance range), the slot a verified export of the current revision was written to (the frame
    the program should run in), if any, and the scene's outline (table, located objects from above,
    the names not located)."""
    s = get_setup(session, setup_id)
    machine = get_machine(session, s.machine_id)
    kind = (machine.controller or {}).get("kind")
    # all of them, also for a file controller of another dialect: the plan then says why not (dialect_mismatch)
    dialects = list(PROBE_DIALECTS)
    exported = session.exec(select(Export).where(Export.setup_id == s.id, Export.result_revision == s.result_revision,
                                                 Export.status == "written").order_by(Export.id.desc())).first()
    return {"setup_id": s.id, "machine_id": machine.id, "machine": machine.name, "controller": kind,
            **_scene_outline(session, files, s, machine),
            "dialects": dialects, "slots": list(controller_slots(machine.controller, PROBE_DIALECTS[0])),
            "detours": list(DETOURS), "subroutine_dialects": list(SUBROUTINE_DIALECTS),
            "exported_slot": exported.slot if exported else None,
            "reads_back": kind in ("linuxcnc", "opcua"),
            "clearance_mm": {"min": CLEARANCE_RANGE_MM[0], "max": CLEARANCE_RANGE_MM[1], "default": 5.0}}


def _comment_lines(lines: list[str]) -> list[str]:
    """The program's comment lines in any dialect (HEIDENHAIN block numbers dropped), for the page."""
    out = []
    for ln in lines:
        s = re.sub(r"^\d+ ", "", ln) if re.match(r"^\d+ ;", ln) else ln
        if s.startswith("(") or (s.startswith(";") and not s.startswith(";$")):
            out.append(s)
    return out


def plan_summary(session: Session, files: FileStore, settings, setup_id: int, *, wcs: str, dialect: str,
                 clearance_mm: float, no_go: str | None, detour: str = "straight") -> dict:
    """The program the probing page offers, as data: refusals are raised as by the program endpoint."""

    prog = probing_plan(session, files, settings, setup_id, dry_run=False, wcs=wcs, dialect=dialect,
                        clearance_mm=clearance_mm, no_go=no_go, detour=detour)
    s = get_setup(session, setup_id)
    machine = get_machine(session, s.machine_id)
    d, slot, clearance = check_program_params(machine, dialect=dialect, wcs=wcs, clearance_mm=clearance_mm,
                                              detour=detour)
    t = check_detour(detour)
    T_prog_table = program_frame(machine, s.result["offset"])
    lines = prog.gcode.splitlines()
    params = {"dialect": d, "wcs": slot, "clearance_mm": f"{clearance:g}", **({"no_go": no_go} if no_go else {}),
              **({"detour": t} if t != "straight" else {})}
    return {
        "setup_id": s.id, "result_revision": s.result_revision, "dialect": d, "slot": slot, "clearance_mm": clearance,
        "detour": t, "file_suffix": program_suffix(d),
        "frame": prog.frame,
        "header": _comment_lines(lines[1:])[:40],
        "obstacles": [{"name": o.name, "source": o.source, "top_mm": round(float(o.top_mm), 3),
                       "footprint_xy_mm": _round(o.footprint_xy_mm, 2), "note": o.note} for o in prog.obstacles],
        "touches": [{"name": t.name, "normal": _round(t.normal, 5), "contact_mm": _round(t.contact),
                     "approach_tip_mm": _round(t.approach_tip), "probe_end_tip_mm": _round(t.probe_end_tip),
                     "contact_tip_prog_mm": _round(transform_points(T_prog_table, [t.contact_tip])[0]),
                     "face_normal_datum": _round(t.face_normal_datum, 6), "face_offset_mm": round(t.face_offset_mm, 4)}
                    for t in prog.touches],
        "travel_mm": [_round(p.waypoints, 2) for p in prog.travel],
        "table_xy_mm": list(table_xy(session, files, machine)),
        "program_lines": len(lines),
        "program_query": params,     # the program endpoint's parameters; the web layer makes the URL
    }
