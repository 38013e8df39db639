"""Setup use cases: create (upload or grab), run the localisation job, read status and results.

The maths is in app/vision/localize.py (``localize``); this module stores the capture, runs the job
in a worker, records every stage (numbers, time, picture) on the setup row as it finishes, and keeps
each result revision.
"""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import cv2
import numpy as np
from sqlalchemy import update
from sqlmodel import Session, col, or_, select

from app.geometry.mesh import load_mesh
from app.geometry.transforms import PoseError, check_pose, make_pose, pose_from_xyz_euler
from app.geometry.work_offset import work_offset_from_poses
from app.services import library
from app.services.audit import audit
from app.services.cameras import read_image, get_camera, grab_frame, image_media_type
from app.services.errors import Conflict, Invalid, NotFound
from app.services.jobs import JobContext, JobRun, JobStopped, Outcome, create_job
from app.services.machines import Limit, get_machine, machine_limit, read_table_angle, table_pose_at
from app.services.setup_result import LocatedObject, SetupResult
from app.store.db import session_scope
from app.store.files import FileStore
from app.store.models import Capture, Job, LibraryModel, Setup, utcnow
from app.vision import object_pose
from app.vision.blas_threads import cores_per_job
from app.vision.fiducials import locate_table
from app.vision.image_header import ImageHeaderError, image_size
from app.vision.intrinsics import intrinsics_sigma
from app.vision.localize import (Candidate, draw_pose_overlay, kind_options, localize, marker_labels_table,
                                 object_entry)
from app.vision.photo_model import PhotoModel, View, known_edge_mask, locate_near

log = logging.getLogger(__name__)

FINAL = ("located", "failed")
# a long stage's progress is written at most this often (s): the page's bar moves, the database is not busy
PROGRESS_EVERY_S = 0.5
LOCATED_KINDS = ("workpiece", "clamp", "support")   # what a setup looks for on the table


def png_bytes(image: np.ndarray) -> bytes:
    return cv2.imencode(".png", image)[1].tobytes()


def calibrated_camera(session: Session, machine, camera_id: int | None):
    """The camera to use (given, else the machine's first), which must have intrinsics; 422 with the reason."""
    if camera_id is None:
        if not machine.camera_ids:
            raise Invalid(f"machine {machine.id} has no camera; give camera_id", code="no_camera")
        camera_id = machine.camera_ids[0]
    cam = get_camera(session, camera_id)
    if not cam.intrinsics:
        raise Invalid(f"camera {cam.id} ({cam.name}) has no intrinsics; calibrate it first "
                      f"(POST /api/v1/cameras/{cam.id}/calibrations)", code="camera_not_calibrated")
    return cam


#: a rotary axis angle beyond this is a typing error (100 turns)
MAX_TABLE_ANGLE_DEG = 36_000.0


def table_angle(session: Session, machine, typed_deg: float | None) -> tuple[float | None, str | None]:
    """(degrees, "controller" | "operator") of the machine's rotary axis for a picture taken now; (None, None)
    on a machine whose table does not turn. The operator types it (``typed_deg``) or the service reads the
    controller, as the machine's ``rotary_axis.angle_from`` says; the other way is refused with the reason."""
    axis = machine.rotary_axis
    if not axis:
        if typed_deg is not None:
            raise Invalid(f"table_angle_deg: machine {machine.id} ({machine.name}) has no rotary axis; leave it out",
                          code="no_rotary_axis")
        return None, None
    if axis["angle_from"] == "operator":
        if typed_deg is None:
            raise Invalid(f"table_angle_deg: type the {axis['name']} angle the controller shows (degrees); machine "
                          f"{machine.id} ({machine.name}) takes it from the operator", code="table_angle_required")
        if not (math.isfinite(typed_deg) and abs(typed_deg) <= MAX_TABLE_ANGLE_DEG):
            raise Invalid(f"table_angle_deg: must be a number within ±{MAX_TABLE_ANGLE_DEG:g}°, got {typed_deg}")
        return float(typed_deg), "operator"
    if typed_deg is not None:
        raise Invalid(f"table_angle_deg: machine {machine.id} ({machine.name}) reads the {axis['name']} angle from "
                      "its controller; leave it out", code="table_angle_from_controller")
    return read_table_angle(session, machine.id)[1], "controller"


def create_setup(session: Session, files: FileStore, *, machine_id: int, camera_id: int | None,
                 model_ids: list[int], image: bytes | None, grab: bool, created_by: str | None = None,
                 table_angle_deg: float | None = None) -> Setup:
    """Validate everything a job needs up front (4xx with the reason), store the capture, queue the job.
    On a machine with a rotary table the axis angle at the picture is recorded (typed or read, see
    :func:`table_angle`); it places the table in the 3D view, the offset is computed at the export angle."""
    machine = get_machine(session, machine_id)
    if table_angle_deg is not None and not math.isfinite(table_angle_deg):
        raise Invalid(f"table_angle_deg: must be a finite number, got {table_angle_deg}")
    cam = calibrated_camera(session, machine, camera_id)
    models = []
    for mid in model_ids:
        m = library.get_model(session, mid, include_deleted=False)
        if m.kind not in LOCATED_KINDS:
            raise Invalid(f"model {mid} ({m.name}) is a {m.kind}; only workpieces, clamps and supports are located "
                          "on the table")
        models.append({"model_id": m.id, "revision": m.current_revision})
    if image is not None and grab:
        raise Invalid("give an image or grab=true, not both")
    if image is None and not grab:
        raise Invalid("no image: upload one or set grab=true to take one from the camera")
    typed = bool(machine.rotary_axis) and machine.rotary_axis["angle_from"] == "operator"
    angle = angle_from = None
    if typed:
        angle, angle_from = table_angle(session, machine, table_angle_deg)  # a typing error before a grab
    if grab:
        frame, origin = grab_frame(cam), "grab"
        data = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
        h, w = frame.shape[:2]
    else:  # the size from the header: the decoding is the job's
        origin, data = "upload", image
        try:
            w, h = image_size(data)
        except ImageHeaderError as exc:
            raise Invalid(f"image {exc}") from None
    if (w, h) != (cam.intrinsics["width"], cam.intrinsics["height"]):
        raise Invalid(f"image is {w} x {h} px but camera {cam.id} is calibrated for "
                      f"{cam.intrinsics['width']} x {cam.intrinsics['height']} px", code="image_size_mismatch")
    if not typed:
        angle, angle_from = table_angle(session, machine, table_angle_deg)  # read right after a grab
    cap = Capture(camera_id=cam.id, image_sha256=files.put(session, data, image_media_type(data)), width=w, height=h,
                  origin=origin)
    session.add(cap)
    session.flush()
    setup = Setup(machine_id=machine.id, camera_id=cam.id, capture_id=cap.id, intrinsics=cam.intrinsics,
                  models=models, created_by=created_by, table_angle_deg=angle, table_angle_from=angle_from)
    session.add(setup)
    session.flush()
    return setup


def get_setup(session: Session, setup_id: int) -> Setup:
    s = session.get(Setup, setup_id)
    if s is None:
        raise NotFound(f"setup {setup_id} not found")
    return s


def list_setups(session: Session, *, machine_id: int | None = None, limit: int = 50) -> list[Setup]:
    q = select(Setup)
    if machine_id is not None:
        q = q.where(Setup.machine_id == machine_id)
    return list(session.exec(q.order_by(col(Setup.id).desc()).limit(limit)).all())


def enqueue_orphaned_setups(session: Session, settings) -> list[int]:
    """Setups left queued or running with no job that will run them (made before jobs existed, or their
    job ended without them): a new localisation job each. Returns the new job ids (to hand to the queue)."""
    open_ids = {j.args.get("setup_id") for j in session.exec(
        select(Job).where(Job.kind == "localize", col(Job.status).in_(["queued", "running"]))).all()}
    new = []
    for setup_id in session.exec(select(Setup.id).where(col(Setup.status).in_(["queued", "running"]))).all():
        if setup_id not in open_ids:
            new.append(create_job(session, "localize", {"setup_id": setup_id}, settings).id)
    return new


def fail_setup(ctx: JobContext, args: dict, reason: str) -> None:
    """The setup's job failed without it (timeout, crash, its worker gone too often): say why."""
    with session_scope(ctx.engine) as session:
        s = session.get(Setup, args["setup_id"])
        if s is not None and s.status not in FINAL:
            s.status, s.reason, s.progress, s.updated_at = "failed", reason[:2000], None, utcnow()
            session.add(s)


def requeue_setup(ctx: JobContext, args: dict) -> None:
    """The setup's job went back to the queue (its worker died): the setup waits again, stages cleared."""
    with session_scope(ctx.engine) as session:
        s = session.get(Setup, args["setup_id"])
        if s is not None and s.status not in FINAL:
            s.status, s.stages, s.reason, s.progress, s.updated_at = "queued", [], "", None, utcnow()
            session.add(s)


def _update(ctx: JobContext, setup_id: int, **fields: Any) -> None:
    """Write the job's ``fields`` to its setup while the setup is still open (queued or running), in one
    statement; else raise :class:`JobStopped`. The watchdog may have ended the setup (timeout) between the
    job's last check and this write: the job must then neither reopen it nor give it a result."""
    stmt = (update(Setup).where(Setup.id == setup_id).where(col(Setup.status).not_in(FINAL))
            .values(updated_at=utcnow(), **fields))
    with session_scope(ctx.engine) as session:
        if session.execute(stmt).rowcount != 1:
            raise JobStopped(f"setup {setup_id} ended while its job ran")


def _append_stage(ctx: JobContext, setup_id: int, record: dict) -> None:
    with session_scope(ctx.engine) as session:
        s = session.get(Setup, setup_id)
        if s.status in FINAL:  # ended by the watchdog since the stage's check
            raise JobStopped(f"setup {setup_id} ended while its job ran")
        s.stages = [*s.stages, record]  # reassign: JSON columns track assignment, not mutation
        s.progress = None               # the stage that was in progress is this one, finished
        s.updated_at = utcnow()
        session.add(s)


def library_candidates(session: Session, files: FileStore, model_refs: list[dict], cache: dict | None = None) -> list:
    """Library models to look for: the ones asked for, else every workpiece, clamp and support
    (recognition). Fixtures carry their declared support surfaces (None: derived from the mesh).
    ``cache`` (a worker's :attr:`JobContext.cache`) keeps prepared models by (glb sha256, kind): a
    fixture is prepared standing as modelled only, a workpiece in all its resting states."""
    cache = {} if cache is None else cache
    if not model_refs:
        rows, _ = library.list_models(session, limit=500)
        model_refs = [{"model_id": m.id, "revision": m.current_revision} for m in rows
                      if m.kind in LOCATED_KINDS]
    out = []
    for ref in model_refs:
        m = library.get_model(session, ref["model_id"])
        rev = library.get_revision(session, m.id, ref["revision"])
        # Prepared edge models cost ~1 s each: keep them per geometry file (immutable, content-addressed).
        prepared = cache.get((rev.glb_sha256, m.kind))
        mesh = prepared.mesh if prepared is not None else load_mesh(files.read(rev.glb_sha256), "model.glb", "mm")
        cand = Candidate(name=m.name, mesh=mesh, kind=m.kind, model_id=m.id, revision=rev.revision,
                         T_obj_datum=np.asarray(rev.T_obj_datum) if rev.T_obj_datum else None,
                         support_surfaces=rev.support_surfaces,
                         guide=_guide_for_candidates(session, rev.guide, model_refs),
                         photo=PhotoModel.from_dict(rev.photo) if rev.photo else None)
        if prepared is not None and prepared.name == m.name:
            cand.prepared = prepared
        else:
            cache[(rev.glb_sha256, m.kind)] = cand.prepare()
        out.append(cand)
    return out


def _guide_for_candidates(session: Session, guide: dict | None, model_refs: list[dict]) -> dict | None:
    """A revision's guide with its ``carrier`` (a library key or name) made the carrier's candidate
    name (the model's name): the one the support chain knows it by. A carrier among the models asked
    for wins over another model of the same name; one not in the library stays as written (the
    chain then reports the guided model as not searched)."""
    if not guide:
        return None
    ref = guide["carrier"]
    asked = {int(r["model_id"]) for r in model_refs}
    rows = session.exec(select(LibraryModel).where(or_(LibraryModel.key == ref, LibraryModel.name == ref))).all()
    rows = sorted(rows, key=lambda m: (m.id not in asked, m.deleted_at is not None, m.key != ref, m.id))
    return {**guide, "carrier": rows[0].name} if rows else dict(guide)


def search_threads(settings) -> int:
    """Threads a setup job's plane search may use: ``SETUPCAM_SEARCH_THREADS``, or where that is 0
    the cores this process may run on shared among the jobs it runs at once (``SETUPCAM_WORKERS``):
    one job on a 2-core panel PC gets both, the operator waits a fifth to a third less."""
    return int(settings.search_threads) if settings.search_threads else cores_per_job(settings.workers)


def run_setup_job(run: JobRun, setup_id: int) -> Outcome:
    """The job: localise table and objects in the stored capture; record stages; end located or failed."""
    ctx = run.ctx
    with session_scope(ctx.engine) as session:
        s = get_setup(session, setup_id)
        if s.status in FINAL:
            return Outcome(s.status == "located", s.reason, {"resource": "setup", "id": setup_id})
        machine = get_machine(session, s.machine_id)
        table_rev = library.get_revision(session, machine.table_model_id, machine.table_revision)
        layout = table_rev.fiducials
        capture = session.get(Capture, s.capture_id)
        image = read_image(ctx.files.read(capture.image_sha256))
        recognise = not s.models
        candidates = library_candidates(session, ctx.files, s.models, ctx.cache)
        (table,) = library_candidates(session, ctx.files, [{"model_id": machine.table_model_id,
                                                            "revision": table_rev.revision}], ctx.cache)
        intr = s.intrinsics
    _update(ctx, setup_id, status="running", stages=[], reason="", progress=None)
    log.info("setup running", extra={"setup_id": setup_id, "candidates": len(candidates)})
    written = [0.0]   # when progress was last written (time.monotonic)

    def on_progress(p: object_pose.Progress) -> None:
        run.check()  # a recognition runs 30-60 s: a timed-out job stops within one model, not after all
        now = time.monotonic()
        if p.done < p.total and now - written[0] < PROGRESS_EVERY_S:
            return
        written[0] = now
        _update(ctx, setup_id, progress=p.to_dict())

    def on_stage(stage) -> None:
        run.check()  # timed out or taken over by another worker: stop at this stage
        rec = {"name": stage.name, "ok": stage.ok, "ms": round(stage.ms, 1), "message": stage.message,
               "data": stage.data}
        if stage.image is not None:
            with session_scope(ctx.engine) as session:
                rec["image_sha256"] = ctx.files.put(session, png_bytes(stage.image), "image/png")
        _append_stage(ctx, setup_id, rec)

    try:
        # models asked for: the support chain (fixtures first, the part on their surfaces or over risers);
        # recognition picks among the whole library and keeps the plain search
        result = localize(image, np.asarray(intr["K"]), np.asarray(intr["dist"]), layout, candidates,
                          recognise=recognise, on_stage=on_stage, on_progress=on_progress, table_model=table,
                          chain=not recognise,
                          intrinsics_sigma=intrinsics_sigma(intr), search_threads=search_threads(ctx.settings))
    except JobStopped:
        raise
    except Exception as exc:  # noqa: BLE001 - a crash must end the job as failed, with a reason
        log.exception("setup crashed", extra={"setup_id": setup_id})
        _update(ctx, setup_id, status="failed", progress=None,
                reason=f"internal error in localisation ({exc.__class__.__name__}); it has been logged")
        return Outcome(False, "internal error in localisation", {"resource": "setup", "id": setup_id})
    run.check()  # a run that timed out or lost its job must not write a result
    payload = review_fields(result.to_dict(), machine, ctx.settings)
    with session_scope(ctx.engine) as session:
        payload["overlay_sha256"] = ctx.files.put(session, png_bytes(result.overlay), "image/png")
    if result.ok:
        _update(ctx, setup_id, status="located", result=payload, result_revision=1, progress=None)
    else:
        _update(ctx, setup_id, status="failed", reason=result.reason, result=payload, progress=None)
    if ctx.events is not None:
        ctx.events.publish("setup.located" if result.ok else "setup.failed",
                           {"setup_id": setup_id, "reason": result.reason, "objects": table_obj_summary(payload),
                            "offset": payload.get("offset")})
    log.info("setup finished", extra={"setup_id": setup_id, "ok": result.ok, "reason": result.reason})
    return Outcome(result.ok, result.reason, {"resource": "setup", "id": setup_id})


def table_obj_summary(result: dict) -> list[dict]:
    """Per object: name and T_table_obj (for lists and events)."""
    return [{"name": o["name"], "T_table_obj": o["T_table_obj"]} for o in (result or {}).get("objects", [])]



# ------------------------------------------------------------------------------ review: offset, adjust, confirm
def uncertainty_check(obj: LocatedObject, max_sigma_mm: float, max_sigma_deg: float) -> tuple[bool, str]:
    """Pass/fail of one object's 1-sigma against the tolerances, with the reason when it fails: the
    axes over their tolerance and, where one source makes most of the worst one's variance, which
    (:func:`sigma_source`) and what would help."""
    s = obj.sigma
    worst, over = [], []                       # the reasons; (excess ratio, covariance index) per axis
    for i, k in enumerate(("x_mm", "y_mm", "z_mm")):
        v = s.get(k)
        if v is None or not np.isfinite(v):
            worst.append(f"{k[0]} unknown")
        elif v > max_sigma_mm:
            worst.append(f"{k[0]} ±{v:.3f} mm > {max_sigma_mm} mm")
            over.append((v / max_sigma_mm, i))
    rz = s.get("rz_deg")
    if rz is not None and np.isfinite(rz) and rz > max_sigma_deg:
        worst.append(f"C ±{rz:.3f}° > {max_sigma_deg}°")
        over.append((rz / max_sigma_deg, 5))
    why = "; ".join(worst)
    if over:
        why += sigma_source(obj, max(over)[1])
    return (not worst, why)


# What a sigma too large to pass is mostly made of, and what would make it smaller
SIGMA_SOURCES = {
    "intrinsics": ("the camera's calibration", "if its intrinsics are known better than their stated sigma "
                   "(0.4 % and 3 px where none is stated), state it in the camera; else calibrate it with more views"),
    "table": ("the table's markers", "get more of them into view, spread over the table (and if they were "
              "surveyed better than the layout's placement_sigma says, state it there)"),
    "image": ("the part's own edges in the picture", "a closer, sharper or less hidden view"),
}


def sigma_source(obj: LocatedObject, index: int) -> str:
    """``; mostly <source> (N % of its variance): <advice>`` for the covariance axis ``index`` (0-2 x,
    y, z mm; 5 rz) when one of the result's shares (``cov6_intrinsics``, the rest of ``cov6_table``,
    the rest of ``cov6``: the image fit) makes more than half of it; else ""."""
    extra = obj.model_extra or {}
    try:
        total = float(np.asarray(extra["cov6"], float)[index, index])
        k = float(np.asarray(extra.get("cov6_intrinsics") or np.zeros((6, 6)), float)[index, index])
        frame = float(np.asarray(extra.get("cov6_table") or np.zeros((6, 6)), float)[index, index])
    except (KeyError, TypeError, ValueError, IndexError):
        return ""
    if not (np.isfinite(total) and total > 0):
        return ""
    shares = {"intrinsics": k, "table": frame - k, "image": total - frame}
    name, v = max(shares.items(), key=lambda t: t[1])
    what, advice = SIGMA_SOURCES[name]
    return f"; mostly {what} ({100 * v / total:.0f} % of its variance): {advice}" if v > 0.5 * total else ""


def proposed_offset(result: SetupResult, T_machine_table: list, max_tilt: Limit,
                    rotary_axis: dict | None = None) -> dict | None:
    """The work offset of the first located workpiece: X, Y, Z, C (+ tilt) in machine coordinates, checked
    against ``max_tilt`` (the machine's own or the global limit; a refusal names which). On a machine with a
    ``rotary_axis`` ``T_machine_table`` is the chain at its ``export_at_deg``, the angle the offset is for
    (``axis`` and ``at_axis_deg`` in the answer)."""
    wp = result.workpiece()
    if wp is None:
        return None
    T_machine_table = np.asarray(T_machine_table)
    max_tilt_deg = max_tilt.value
    off = work_offset_from_poses(T_machine_table, wp.pose, wp.datum, max_tilt_deg=max_tilt_deg,
                                 max_tilt_from=max_tilt.source)
    out = {"object": wp.name, "x_mm": off.x_mm, "y_mm": off.y_mm, "z_mm": off.z_mm, "c_deg": off.c_deg,
           "a_deg": off.a_deg, "b_deg": off.b_deg, "tilt_deg": off.tilt_deg, "ok": off.ok, "reason": off.reason,
           "max_tilt_deg": max_tilt_deg, "max_tilt_from": max_tilt.source,
           "T_machine_datum": off.T_machine_datum.tolist(), "datum_defined": bool(wp.T_obj_datum),
           "datum_ambiguous": wp.datum_ambiguous, "datum_note": wp.datum_note or "", "datum_choices": []}
    if rotary_axis:
        out["axis"], out["at_axis_deg"] = rotary_axis["name"], float(rotary_axis["export_at_deg"])
    if wp.datum_undecided():  # the offset each equivalent pose would give: the operator picks one
        for T in wp.datum_candidates():
            o = work_offset_from_poses(T_machine_table, T, wp.datum, max_tilt_deg=max_tilt_deg)
            out["datum_choices"].append({"x_mm": o.x_mm, "y_mm": o.y_mm, "z_mm": o.z_mm, "c_deg": o.c_deg})
    return out


MAX_POSITION_MM = 10_000.0  # no part sits 10 m from the table origin: a pose out there is a typo


def adjustment_check(obj: LocatedObject, max_mm: float, max_deg: float) -> tuple[bool, str]:
    """Is an operator's move still covered by the fit? The 1-sigma describes the pose the fit found
    (``T_table_obj_fit``, table frame); a move of more than 3 sigma, or more than ``max_mm`` / ``max_deg``,
    along any axis leaves it: the object must be refined (fit again from there) before it may pass."""
    if obj.T_table_obj_fit is None:
        return True, ""
    T, F = obj.pose, np.asarray(obj.T_table_obj_fit, float)
    sigma = obj.sigma
    reasons = []
    for i, axis in enumerate("xyz"):
        moved = float(T[i, 3] - F[i, 3])
        s = sigma.get(f"{axis}_mm")
        limit = min(3 * s, max_mm) if s is not None and np.isfinite(s) else max_mm
        if abs(moved) > limit:
            reasons.append(f"moved {moved:+.2f} mm in {axis} from the fitted pose (more than {limit:.2f} mm"
                           f"{' = 3 sigma' if limit < max_mm else ''})")
    R = T[:3, :3] @ F[:3, :3].T  # the turn, in the table frame
    angle = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))
    s_rot = [sigma.get(k) for k in ("rx_deg", "ry_deg", "rz_deg") if sigma.get(k) is not None]
    s_rot = [v for v in s_rot if np.isfinite(v)]
    limit = min(3 * max(s_rot), max_deg) if s_rot else max_deg
    if angle > limit:
        reasons.append(f"turned {angle:.2f}° from the fitted pose (more than {limit:.2f}°"
                       f"{' = 3 sigma' if limit < max_deg else ''})")
    if reasons:
        return False, "; ".join(reasons) + "; refine from here (or locate again) before export"
    return True, ""


def review(result: SetupResult, machine, settings) -> SetupResult:
    """Pass/fail per object and the proposed offset, set on ``result`` (which is returned). An object the
    operator moved away from its fitted pose fails until refined (``adjustment_check``); a probing FAIL
    fails it until an operator adjusts it."""
    for o in result.objects:
        ok, why = uncertainty_check(o, settings.max_sigma_mm, settings.max_sigma_deg)
        moved_ok, moved_why = adjustment_check(o, getattr(settings, "max_adjust_mm", 1.0),
                                               getattr(settings, "max_adjust_deg", 0.5))
        if not moved_ok:
            ok, why = False, "; ".join(w for w in (moved_why, why) if w)
        if o.probe_fail:  # probing showed the part does not sit as this pose says
            ok, why = False, f"probing: {o.probe_fail}"
        o.uncertainty_pass, o.uncertainty_reason = ok, why
    result.offset = proposed_offset(result, table_pose_at(machine), machine_limit(machine, settings, "max_tilt_deg"),
                                    getattr(machine, "rotary_axis", None))
    return result


def review_fields(result: dict, machine, settings) -> dict:
    """:func:`review` of a result as its JSON dict (a fresh localisation, a stored result): the dict back."""
    return review(SetupResult.load(result), machine, settings).dump()


def setup_result(s: Setup) -> SetupResult:
    """The typed result of a setup (empty when it has none yet)."""
    return SetupResult.load(s.result)


def captured_image(session: Session, files: FileStore, setup_id: int) -> tuple[bytes, str]:
    """(bytes, media type as stored) of the image a setup was located in."""
    sha = session.get(Capture, get_setup(session, setup_id).capture_id).image_sha256
    return files.read(sha), files.media_type(session, sha)


def picture_sha256(session: Session, s: Setup) -> str:
    """The setup's picture to show: the overlay of its current result, else the image as taken."""
    return (s.result or {}).get("overlay_sha256") or session.get(Capture, s.capture_id).image_sha256


def revise(session: Session, files: FileStore, settings, s: Setup, result: SetupResult, *, note: str,
           by: str | None, action: str, object_index: int, audited: LocatedObject | None = None,
           **detail: Any) -> Setup:
    """The one way a located setup's result changes: every object's ``T_cam_obj`` set from its
    ``T_table_obj``, the review (pass/fail, proposed offset), the overlay redrawn at the new poses, the
    old revision kept in the history, revision n+1 (never confirmed: it must be confirmed again before
    export), and ``action`` on the audit log with ``detail`` and the revised object's (``object_index``,
    or ``audited`` when it is no longer in the result) pose and review."""
    result.place()
    review(result, get_machine(session, s.machine_id), settings)
    result.overlay_sha256 = _redraw(session, files, s, result)
    result.note, result.revised_by = note, by
    s.history = [*s.history, {"revision": s.result_revision, "result": s.result}]
    s.result = result.dump()
    s.result_revision += 1
    s.updated_at = utcnow()
    session.add(s)
    session.flush()
    obj = audited if audited is not None else result.objects[object_index]
    audit(session, by or "?", action, setup_id=s.id, machine_id=s.machine_id, result_revision=s.result_revision,
          object_index=object_index, T_table_obj=obj.T_table_obj, uncertainty_pass=obj.uncertainty_pass,
          reason=obj.uncertainty_reason, **detail)
    return s


def _require_located(s: Setup) -> None:
    if s.status != "located" or not s.result:
        raise Invalid(f"setup {s.id} is {s.status}; only a located setup can be adjusted or confirmed")


def _located_object(session: Session, setup_id: int, object_index: int) -> tuple[Setup, SetupResult, LocatedObject]:
    """A located setup, its typed result and the object at ``object_index`` (checked against them)."""
    s = get_setup(session, setup_id)
    _require_located(s)
    result = setup_result(s)
    if not 0 <= object_index < len(result.objects):
        raise Invalid(f"object_index {object_index} out of range: setup {setup_id} has {len(result.objects)} objects")
    return s, result, result.objects[object_index]


def adjust_object(session: Session, files: FileStore, settings, setup_id: int, *, object_index: int,
                  T_table_obj: list | None = None, nudge: dict | None = None, by: str | None = None) -> Setup:
    """Operator adjustment: a new pose (or a nudge in table x/y/z mm and C deg) -> result revision n+1."""
    s, result, before = _located_object(session, setup_id, object_index)
    old = before.pose
    if (T_table_obj is None) == (nudge is None):
        raise Invalid("give either T_table_obj or nudge")
    if nudge is not None:
        d = {k: float(nudge.get(k, 0.0)) for k in ("dx_mm", "dy_mm", "dz_mm", "dc_deg")}
        if max(abs(d["dx_mm"]), abs(d["dy_mm"]), abs(d["dz_mm"])) > 50 or abs(d["dc_deg"]) > 30:
            raise Invalid("nudge too large: at most 50 mm and 30° per step")
        centre = old[:3, 3]
        # Rotate about the object's own origin around table z, then shift along table axes.
        R = pose_from_xyz_euler(c_deg=d["dc_deg"])
        new = make_pose(t=centre + [d["dx_mm"], d["dy_mm"], d["dz_mm"]]) @ R @ make_pose(t=-centre) @ old
    else:
        try:
            new = check_pose(T_table_obj, "T_table_obj", tol=1e-5)
        except PoseError as exc:
            raise Invalid(str(exc)) from None
    if np.max(np.abs(new[:3, 3])) > MAX_POSITION_MM:
        raise Invalid(f"T_table_obj: position {np.round(new[:3, 3], 1).tolist()} mm is more than "
                      f"{MAX_POSITION_MM / 1000:.0f} m from the table origin")
    # the pose the fit found stays on record: the move away from it is what adjustment_check judges
    fitted = before.T_table_obj_fit or before.T_table_obj
    obj = before.moved_to(new, T_table_obj_fit=fitted, adjusted=True, score=None,
                          flags=[*before.flags, "adjusted by operator"])
    obj.clear_probe_fail()  # a probing FAIL judged the old pose; the operator's pose is judged anew
    result = result.replace(object_index, obj)
    return revise(session, files, settings, s, result, note="adjusted", by=by, action="setup.adjust",
                  object_index=object_index, nudge=nudge)


def _redraw(session: Session, files: FileStore, s: Setup, result: SetupResult) -> str:
    """Overlay for a revised result: table markers from the stored table stage, objects at their poses."""
    table_pic = next((st.get("image_sha256") for st in s.stages if st["name"] == "table markers"), None)
    sha = table_pic or session.get(Capture, s.capture_id).image_sha256
    base = cv2.imdecode(np.frombuffer(files.read(sha), np.uint8), cv2.IMREAD_COLOR)
    cands = {(c.model_id, c.revision): c for c in library_candidates(session, files, [
        {"model_id": o.model_id, "revision": o.revision} for o in result.objects if o.model_id])}
    K, dist = np.asarray(s.intrinsics["K"]), np.asarray(s.intrinsics["dist"])
    pic = draw_pose_overlay(base, K, dist, result.dump(), cands)
    return files.put(session, png_bytes(pic), "image/png")


def choose_datum(session: Session, files: FileStore, settings, setup_id: int, *, object_index: int,
                 choice: int, by: str | None = None) -> Setup:
    """The operator says which of the equivalent poses is meant (0 = the pose as located) -> revision n+1."""
    s, result, obj = _located_object(session, setup_id, object_index)
    cands = obj.datum_candidates()
    if len(cands) < 2:
        raise Invalid(f"{obj.name} has no equivalent poses to choose from")
    if not 0 <= choice < len(cands):
        raise Invalid(f"choice {choice} out of range: {obj.name} has {len(cands)} equivalent poses (0..{len(cands) - 1})")
    entry = obj.moved_to(
        cands[choice], equivalent_poses=[c.tolist() for i, c in enumerate(cands) if i != choice],
        datum_ambiguous=False,
        datum_note=f"datum chosen by {by or 'the operator'}: pose {choice + 1} of {len(cands)} "
                   f"(the image could not decide: {obj.datum_note})",
        flags=[f for f in obj.flags if f != "datum_ambiguous"] + ["datum chosen by operator"])
    if choice > 0:  # an equivalent pose of the fit is a fitted pose (the image fits it as well): nothing moved
        entry.T_table_obj_fit = None
        entry.model_fields_set.discard("T_table_obj_fit")
    return revise(session, files, settings, s, result.replace(object_index, entry),
                  note=f"datum chosen: pose {choice + 1} of {len(cands)}", by=by, action="setup.datum",
                  object_index=object_index, choice=choice)


def dismiss_object(session: Session, files: FileStore, settings, setup_id: int, *, object_index: int,
                   by: str | None = None) -> Setup:
    """The operator says a located workpiece is not there (recognition took something else for a
    library part) -> revision n+1 without it; the offset is then the next workpiece's. The dismissed
    object stays in the history and on the audit log. Clamps and fixtures are not dismissed (the
    probing paths avoid them), nor the last workpiece (there would be no offset to propose: locate
    again with the part named)."""
    s, result, obj = _located_object(session, setup_id, object_index)
    if obj.kind != "workpiece":
        raise Invalid(f"{obj.name} is a {obj.kind}: only a workpiece can be dismissed (clamps and fixtures "
                      "stay in the result so that the probing paths avoid them)")
    if sum(o.kind == "workpiece" for o in result.objects) < 2:
        raise Invalid(f"{obj.name} is the only workpiece located: if it is not on the table, start a new setup "
                      "with the right part named")
    return revise(session, files, settings, s, result.without(object_index),
                  note=f"{obj.name} dismissed: not on the table", by=by, action="setup.dismiss",
                  object_index=object_index, audited=obj, name=obj.name)


def confirm_setup(session: Session, setup_id: int, *, result_revision: int, by: str, events=None) -> Setup:
    """Record who confirmed which exact result revision, and when. Only that revision may be exported.
    Refused while a workpiece's datum is undecided (never chosen silently). With ``events`` the
    confirmation is committed, then published as ``setup.confirmed``."""
    s = get_setup(session, setup_id)
    _require_located(s)
    if result_revision != s.result_revision:
        raise Conflict(f"result revision {result_revision} is not the current one ({s.result_revision}); "
                       "reload the setup and confirm what you see")
    for o in setup_result(s).objects:
        if o.kind == "workpiece" and o.datum_undecided():
            raise Conflict(f"the datum of {o.name} is not decided: {len(o.datum_candidates())} poses look the "
                           f"same in this image; choose which one is meant, then confirm")
    s.confirmed_revision, s.confirmed_by, s.confirmed_at = result_revision, by, utcnow()
    s.updated_at = utcnow()
    session.add(s)
    session.flush()
    audit(session, by, "setup.confirm", setup_id=s.id, machine_id=s.machine_id, result_revision=result_revision,
          offset=(s.result or {}).get("offset"))
    if events is not None:
        session.commit()  # subscribers read the confirmed setup
        events.publish("setup.confirmed", {"setup_id": s.id, "result_revision": s.confirmed_revision,
                                           "by": s.confirmed_by, "offset": (s.result or {}).get("offset")})
    return s


def refine_object(session: Session, files: FileStore, settings, setup_id: int, *, object_index: int,
                  by: str | None = None) -> Setup:
    """"Refine from here": the edge fit started at the object's current (e.g. adjusted) pose -> revision n+1."""
    s, result, obj = _located_object(session, setup_id, object_index)
    if not obj.model_id:
        raise Invalid(f"object {obj.name} has no library model to refine against")
    (cand,) = library_candidates(session, files, [{"model_id": obj.model_id, "revision": obj.revision}])
    cand.name = obj.name
    image = read_image(files.read(session.get(Capture, s.capture_id).image_sha256))
    K, dist = np.asarray(s.intrinsics["K"]), np.asarray(s.intrinsics["dist"])
    machine = get_machine(session, s.machine_id)
    (table,) = library_candidates(session, files, [{"model_id": machine.table_model_id,
                                                    "revision": machine.table_revision}])
    layout = library.get_revision(session, machine.table_model_id, machine.table_revision).fiducials
    # the table pose's covariance (the stored result keeps its sigmas only): the markers again
    tp = locate_table(image, K, dist, layout or {}, intrinsics_sigma=intrinsics_sigma(s.intrinsics)) if layout else None
    if cand.photo is not None:      # a photo model: its search, near the operator's pose
        ign = known_edge_mask(image.shape[:2], K, dist, result.T_cam_table, [(table.prepare(), np.eye(4))],
                              marker_labels_table(layout or {}))
        view = View(image, K, dist, result.T_cam_table, ign, *((tp.covariance, tp.centroid_table_mm) if tp else ()))
        pose = locate_near(view, cand.photo, cand.name, obj.pose)
    else:
        pose = object_pose.locate_object(image, K, dist, result.T_cam_table, cand.prepare(),
                                         start_poses=[obj.pose],
                                         table_covariance=tp.frame_error() if tp else None,
                                         known_models=((table.prepare(), np.eye(4)),),
                                         known_regions=marker_labels_table(layout or {}),
                                         **kind_options(cand.kind), **({"gamma": tp.gamma} if tp else {}))
    if not pose:
        raise Invalid(f"refinement from this pose failed: {pose.reason}; nudge the part closer to where "
                      "it is in the picture and try again")
    entry = LocatedObject.model_validate(object_entry(cand, pose, tuple(getattr(obj, "colour_bgr", None)
                                                                        or (0, 220, 0))))
    entry.flags = [*entry.flags, "refined from the operator's pose"]
    return revise(session, files, settings, s, result.replace(object_index, entry),
                  note="refined from the operator's pose", by=by, action="setup.refine", object_index=object_index)
