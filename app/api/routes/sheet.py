"""/api/v1/sheet: sheet metal on a cutting bed: align, confirm, export X/Y/C, monitor drift."""

from __future__ import annotations

import asyncio
import json
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, Request, Response, UploadFile, status
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool
from pydantic import BaseModel, Field

from app.api.deps import CurrentPrincipal, FilesDep, OperatorPrincipal, SessionDep, SettingsDep, get_principal, \
    require_admin
from app.api.routes.jobs import JobAccepted, enqueue
from app.api.uploads import check_image, json_form, read_image_upload, read_upload
from app.services import sheet as svc
from app.services.errors import NotFound
from app.services.transaction import transaction

router = APIRouter(prefix="/sheet", tags=["sheet"], dependencies=[Depends(get_principal)])

Pose = list[list[float]]


class BedPoseIn(BaseModel):
    T_cam_bed: Pose = Field(description="4x4 pose of the bed frame in the camera (mm)")


class BedPosePublic(BedPoseIn):
    camera_id: int
    set_by: str
    updated_at: datetime


class AlignmentPublic(BaseModel):
    id: int
    machine_id: int
    camera_id: int
    status: str = Field(description="located | failed")
    reason: str
    thickness_mm: float
    margin_mm: float
    T_cam_bed: Pose
    result: dict | None = Field(description="corners_px, corners_bed_mm (nearest to the bed origin first, CCW "
                                            "from above), angle_deg, origin_bed_mm, offset {x_mm, y_mm, c_deg} "
                                            "(bed frame), side_lengths_mm; or {error, stage}")
    confirmed_by: str | None
    confirmed_at: datetime | None
    created_by: str | None
    created_at: datetime
    image_url: str
    picture_url: str | None


def _alignment(a) -> AlignmentPublic:
    base = f"/api/v1/sheet/alignments/{a.id}"
    return AlignmentPublic(**a.model_dump(exclude={"intrinsics", "image_sha256", "picture_sha256", "origin"}),
                           image_url=f"{base}/image", picture_url=f"{base}/picture" if a.picture_sha256 else None)


class ExportIn(BaseModel):
    slot: str = Field(default="G54", examples=["G54"])


class ExportPublic(BaseModel):
    slot: str
    status: str = Field(description="verified | mismatch")
    before: dict | None
    written: dict | None = Field(description="X, Y (machine, mm), Z kept from the controller, C (deg)")
    read_back: dict | None
    reason: str = ""


class MonitorIn(BaseModel):
    alignment_id: int
    l1_mm: float = Field(gt=0, description="below: nothing; from L1: re-datum")
    l2_mm: float = Field(gt=0, description="from L2: stop the machine")
    interval_s: float | None = Field(default=None, description="poll the camera every interval_s; null: frames "
                                                               "are posted to /monitors/{id}/frames")
    slot: str = Field(default="G54", description="work offset slot the re-datums write")
    roi_px: int = Field(default=100, ge=20, le=1000)
    hold_after_unseen: int | None = Field(default=None, ge=1, description="hold (pause) the program after this "
                                          "many frames in a row without all four corners; null: never")


class MonitorPublic(BaseModel):
    id: int
    alignment_id: int
    camera_id: int | None = Field(description="the alignment's camera: one running monitor each")
    l1_mm: float
    l2_mm: float
    interval_s: float | None
    slot: str
    roi_px: int
    hold_after_unseen: int | None
    state: str = Field(description="running | stopped (by a stop decision) | finished (ended)")
    reason: str
    frames: int
    last_decision: dict | None
    created_by: str | None
    created_at: datetime
    updated_at: datetime
    alignment: AlignmentPublic
    decisions: list[dict] = Field(description="recent decisions, oldest first: decision, reason, errors_mm "
                                              "(per corner), action, frame/picture URLs")


class StopIn(BaseModel):
    stop_machine: bool = Field(default=False, description="also abort the running program")


def _monitor(session, mon, recent: int = 100) -> MonitorPublic:
    # the decisions first, then the row again: a decision and the state it sets are committed together
    # (the poller runs beside this request), so the state read after them is at least as new as the
    # newest decision listed (read the other way round, a "stop" could show beside "running")
    events = svc.monitor_events(session, mon.id, limit=recent)
    session.refresh(mon)
    return MonitorPublic(**mon.model_dump(), alignment=_alignment(svc.get_alignment(session, mon.alignment_id)),
                         decisions=[svc.event_public(e, decision_url) for e in events])


def _stored(session, files, sha: str) -> Response:
    return Response(files.read(sha), media_type=files.media_type(session, sha), headers={"Cache-Control": "max-age=3600"})


def decision_url(monitor_id: int, decision_id: int) -> str:
    """Where a monitor's decision is read (its frame and picture below it)."""
    return f"/api/v1/sheet/monitors/{monitor_id}/decisions/{decision_id}"


# ----------------------------------------------------------------------------------------- bed pose
@router.put("/cameras/{camera_id}/bed-pose", response_model=BedPosePublic,
            summary="Store the bed pose of a camera (used when an alignment gives no T_cam_bed)")
def put_bed_pose(session: SessionDep, camera_id: int, body: BedPoseIn,
                 who: Annotated[object, Depends(require_admin)]) -> BedPosePublic:
    return BedPosePublic(**svc.set_bed_pose(session, camera_id, body.T_cam_bed, who.label()).model_dump())


@router.get("/cameras/{camera_id}/bed-pose", response_model=BedPosePublic, summary="The stored bed pose of a camera")
def get_bed_pose(session: SessionDep, camera_id: int) -> BedPosePublic:
    return BedPosePublic(**svc.get_bed_pose(session, camera_id).model_dump())


# ----------------------------------------------------------------------------------------- alignments
@router.post("/alignments", status_code=status.HTTP_202_ACCEPTED, response_model=JobAccepted,
             summary="Find the sheet (corners, angle, work offset) in an uploaded or grabbed image; a job whose "
                     "result is the alignment",
             responses={422: {"description": "bad image, pose, margin; camera without intrinsics"}})
async def create_alignment(
    request: Request, session: SessionDep, files: FilesDep, settings: SettingsDep, who: CurrentPrincipal,
    machine_id: Annotated[int, Form()],
    camera_id: Annotated[int, Form()],
    thickness_mm: Annotated[float, Form(allow_inf_nan=False, description="sheet thickness; its top is z = thickness in the bed frame")],
    margin_mm: Annotated[float, Form(allow_inf_nan=False, description="work origin inset from corner 0 along both edges, 0..20")] = 0.0,
    T_cam_bed: Annotated[str | None, Form(description="JSON 4x4 (mm); default: the camera's stored bed pose")] = None,
    grab: Annotated[bool, Form(description="grab the image from the camera's source")] = False,
    image: Annotated[UploadFile | None, File(description="JPEG/PNG of the bed")] = None,
) -> JobAccepted:
    data = await read_image_upload(image, settings, "image") if image is not None and image.filename else None
    pose = json_form(T_cam_bed, "T_cam_bed")
    if isinstance(pose, dict):
        pose = pose.get("T_cam_bed")
    args = await run_in_threadpool(
        svc.prepare_alignment, session, files, machine_id=machine_id, camera_id=camera_id, image=data, grab=grab,
        T_cam_bed=pose, thickness_mm=thickness_mm, margin_mm=margin_mm, by=who.label())
    return enqueue(request, session, "sheet_align", args, who.label())


@router.get("/alignments/{alignment_id}", response_model=AlignmentPublic, summary="One sheet alignment")
def get_alignment(session: SessionDep, alignment_id: int) -> AlignmentPublic:
    return _alignment(svc.get_alignment(session, alignment_id))


@router.get("/alignments/{alignment_id}/image", response_class=Response, summary="The image the sheet was found in")
def alignment_image(session: SessionDep, files: FilesDep, alignment_id: int) -> Response:
    return _stored(session, files, svc.get_alignment(session, alignment_id).image_sha256)


@router.get("/alignments/{alignment_id}/picture", response_class=Response,
            summary="The detection picture: edge points, fitted sides, corners, origin")
def alignment_picture(session: SessionDep, files: FilesDep, alignment_id: int) -> Response:
    a = svc.get_alignment(session, alignment_id)
    if not a.picture_sha256:
        raise NotFound(f"sheet alignment {alignment_id} has no picture")
    return Response(files.read(a.picture_sha256), media_type="image/png", headers={"Cache-Control": "max-age=3600"})


@router.post("/alignments/{alignment_id}/confirm", response_model=AlignmentPublic,
             summary="An operator confirms this exact alignment (needed before export and monitoring)")
def confirm_alignment(request: Request, session: SessionDep, alignment_id: int,
                      who: OperatorPrincipal) -> AlignmentPublic:
    return _alignment(svc.confirm_alignment(session, request.app.state.events, alignment_id, who.label()))


@router.post("/alignments/{alignment_id}/export", response_model=ExportPublic,
             summary="Write the confirmed offset X, Y, C to a slot, read it back, audit",
             responses={409: {"description": "not confirmed or failed"}, 502: {"description": "controller failed"}})
def export_alignment(request: Request, session: SessionDep, alignment_id: int, body: ExportIn,
                     who: OperatorPrincipal) -> ExportPublic:
    return ExportPublic(**svc.export_alignment(session, request.app.state.events, alignment_id, slot=body.slot,
                                               actor=who.label()))


# ----------------------------------------------------------------------------------------- monitors
@router.post("/monitors", status_code=status.HTTP_201_CREATED, response_model=MonitorPublic,
             summary="Start drift monitoring of a confirmed alignment (camera polling or posted frames)",
             responses={409: {"description": "the alignment is not confirmed, or its camera already has a running "
                                             "monitor (code camera_monitored; the detail names it)"}})
def start_monitor(request: Request, session: SessionDep, body: MonitorIn, who: OperatorPrincipal) -> MonitorPublic:
    mon = request.app.state.sheet_monitors.start(
        session, alignment_id=body.alignment_id, l1_mm=body.l1_mm, l2_mm=body.l2_mm, interval_s=body.interval_s,
        slot=body.slot, roi_px=body.roi_px, actor=who.label(), hold_after_unseen=body.hold_after_unseen)
    return _monitor(session, mon)


@router.get("/monitors", response_model=list[MonitorPublic], summary="Recent monitors, newest first")
def list_monitors(request: Request, session: SessionDep, state: str | None = None, limit: int = 20) -> list[MonitorPublic]:
    return [_monitor(session, m, recent=1) for m in svc.list_monitors(session, state, max(1, min(limit, 100)))]


@router.get("/monitors/{monitor_id}", response_model=MonitorPublic, summary="State and recent decisions")
def get_monitor(request: Request, session: SessionDep, monitor_id: int, recent: int = 100) -> MonitorPublic:
    return _monitor(session, svc.get_monitor(session, monitor_id), max(1, min(recent, svc.RECENT)))


@router.post("/monitors/{monitor_id}/frames", summary="Feed one frame (batch/test mode); no file = a missing frame",
             responses={409: {"description": "the monitor is stopped or finished"}})
async def post_frame(request: Request, session: SessionDep, settings: SettingsDep, monitor_id: int, who: OperatorPrincipal,
                     frame: Annotated[UploadFile | None, File(description="JPEG/PNG frame")] = None) -> dict:
    data = await read_upload(frame, settings, "frame") if frame is not None else None
    if data:  # never decode an image over the pixel limit; an unreadable frame is the monitor's to judge
        check_image(data, settings, "frame", unreadable_ok=True)
    reg = request.app.state.sheet_monitors
    session.commit()  # the frame is processed in sessions of its own
    return await asyncio.to_thread(reg.process, monitor_id, data or None, actor=who.label())


@router.post("/monitors/{monitor_id}/stop", response_model=MonitorPublic,
             summary="End monitoring (and, with stop_machine, abort the program)")
def stop_monitor(request: Request, session: SessionDep, monitor_id: int, who: OperatorPrincipal,
                 body: StopIn | None = None) -> MonitorPublic:
    mon = request.app.state.sheet_monitors.end(session, monitor_id, who.label(),
                                              stop_machine=bool(body and body.stop_machine))
    return _monitor(session, mon)


@router.get("/monitors/{monitor_id}/decisions/{event_id}/{what}", response_class=Response,
            summary="The frame of a decision (as received) or its picture (ROIs, corners, errors)")
def decision_file(session: SessionDep, files: FilesDep, monitor_id: int, event_id: int, what: str) -> Response:
    ev = svc.get_event(session, monitor_id, event_id)
    sha = {"frame": ev.frame_sha256, "picture": ev.picture_sha256}.get(what)
    if sha is None:
        raise NotFound(f"decision {event_id} has no {what}" if what in ("frame", "picture")
                       else "ask for frame or picture")
    return _stored(session, files, sha)


@router.get("/monitors/{monitor_id}/events", summary="Decisions as server-sent events (one per frame)",
            response_class=StreamingResponse, responses={200: {"content": {"text/event-stream": {}}}})
async def monitor_events(request: Request, monitor_id: int, after: int = 0) -> StreamingResponse:
    """``event: decision`` per frame (after decision id ``after``; 0 = from the first), then ``event: end``
    with the state once the monitor is stopped or finished."""
    engine = request.app.state.engine
    with transaction(engine) as session:
        svc.get_monitor(session, monitor_id)  # 404 before the stream starts

    def fetch(last: int) -> tuple[list[dict], str, str]:
        with transaction(engine) as session:
            mon = svc.get_monitor(session, monitor_id)
            rows = svc.monitor_events(session, monitor_id, after_id=last, limit=1000)
            return [svc.event_public(e, decision_url) for e in rows], mon.state, mon.reason

    async def stream():
        last, idle = after, 0
        while True:
            if await request.is_disconnected():
                return
            items, state, reason = await asyncio.to_thread(fetch, last)
            for it in items:
                last = it["id"]
                yield f"id: {it['id']}\nevent: decision\ndata: {json.dumps(it)}\n\n"
            if state != "running" and not items:
                yield f"event: end\ndata: {json.dumps({'state': state, 'reason': reason})}\n\n"
                return
            idle = 0 if items else idle + 1
            if idle and idle % 150 == 0:
                yield ": keep-alive\n\n"
            await asyncio.sleep(0.1)

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})
