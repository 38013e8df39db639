"""Sheet metal on a cutting bed: align (find the sheet), confirm, export X/Y/C, and monitor drift.

The vision is in :mod:`app.vision.sheet` and :mod:`app.vision.drift` (pure); this module joins it to
the store, the camera sources and the controllers.

Frames: the sheet's offset is found in the bed frame (``T_cam_bed``: origin at a front-left corner of
the slat field, x along the long side, z up, slat tips at z = 0). The machine's ``T_machine_table`` is
taken as ``T_machine_bed``, so the work offset written is ``T_machine_bed @ [Rz(c) | (x, y, thickness)]``
reduced to X, Y and C; the slot's Z is left as the controller has it (height sensing sets it on
laser/plasma machines).

Safety (DESIGN): nothing is written before an operator confirmed that exact alignment; each write is
read back and compared and is on the audit log before and after. A monitor of a confirmed alignment
re-datums (writes a new X, Y, C) when the sheet moved by more than L1 and less than L2: that
confirmation covers those re-datums, never a move of L2 or more, which stops the machine.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

import cv2
import numpy as np
from sqlalchemy.exc import IntegrityError
from sqlmodel import Session, col, select

from app.geometry.transforms import check_pose
from app.geometry.work_offset import sheet_work_offset
from app.machine import ControllerError, WorkOffset, make_controller
from app.services.audit import audit
from app.services.cameras import read_image, get_camera, grab_frame, image_media_type
from app.services.controller_write import check_slot, guarded_write, open_controller, travel_reasons
from app.services.errors import Conflict, Invalid, NotFound, Unavailable
from app.services.jobs import JobRun, Outcome
from app.services.machines import get_machine
from app.sources import SourceError, make_source
from app.store.db import session_scope
from app.store.files import FileStore
from app.store.models import SheetAlignment, SheetBedPose, SheetMonitor, SheetMonitorEvent, utcnow
from app.vision.bed_scale import BedPlane
from app.vision.drift import CORNER_NOT_FOUND, DriftMonitor, FRAME_MISSING, REDATUM, STOP, draw_drift
from app.vision.image_header import ImageHeaderError, image_size
from app.vision.intrinsics import parse_intrinsics
from app.vision.sheet import MAX_MARGIN_MM, draw_sheet, find_sheet

log = logging.getLogger(__name__)

#: decisions published as events (``sheet.ok`` would be one per frame: only logged and stored)
PUBLISHED = ("redatum", "stop", "frame_missing", "corner_not_found")
RECENT = 200  # decisions kept in memory per monitor for the page
DecisionUrl = Callable[[int, int], str]  # (monitor id, decision id) -> the decision's address


# ----------------------------------------------------------------------------------------- bed pose
def _check_bed_pose(T_cam_bed) -> np.ndarray:
    try:
        return check_pose(T_cam_bed, "T_cam_bed", tol=1e-5)
    except (ValueError, TypeError) as exc:
        raise Invalid(str(exc)) from None


def set_bed_pose(session: Session, camera_id: int, T_cam_bed, by: str) -> SheetBedPose:
    get_camera(session, camera_id)
    T = _check_bed_pose(T_cam_bed)
    row = session.get(SheetBedPose, camera_id) or SheetBedPose(camera_id=camera_id, T_cam_bed=[], set_by=by)
    row.T_cam_bed, row.set_by, row.updated_at = T.tolist(), by, utcnow()
    session.add(row)
    session.flush()
    return row


def get_bed_pose(session: Session, camera_id: int) -> SheetBedPose:
    get_camera(session, camera_id)
    row = session.get(SheetBedPose, camera_id)
    if row is None:
        raise NotFound(f"camera {camera_id} has no stored bed pose; PUT one or give T_cam_bed with the request")
    return row


# ----------------------------------------------------------------------------------------- alignment
def _plane(intrinsics: dict, T_cam_bed, thickness_mm: float):
    cam = parse_intrinsics(intrinsics)
    try:  # e.g. the pose puts the camera below the bed: a 422 with the reason, never a 500
        return BedPlane.create(cam.K_array, cam.dist_array, np.asarray(T_cam_bed, float), thickness_mm)
    except ValueError as exc:
        raise Invalid(str(exc)) from None


def _png(img: np.ndarray) -> bytes:
    return cv2.imencode(".png", img)[1].tobytes()


def _jpeg(img: np.ndarray, quality: int = 90) -> bytes:
    return cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])[1].tobytes()


def prepare_alignment(session: Session, files: FileStore, *, machine_id: int, camera_id: int,
                      image: bytes | None, grab: bool, T_cam_bed, thickness_mm: float, margin_mm: float,
                      by: str | None) -> dict:
    """Check the request at once (4xx with the reason; the image's size from its header), grab or take
    the image and store it: the alignment job's arguments. Nothing is decoded here."""
    machine = get_machine(session, machine_id)
    cam = get_camera(session, camera_id)
    if not cam.intrinsics:
        raise Invalid(f"camera {cam.id} ({cam.name}) has no intrinsics; calibrate it first")
    if not 0.0 <= margin_mm <= MAX_MARGIN_MM:
        raise Invalid(f"margin_mm {margin_mm} is outside 0..{MAX_MARGIN_MM:.0f} mm")
    if not 0.0 <= thickness_mm <= 200.0:
        raise Invalid(f"thickness_mm {thickness_mm} is outside 0..200 mm")
    T = _check_bed_pose(T_cam_bed) if T_cam_bed is not None else np.asarray(get_bed_pose(session, cam.id).T_cam_bed)
    if (image is None) == (not grab):
        raise Invalid("give either an image file or grab=true (not both, not neither)")
    data = _jpeg(grab_frame(cam), 95) if grab else image
    try:
        width, height = image_size(data)
    except ImageHeaderError as exc:
        raise Invalid(f"image {exc}") from None
    w, h = cam.intrinsics["width"], cam.intrinsics["height"]
    if (width, height) != (w, h):
        raise Invalid(f"image is {width} x {height} px but camera {cam.id}'s intrinsics are for "
                      f"{w} x {h} px; use the calibration of this camera and resolution")
    _plane(cam.intrinsics, T, thickness_mm)  # a pose that puts the camera below the bed: 422 now
    return {"machine_id": machine.id, "camera_id": cam.id, "T_cam_bed": T.tolist(), "thickness_mm": thickness_mm,
            "margin_mm": margin_mm, "origin": "grab" if grab else "upload", "by": by,
            "image_sha256": files.put(session, data, image_media_type(data))}


def run_alignment_job(run: JobRun, *, machine_id: int, camera_id: int, T_cam_bed: list, thickness_mm: float,
                      margin_mm: float, origin: str, by: str | None, image_sha256: str) -> Outcome:
    """The job: find the sheet in the stored image; the attempt is stored whether found or not."""
    ctx = run.ctx
    with Session(ctx.engine) as session:
        intrinsics = get_camera(session, camera_id).intrinsics
    img = read_image(ctx.files.read(image_sha256), "image")
    result = find_sheet(img, _plane(intrinsics, T_cam_bed, thickness_mm), margin_mm=margin_mm)
    run.check()  # a run that timed out or lost its job stores nothing
    with session_scope(ctx.engine) as session:
        row = SheetAlignment(
            machine_id=machine_id, camera_id=camera_id, intrinsics=intrinsics, T_cam_bed=T_cam_bed,
            thickness_mm=thickness_mm, margin_mm=margin_mm, image_sha256=image_sha256,
            picture_sha256=ctx.files.put(session, _png(draw_sheet(img, result)), "image/png"), origin=origin,
            status="located" if result else "failed", reason="" if result else result.reason,
            result=result.as_dict(), created_by=by)
        session.add(row)
        session.flush()
    log.info("sheet alignment", extra={"alignment_id": row.id, "status": row.status, "reason": row.reason})
    if ctx.events is not None:
        ctx.events.publish("sheet.located" if result else "sheet.failed",
                           {"alignment_id": row.id, "machine_id": machine_id, "camera_id": camera_id,
                            **({"offset": result.offset.as_dict(), "angle_deg": result.angle_deg} if result
                               else {"reason": row.reason})})
    return Outcome(bool(result), row.reason, {"resource": "sheet_alignment", "id": row.id})


def get_alignment(session: Session, alignment_id: int) -> SheetAlignment:
    row = session.get(SheetAlignment, alignment_id)
    if row is None:
        raise NotFound(f"sheet alignment {alignment_id} not found")
    return row


def confirm_alignment(session: Session, events, alignment_id: int, actor: str) -> SheetAlignment:
    row = get_alignment(session, alignment_id)
    if row.status != "located":
        raise Conflict(f"sheet alignment {alignment_id} failed ({row.reason}); there is nothing to confirm")
    if row.confirmed_at is None:
        row.confirmed_by, row.confirmed_at = actor, utcnow()
        session.add(row)
        audit(session, actor, "sheet.confirm", machine_id=row.machine_id, alignment_id=row.id,
              offset=row.result["offset"])
        events.publish("sheet.confirmed", {"alignment_id": row.id, "machine_id": row.machine_id, "by": actor})
    return row


def machine_offset(machine, offset_bed: dict, thickness_mm: float, z_mm: float) -> WorkOffset:
    """X, Y, C of the sheet's work origin in machine coordinates (``T_machine_table`` as ``T_machine_bed``);
    Z is passed through (the controller's current Z)."""
    x, y, c = sheet_work_offset(machine.T_machine_table, offset_bed["x_mm"], offset_bed["y_mm"],
                                offset_bed["c_deg"], thickness_mm)
    return WorkOffset(x, y, z_mm, c)


def write_sheet_offset(session: Session, machine, alignment_id: int, offset_bed: dict, thickness_mm: float,
                       slot: str, actor: str, action: str) -> dict:
    """The guarded write (:func:`app.services.controller_write.guarded_write`) of X/Y/C, Z kept.

    ``action`` is ``sheet.export`` or ``sheet.redatum`` (the audit prefix). Returns {status:
    verified|mismatch|failed, slot, before, written, read_back, reason}; raises Unavailable when the
    controller cannot be read before writing, Conflict (code ``no_offset_yet``) when it holds no offset
    there yet (there is no Z to keep), Invalid when the offset lies outside the machine's travel in X or Y.
    """
    controller = open_controller(machine)
    ids = {"machine_id": machine.id, "alignment_id": alignment_id}
    out: dict = {"slot": slot, "before": None, "written": None, "read_back": None}

    def unreachable(exc: ControllerError) -> None:
        audit(session, actor, f"{action}.read_failed", **ids, slot=slot, reason=str(exc))
        session.commit()

    def target(before: WorkOffset | None, empty: str) -> WorkOffset:
        if before is None:  # the controller answered and holds nothing there: a note with what to do
            raise Conflict(f"{empty}: the sheet alignment keeps the slot's Z, so write a full offset to {slot} "
                           "first (a setup's export, or at the controller); nothing was written",
                           code="no_offset_yet")
        off = machine_offset(machine, offset_bed, thickness_mm, before.z_mm)
        if reasons := travel_reasons(machine, off, "xy"):
            raise Invalid("offset refused: " + "; ".join(reasons))
        out.update(before=before.as_dict(), written=off.as_dict())
        return off

    try:
        verdict = guarded_write(session, controller, slot=slot, actor=actor, action=action, ids=ids,
                                target=target, unreachable=unreachable)
    finally:
        controller.close()
    written = verdict.wanted
    if verdict.status == "written":
        audit(session, actor, f"{action}.verified", **ids, slot=slot, written=written.as_dict(),
              read_back=verdict.read_back.as_dict())
        session.commit()
        return {**out, "read_back": verdict.read_back.as_dict(), "status": "verified", "reason": ""}
    if verdict.differs:
        audit(session, actor, f"{action}.mismatch", **ids, slot=slot, written=written.as_dict(),
              read_back=verdict.read_back.as_dict())
        session.commit()
        return {**out, "read_back": verdict.read_back.as_dict(), "status": "mismatch",
                "reason": f"read-back {verdict.read_back} differs from written {written} beyond the controller's "
                          f"rounding ({controller.rounding_mm} mm, {controller.rounding_deg}°)"}
    why = f"{verdict.error}; {verdict.reason}" if verdict.error is not None else verdict.reason
    audit(session, actor, f"{action}.failed", **ids, slot=slot, reason=why)
    session.commit()
    log.error("sheet offset write failed", extra={"alignment_id": alignment_id, "reason": why})
    return {**out, "read_back": verdict.read_back.as_dict() if verdict.read_back else None, "status": "failed",
            "reason": f"writing {slot} failed: {why}"}


def export_alignment(session: Session, events, alignment_id: int, *, slot: str, actor: str) -> dict:
    """Write a confirmed alignment's X, Y, C to ``slot`` (read back, audit, events)."""
    slot = check_slot(slot)
    row = get_alignment(session, alignment_id)
    if row.status != "located":
        raise Conflict(f"sheet alignment {alignment_id} failed ({row.reason}); there is nothing to export")
    if row.confirmed_at is None:
        raise Conflict(f"sheet alignment {alignment_id} is not confirmed; an operator must confirm it before export")
    machine = get_machine(session, row.machine_id)
    try:
        res = write_sheet_offset(session, machine, row.id, row.result["offset"], row.thickness_mm, slot,
                                 actor, "sheet.export")
    except Unavailable as exc:
        events.publish("offset.export_failed", {"alignment_id": row.id, "slot": slot, "reason": exc.detail})
        raise
    base = {"alignment_id": row.id, "machine_id": machine.id, "slot": slot}
    if res["status"] == "verified":
        events.publish("sheet.offset_exported", {**base, "written": res["written"], "read_back": res["read_back"]})
    else:
        events.publish("offset.export_failed", {**base, "reason": res["reason"]})
        if res["status"] == "failed":
            raise Unavailable(res["reason"])
    return res


# ----------------------------------------------------------------------------------------- monitoring
@dataclass
class _Runtime:
    """A running monitor in this service: the drift state machine, its lock and its poller."""

    monitor_id: int
    drift: object
    lock: threading.Lock = field(default_factory=threading.Lock)
    stop_event: threading.Event = field(default_factory=threading.Event)
    thread: threading.Thread | None = None
    unseen: int = 0  # frames in a row without a usable decision (frame_missing / corner_not_found)
    held: bool = False  # the program was held for them


class SheetMonitors:
    """The monitors running in this service process (``app.state.sheet_monitors``).

    Frames come from a poller thread per monitor (camera source, every ``interval_s``) or are posted
    (batch/test mode); both go through :meth:`process`, one frame at a time per monitor.
    """

    def __init__(self, engine, files: FileStore, events, decision_url: DecisionUrl) -> None:
        self.engine, self.files, self.events = engine, files, events
        self.decision_url = decision_url  # the web layer's address of a decision (for the published events)
        self._runs: dict[int, _Runtime] = {}
        self._lock = threading.Lock()

    def resume(self) -> list[int]:
        """At start-up: the monitors left 'running' by an earlier run of the service carry on from their
        stored drift state (and poll again); one that cannot (its alignment picture or camera source is
        gone) is finished with the reason. Returns the ids resumed."""
        resumed = []
        with Session(self.engine, expire_on_commit=False) as session:
            rows = session.exec(select(SheetMonitor).where(SheetMonitor.state == "running")).all()
            for mon in rows:
                try:
                    align = get_alignment(session, mon.alignment_id)
                    drift = self._drift(align, mon.l1_mm, mon.l2_mm, mon.roi_px)
                    if mon.drift_state:
                        drift.restore(mon.drift_state)
                    cam = get_camera(session, align.camera_id)
                    source = make_source(cam.source) if mon.interval_s is not None else None
                except Exception as exc:  # noqa: BLE001 - whatever broke, the monitor says so and stops
                    mon.state, mon.updated_at = "finished", utcnow()
                    mon.reason = f"could not resume after the service restarted: {exc}"[:2000]
                    session.add(mon)
                    log.warning("sheet monitor not resumed", extra={"monitor_id": mon.id, "reason": mon.reason})
                    continue
                self._run(mon.id, drift, source, mon.interval_s)
                resumed.append(mon.id)
            session.commit()
        if resumed:
            log.info("sheet monitors resumed", extra={"monitor_ids": resumed})
        return resumed

    def _drift(self, align: SheetAlignment, l1_mm: float, l2_mm: float, roi_px: int) -> DriftMonitor:
        """A drift monitor of a located alignment, its start corners confirmed on the alignment's picture."""
        image = read_image(self.files.read(align.image_sha256), "alignment image")
        plane = _plane(align.intrinsics, align.T_cam_bed, align.thickness_mm)
        return DriftMonitor(np.asarray(align.result["corners_px"]), plane, l1_mm, l2_mm, margin_mm=align.margin_mm,
                            roi_px=roi_px, start_frame=image)

    def _run(self, monitor_id: int, drift: DriftMonitor, source, interval_s: float | None) -> _Runtime:
        rt = _Runtime(monitor_id, drift)
        with self._lock:
            self._runs[monitor_id] = rt
        if source is not None:
            rt.thread = threading.Thread(target=self._poll, args=(rt, source, interval_s),
                                         name=f"sheet-monitor-{monitor_id}", daemon=True)
            rt.thread.start()
        return rt

    # ------------------------------------------------------------------ start / stop
    def start(self, session: Session, *, alignment_id: int, l1_mm: float, l2_mm: float, interval_s: float | None,
              slot: str, roi_px: int, actor: str, hold_after_unseen: int | None = None) -> SheetMonitor:
        slot = check_slot(slot)
        row = get_alignment(session, alignment_id)
        if row.status != "located":
            raise Conflict(f"sheet alignment {alignment_id} failed ({row.reason}); nothing to monitor")
        if row.confirmed_at is None:
            raise Conflict(f"sheet alignment {alignment_id} is not confirmed; monitoring re-datums the machine, "
                           "so an operator must confirm the alignment first")
        if not 0.0 < l1_mm < l2_mm:
            raise Invalid(f"thresholds must satisfy 0 < L1 < L2, got L1 = {l1_mm} mm, L2 = {l2_mm} mm")
        if hold_after_unseen is not None and hold_after_unseen < 1:
            raise Invalid(f"hold_after_unseen must be 1 or more frames (or null: never), got {hold_after_unseen}")
        if interval_s is not None and not 0.05 <= interval_s <= 3600:
            raise Invalid(f"interval_s {interval_s} is outside 0.05..3600 s")
        cam = get_camera(session, row.camera_id)
        self._check_camera_free(session, cam)
        source = None
        if interval_s is not None:
            if cam.source.get("kind", "upload") == "upload":
                raise Invalid(f"camera {cam.id} ({cam.name}) has no image source to poll (upload only); "
                              "configure a source or post frames (interval_s = null)")

            source = make_source(cam.source)
        try:
            drift = self._drift(row, l1_mm, l2_mm, roi_px)
        except ValueError as exc:
            raise Invalid(f"monitor not started: {exc}") from None
        mon = SheetMonitor(alignment_id=row.id, camera_id=cam.id, l1_mm=l1_mm, l2_mm=l2_mm, interval_s=interval_s,
                           slot=slot, roi_px=roi_px, hold_after_unseen=hold_after_unseen, created_by=actor)
        session.add(mon)
        try:
            session.flush()
        except IntegrityError:  # another request started one on this camera since the check: the index refused
            session.rollback()
            self._check_camera_free(session, cam)
            raise Conflict(f"another monitor was started on camera {cam.id} ({cam.name}) at the same moment; "
                           "look at GET /api/v1/sheet/monitors?state=running", "camera_monitored") from None
        audit(session, actor, "sheet.monitor_start", machine_id=row.machine_id, alignment_id=row.id,
              monitor_id=mon.id, l1_mm=l1_mm, l2_mm=l2_mm, slot=slot)
        session.commit()
        self._run(mon.id, drift, source, interval_s)
        log.info("sheet monitor started", extra={"monitor_id": mon.id, "alignment_id": row.id})
        return mon

    @staticmethod
    def _check_camera_free(session: Session, cam) -> None:
        """Conflict naming the monitor already running on ``cam``: one camera, one monitor (two would
        re-datum the same machine from the same pictures). The database's unique index over the running
        monitors' cameras holds this across requests and service processes."""
        running = session.exec(select(SheetMonitor).where(SheetMonitor.camera_id == cam.id,
                                                          SheetMonitor.state == "running")).first()
        if running is not None:
            since = running.created_at.strftime("%Y-%m-%d %H:%M UTC") if running.created_at else "earlier"
            raise Conflict(f"camera {cam.id} ({cam.name}) is already watched by monitor {running.id} (alignment "
                           f"{running.alignment_id}, started by {running.created_by or 'unknown'} at {since}); one "
                           f"monitor per camera: stop monitor {running.id} first "
                           f"(POST /api/v1/sheet/monitors/{running.id}/stop)", "camera_monitored")

    def end(self, session: Session, monitor_id: int, actor: str, *, stop_machine: bool = False) -> SheetMonitor:
        """End monitoring (state ``finished`` unless the monitor stopped the machine); optionally abort."""
        mon = get_monitor(session, monitor_id)
        self._drop(monitor_id)  # first: the poller's last frame commits before this session writes
        session.refresh(mon)
        action = None
        if stop_machine:
            machine = get_machine(session, get_alignment(session, mon.alignment_id).machine_id)
            action = _controller_call(machine, "stop")
            audit(session, actor, "sheet.operator_stop", machine_id=machine.id, monitor_id=mon.id, result=action)
        if mon.state == "running":
            mon.state, mon.reason = "finished", f"ended by {actor}"
            if action:
                mon.reason += f"; machine stop: {action}"
            mon.updated_at = utcnow()
            session.add(mon)
        session.commit()
        return mon

    def _drop(self, monitor_id: int) -> _Runtime | None:
        with self._lock:
            rt = self._runs.pop(monitor_id, None)
        if rt is not None:
            rt.stop_event.set()
            if rt.thread is not None and rt.thread is not threading.current_thread():
                rt.thread.join(timeout=10)
        return rt

    def shutdown(self) -> None:
        for mid in list(self._runs):
            self._drop(mid)

    def runtime(self, monitor_id: int) -> _Runtime | None:
        return self._runs.get(monitor_id)

    # ------------------------------------------------------------------ frames
    def _poll(self, rt: _Runtime, source, interval_s: float) -> None:
        while not rt.stop_event.is_set():
            t0 = time.monotonic()
            try:
                frame, why = source.grab(), ""
            except SourceError as exc:
                frame, why = None, f"frame missing: {exc}"
            except Exception as exc:  # noqa: BLE001 - a poller must keep reporting, never die silently
                frame, why = None, f"frame missing: {exc.__class__.__name__}: {exc}"
            if rt.stop_event.is_set():
                return
            try:
                self.process(rt.monitor_id, frame, missing_reason=why)
            except Conflict:
                return  # the monitor ended meanwhile
            except Exception:  # noqa: BLE001
                log.exception("sheet monitor frame failed", extra={"monitor_id": rt.monitor_id})
            rt.stop_event.wait(max(0.0, interval_s - (time.monotonic() - t0)))

    def process(self, monitor_id: int, frame, *, missing_reason: str = "", actor: str = "sheet monitor") -> dict:
        """One frame (BGR ndarray, encoded bytes or None) -> decision, stored, acted on, published."""
        rt = self._runs.get(monitor_id)
        if rt is None:
            with Session(self.engine, expire_on_commit=False) as session:
                mon = get_monitor(session, monitor_id)
            raise Conflict(f"monitor {monitor_id} is {mon.state} ({mon.reason}); it takes no more frames")
        with rt.lock:
            decision = rt.drift.update(frame)
            if decision.decision == FRAME_MISSING and missing_reason:
                decision = dataclasses.replace(decision, reason=missing_reason)
            with Session(self.engine, expire_on_commit=False) as session:
                mon = get_monitor(session, monitor_id)
                align = get_alignment(session, mon.alignment_id)
                machine = get_machine(session, align.machine_id)
                frame_sha = picture_sha = None
                img = None
                if isinstance(frame, np.ndarray):
                    img = frame
                    frame_sha = self.files.put(session, _jpeg(frame), "image/jpeg")
                elif isinstance(frame, (bytes, bytearray)) and frame:
                    frame_sha = self.files.put(session, bytes(frame), image_media_type(bytes(frame)))
                    img = cv2.imdecode(np.frombuffer(bytes(frame), np.uint8), cv2.IMREAD_COLOR)
                if img is not None and decision.decision != "ok":
                    picture_sha = self.files.put(session, _jpeg(draw_drift(img, decision, mon.roi_px)), "image/jpeg")
                action: dict | None = None
                if decision.decision == STOP and mon.state == "running":
                    action = {"stop": _controller_call(machine, "stop")}
                    mon.state, mon.reason = "stopped", decision.reason
                    audit(session, actor, "sheet.stop", machine_id=machine.id, monitor_id=mon.id,
                          alignment_id=align.id, reason=decision.reason, result=action["stop"])
                elif decision.decision == REDATUM:
                    action = self._redatum(session, machine, align, mon, decision.new_offset.as_dict(), actor)
                if decision.decision in (FRAME_MISSING, CORNER_NOT_FOUND):
                    rt.unseen += 1
                    if mon.hold_after_unseen and rt.unseen >= mon.hold_after_unseen and not rt.held:
                        rt.held = True
                        action = {"pause": _controller_call(machine, "pause")}
                        audit(session, actor, "sheet.unseen_hold", machine_id=machine.id, monitor_id=mon.id,
                              frames=rt.unseen, reason=decision.reason, result=action["pause"])
                else:
                    rt.unseen, rt.held = 0, False
                d = decision.as_dict()
                ev = SheetMonitorEvent(monitor_id=mon.id, frame_index=decision.frame_index, decision=decision.decision,
                                       reason=decision.reason, errors_mm=d["errors_mm"], detail={**d, "action": action},
                                       frame_sha256=frame_sha, picture_sha256=picture_sha)
                session.add(ev)
                mon.frames += 1
                mon.drift_state = rt.drift.state()  # in the row: the monitor resumes after a restart
                mon.updated_at = utcnow()
                session.add(mon)
                session.flush()
                item = event_public(ev, self.decision_url)
                mon.last_decision = item
                session.add(mon)
                session.commit()
                state = mon.state
        level = logging.INFO if decision.decision == "ok" else logging.WARNING
        log.log(level, "sheet decision", extra={"monitor_id": monitor_id, "decision": decision.decision,
                                                "reason": decision.reason, "errors_mm": d["errors_mm"]})
        if decision.decision in PUBLISHED:
            self.events.publish(f"sheet.{decision.decision}", {"machine_id": machine.id, "alignment_id": align.id,
                                                               **item})
        if state != "running":
            self._drop(monitor_id)
        return item

    def _redatum(self, session: Session, machine, align, mon, offset_bed: dict, actor: str) -> dict:
        """Write the new X, Y, C; if it cannot be written and verified, hold the program (feed hold)."""
        if not machine.controller:
            return {"redatum": {"status": "not_sent", "reason": f"machine {machine.id} has no controller configured"}}
        try:
            res = write_sheet_offset(session, machine, align.id, offset_bed, align.thickness_mm,
                                     mon.slot, actor, "sheet.redatum")
        except (Unavailable, Invalid) as exc:
            res = {"status": "failed", "reason": exc.detail}
        out = {"redatum": res}
        if res["status"] != "verified":
            out["pause"] = _controller_call(machine, "pause")
            audit(session, actor, "sheet.redatum_pause", machine_id=machine.id, monitor_id=mon.id,
                  reason=res["reason"], result=out["pause"])
        return out


def _controller_call(machine, what: str) -> str:
    """``controller.stop()`` / ``pause()``: "done", or the reason it failed (also logged)."""
    if not machine.controller:
        return f"not sent: machine {machine.id} has no controller configured"
    try:
        controller = make_controller(machine.controller)
    except ValueError as exc:
        return f"not sent: controller settings: {exc}"
    try:
        getattr(controller, what)()
        return "done"
    except ControllerError as exc:
        log.error(f"sheet monitor: controller {what} failed", extra={"machine_id": machine.id, "reason": str(exc)})
        return f"failed: {exc}"
    finally:
        controller.close()


def get_monitor(session: Session, monitor_id: int) -> SheetMonitor:
    mon = session.get(SheetMonitor, monitor_id)
    if mon is None:
        raise NotFound(f"sheet monitor {monitor_id} not found")
    return mon


def list_monitors(session: Session, state: str | None = None, limit: int = 20) -> list[SheetMonitor]:
    q = select(SheetMonitor).order_by(col(SheetMonitor.id).desc()).limit(limit)
    if state:
        q = q.where(SheetMonitor.state == state)
    return list(session.exec(q).all())


def monitor_events(session: Session, monitor_id: int, *, after_id: int = 0, limit: int = RECENT) -> list[SheetMonitorEvent]:
    """Decisions with id > after_id, oldest first (at most ``limit``, the newest ones)."""
    rows = session.exec(select(SheetMonitorEvent).where(SheetMonitorEvent.monitor_id == monitor_id,
                                                       SheetMonitorEvent.id > after_id)
                        .order_by(col(SheetMonitorEvent.id).desc()).limit(limit)).all()
    return list(reversed(rows))


def get_event(session: Session, monitor_id: int, event_id: int) -> SheetMonitorEvent:
    ev = session.get(SheetMonitorEvent, event_id)
    if ev is None or ev.monitor_id != monitor_id:
        raise NotFound(f"monitor {monitor_id} has no decision {event_id}")
    return ev


def event_public(ev: SheetMonitorEvent, decision_url: DecisionUrl) -> dict:
    """A decision as answered and published; its frame and picture at ``decision_url(monitor, decision)``
    + ``/frame`` and ``/picture`` (the web layer's addresses: services build no URLs of their own)."""
    base = decision_url(ev.monitor_id, ev.id)
    return {"id": ev.id, "monitor_id": ev.monitor_id, "frame_index": ev.frame_index, "decision": ev.decision,
            "reason": ev.reason, "errors_mm": ev.errors_mm, "at": ev.at.isoformat(),
            "corners_px": ev.detail.get("corners_px"), "new_offset": ev.detail.get("new_offset"),
            "action": ev.detail.get("action"),
            "frame_url": f"{base}/frame" if ev.frame_sha256 else None,
            "picture_url": f"{base}/picture" if ev.picture_sha256 else None}
