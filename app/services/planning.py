"""Planning use cases: safe travel paths (plain requests or a located setup's scene) and probing programs.

The maths is in app/planning/; this module only gathers the located scene (meshes at T_table_obj,
inflated by their uncertainty) from a setup and turns planner errors into 422 answers.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sqlmodel import Session

from app.services.errors import Conflict, Invalid
from app.services.setups import _candidates, get_setup
from app.store.files import FileStore


def setup_scene(session: Session, files: FileStore, setup_id: int) -> tuple[list, list, list, float, dict]:
    """(meshes, T_table_obj poses, names, largest 1-sigma in mm, workpiece entry) of a located setup."""
    s = get_setup(session, setup_id)
    if s.status != "located" or not s.result:
        raise Invalid(f"setup {setup_id} is {s.status}; paths need a located setup")
    objs = [o for o in s.result.get("objects", []) if o.get("model_id")]
    cands = {(c.model_id, c.revision): c for c in _candidates(
        session, files, [{"model_id": o["model_id"], "revision": o["revision"]} for o in objs])}
    meshes, poses, names, sig = [], [], [], 0.0
    for o in objs:
        meshes.append(cands[(o["model_id"], o["revision"])].mesh)
        poses.append(np.asarray(o["T_table_obj"]))
        names.append(o["name"])
        s_xyz = [v for k, v in (o.get("sigma") or {}).items() if k.endswith("_mm") and v is not None]
        sig = max([sig, *s_xyz])
    wp = next((o for o in objs if o.get("kind") == "workpiece"), None)
    return meshes, poses, names, sig, wp


def plan(session: Session, files: FileStore, request: dict[str, Any]) -> dict:
    """Plan a path for a REST request; ``obstacles: {"setup_id": n}`` uses that setup's located scene."""
    from app.planning.request import plan_request

    req = dict(request)
    ob = req.get("obstacles")
    if isinstance(ob, dict) and "meshes" in ob:
        raise Invalid("obstacles.meshes with file paths is for the CLI; over REST give setup_id, regions, "
                      "part_top_mm or per_move_mm")
    if isinstance(ob, dict) and "setup_id" in ob:
        meshes, poses, names, sig, _ = setup_scene(session, files, int(ob["setup_id"]))
        if not meshes:
            raise Invalid(f"setup {ob['setup_id']} has no located objects to plan around")
        req["obstacles"] = {"meshes": [{"mesh": m, "T_table_obj": p.tolist(), "name": n}
                                       for m, p, n in zip(meshes, poses, names)],
                            "uncertainty_mm": float(ob.get("uncertainty_mm", 3.0 * sig))}
    try:
        return plan_request(req)
    except ValueError as exc:
        raise Invalid(str(exc)) from None


def probing_program(session: Session, files: FileStore, setup_id: int, *, dry_run: bool,
                    wcs: str = "G54") -> str:
    """LinuxCNC probing program for the confirmed workpiece of a setup (table frame as program frame)."""
    return probing_plan(session, files, setup_id, dry_run=dry_run, wcs=wcs).gcode


def probing_plan(session: Session, files: FileStore, setup_id: int, *, dry_run: bool = True,
                 wcs: str = "G54"):
    """The probing program with its touches and safe travel paths (table frame, mm): ProbingProgram."""
    from app.planning.obstacles import height_grid_from_meshes
    from app.planning.path import ProbeParams
    from app.planning.probing import ProbingParams, choose_touch_points, probing_gcode

    s = get_setup(session, setup_id)
    if s.confirmed_revision is None or s.confirmed_revision != s.result_revision:
        raise Conflict(f"setup {setup_id} is not confirmed in its current revision; confirm it before probing")
    meshes, poses, names, sig, wp = setup_scene(session, files, setup_id)
    if wp is None:
        raise Invalid(f"setup {setup_id} has no located workpiece to probe")
    i = names.index(wp["name"])
    datum = np.asarray(wp["T_obj_datum"]) if wp.get("T_obj_datum") else np.eye(4)
    params = ProbingParams()
    travel = ProbeParams(working_distance_mm=0.0, clearance_mm=5.0, radius_mm=15.0, length_mm=80.0)
    try:
        touches = choose_touch_points(meshes[i], poses[i], datum, params)
        grid = height_grid_from_meshes(meshes, poses, uncertainty_mm=3.0 * sig)
        top = max(float((m.bounds[1][2] + p[2, 3])) for m, p in zip(meshes, poses))
        centre = poses[i][:3, 3]
        program = probing_gcode(touches, grid, travel, (centre[0], centre[1], top + 50.0), params=params,
                                dry_run=dry_run, wcs=wcs, title=f"setupcam probing, setup {setup_id}")
    except ValueError as exc:
        raise Invalid(f"probing program: {exc}") from None
    return program


def _touches(session: Session, files: FileStore, setup_id: int):
    from app.planning.probing import ProbingParams, choose_touch_points

    meshes, poses, names, sig, wp = setup_scene(session, files, setup_id)
    if wp is None:
        raise Invalid(f"setup {setup_id} has no located workpiece to probe")
    i = names.index(wp["name"])
    datum = np.asarray(wp["T_obj_datum"]) if wp.get("T_obj_datum") else np.eye(4)
    params = ProbingParams()
    return choose_touch_points(meshes[i], poses[i], datum, params), params, wp, datum


def apply_probe_results(session: Session, files: FileStore, settings, setup_id: int, text: str,
                        by: str | None) -> Any:
    """Refine the confirmed workpiece pose from the probing program's results (least squares) and make
    it a new result revision; it must be confirmed again before export (the usual safety gate)."""
    from app.planning.probing import parse_probe_results, refine_offset
    from app.services.machines import get_machine
    from app.services.setups import _new_revision, review_fields

    s = get_setup(session, setup_id)
    if s.confirmed_revision is None or s.confirmed_revision != s.result_revision:
        raise Conflict(f"setup {setup_id}: probe results belong to the confirmed revision the program was made "
                       "from; confirm, generate the program, probe, then send the results")
    try:
        tips = parse_probe_results(text)
        touches, params, wp, datum = _touches(session, files, setup_id)
        T_table_datum = np.asarray(wp["T_table_obj"]) @ datum
        ref = refine_offset(touches, tips, T_table_datum, ball_radius_mm=params.ball_radius_mm)
    except ValueError as exc:
        raise Invalid(f"probe results: {exc}") from None
    if ref.reason:
        raise Invalid(f"probe results not used: {ref.reason}")
    T_table_obj = ref.T_table_datum @ np.linalg.inv(datum)
    T_cam_table = np.asarray(s.result["table"]["T_cam_table"])
    worst = float(np.max(np.abs(ref.residuals_mm))) if ref.residuals_mm else 0.0
    objs = []
    for o in s.result["objects"]:
        if o is wp or o["name"] == wp["name"]:
            o = {**o, "T_table_obj": T_table_obj.tolist(), "T_cam_obj": (T_cam_table @ T_table_obj).tolist(),
                 "probed": True, "probe_residuals_mm": list(ref.residuals_mm),
                 "sigma": {**(o.get("sigma") or {}), "x_mm": max(worst, 0.005), "y_mm": max(worst, 0.005),
                           "z_mm": max(worst, 0.005)},
                 "flags": [*o.get("flags", []), "refined by probing"]}
        objs.append(o)
    result = review_fields({**s.result, "objects": objs}, get_machine(session, s.machine_id), settings)
    _new_revision(s, result, f"refined by probing (dx {ref.dx_mm:+.3f}, dy {ref.dy_mm:+.3f}, dz {ref.dz_mm:+.3f} mm, "
                             f"dC {ref.dc_deg:+.4f} deg)", by)
    session.add(s)
    session.flush()
    return s
