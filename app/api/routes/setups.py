"""/api/v1/setups: one image -> located table and objects -> (later) confirm and export."""

from __future__ import annotations

import asyncio
import json
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, Header, Query, Request, Response, UploadFile, status
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, Field

from starlette.concurrency import run_in_threadpool

from app.api.deps import CurrentPrincipal, FilesDep, OperatorPrincipal, SessionDep, SettingsDep, get_principal
from app.api.routes.jobs import enqueue
from app.api.uploads import read_image_upload
from app.services import export as export_svc
from app.services import setups as svc
from app.services.audit import export_refusals
from app.services.errors import Invalid, NotFound
from app.services.transaction import transaction

router = APIRouter(prefix="/setups", tags=["setups"], dependencies=[Depends(get_principal)])


class SetupAccepted(BaseModel):
    id: int
    status: str
    url: str
    events_url: str
    job_id: int = Field(description="The localisation job (GET job_url: attempts, worker, timeout)")
    job_url: str


class SetupPublic(BaseModel):
    id: int
    machine_id: int
    camera_id: int | None
    capture_id: int
    models: list[dict] = Field(description="[{model_id, revision}] asked for; empty means recognition")
    status: str = Field(description="queued | running | located | failed")
    reason: str = Field(description="Why it failed, in plain words (empty otherwise)")
    stages: list[dict] = Field(description="Per stage: name, ok, ms, message, data, image_url")
    progress: dict | None = Field(default=None, description="While a long stage runs (recognition over the "
                                  "library): {stage, done, total, message}; null otherwise")
    result: dict | None = Field(description="table (T_cam_table, markers used/rejected, rms_px) and objects "
                                            "(T_cam_obj, T_table_obj, score, uncertainty, ...), mm and degrees")
    result_revision: int
    table_angle_deg: float | None = Field(default=None, description="a machine with a rotary table: the axis "
                                         "angle when the picture was taken, degrees (the offset is for the "
                                         "machine's export angle, result.offset.at_axis_deg)")
    table_angle_from: str | None = Field(default=None, description="where that angle came from: controller | operator")
    confirmed_revision: int | None
    confirmed_by: str | None
    confirmed_at: datetime | None
    created_at: datetime
    updated_at: datetime
    image_url: str
    overlay_url: str | None


def to_public(s) -> SetupPublic:
    stages = [{**st, "image_url": f"/api/v1/setups/{s.id}/stages/{i}.png" if st.get("image_sha256") else None}
              for i, st in enumerate(s.stages)]
    has_overlay = bool(s.result and s.result.get("overlay_sha256"))
    return SetupPublic(**s.model_dump(exclude={"stages"}), stages=stages, image_url=f"/api/v1/setups/{s.id}/image",
                       overlay_url=f"/api/v1/setups/{s.id}/overlay.png" if has_overlay else None)


def _parse_ids(text: str | None) -> list[int]:
    if not text:
        return []
    try:
        return [int(x) for x in text.replace(" ", "").split(",") if x]
    except ValueError:
        raise Invalid(f"model_ids: give comma-separated integers, got {text!r}") from None


@router.post("", status_code=status.HTTP_202_ACCEPTED, response_model=SetupAccepted,
             summary="Start a setup from an uploaded image or a frame grabbed from the camera",
             responses={422: {"description": "unknown machine/camera/model, camera without intrinsics, bad image"}})
async def create_setup(
    request: Request, session: SessionDep, files: FilesDep, settings: SettingsDep, who: CurrentPrincipal,
    machine_id: Annotated[int, Form(examples=[1])],
    camera_id: Annotated[int | None, Form(description="Default: the machine's first camera")] = None,
    model_ids: Annotated[str | None, Form(description="Comma-separated library model ids; empty = recognise",
                                          examples=["3,5"])] = None,
    grab: Annotated[bool, Form(description="Grab the image from the camera's source")] = False,
    image: Annotated[UploadFile | None, File(description="JPEG/PNG of table and workpiece")] = None,
    table_angle_deg: Annotated[float | None, Form(
        description="A machine with a rotary table whose angle the operator types: the axis angle (degrees, as "
                    "the controller shows it) at which the picture was taken; leave it out otherwise")] = None,
) -> SetupAccepted:
    data = await read_image_upload(image, settings, "image") if image is not None and image.filename else None
    # checks, storing the image and a camera grab (I/O) off the event loop; the localisation is the job's
    setup = await run_in_threadpool(svc.create_setup, session, files, machine_id=machine_id, camera_id=camera_id,
                                    model_ids=_parse_ids(model_ids), image=data, grab=grab, created_by=who.label(),
                                    table_angle_deg=table_angle_deg)
    job = enqueue(request, session, "localize", {"setup_id": setup.id}, who.label())
    return SetupAccepted(id=setup.id, status=setup.status, url=f"/api/v1/setups/{setup.id}",
                         events_url=f"/api/v1/setups/{setup.id}/events", job_id=job.job_id, job_url=job.job_url)


@router.get("", response_model=list[SetupPublic], summary="Recent setups (optionally of one machine)")
def list_setups(session: SessionDep, machine_id: int | None = None,
                limit: Annotated[int, Query(ge=1, le=500)] = 50) -> list[SetupPublic]:
    return [to_public(s) for s in svc.list_setups(session, machine_id=machine_id, limit=limit)]


@router.get("/{setup_id}", response_model=SetupPublic, summary="Status and result of a setup")
def get_setup(session: SessionDep, setup_id: int) -> SetupPublic:
    return to_public(svc.get_setup(session, setup_id))


@router.get("/{setup_id}/events", summary="Progress as server-sent events (stage, progress, status)",
            response_class=StreamingResponse, responses={200: {"content": {"text/event-stream": {}}}})
async def setup_events(request: Request, setup_id: int) -> StreamingResponse:
    engine = request.app.state.engine
    with transaction(engine) as session:
        svc.get_setup(session, setup_id)  # 404 before the stream starts

    def snapshot() -> tuple[str, list[dict], str, dict | None]:
        with transaction(engine) as session:
            s = svc.get_setup(session, setup_id)
            return s.status, list(s.stages), s.reason, s.progress

    async def stream():
        sent_stages, last_status, last_progress = 0, None, None
        for _ in range(20 * 60 * 10):  # at most 10 minutes, then the client reconnects
            if await request.is_disconnected():
                return
            st, stages, reason, progress = await asyncio.to_thread(snapshot)
            for i in range(sent_stages, len(stages)):
                stage = {k: v for k, v in stages[i].items() if k != "data"}
                yield f"event: stage\ndata: {json.dumps({'index': i, **stage})}\n\n"
            sent_stages = len(stages)
            if progress and progress != last_progress:   # the stage after the last one sent, under way
                yield f"event: progress\ndata: {json.dumps({'index': sent_stages, **progress})}\n\n"
            last_progress = progress
            if st != last_status:
                yield f"event: status\ndata: {json.dumps({'status': st, 'reason': reason})}\n\n"
                last_status = st
            if st in svc.FINAL:
                return
            await asyncio.sleep(0.1)

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})


def _png(files, sha: str) -> Response:
    return Response(files.read(sha), media_type="image/png", headers={"Cache-Control": "max-age=3600"})


@router.get("/{setup_id}/overlay.png", response_class=Response, summary="Image with fitted edges and markers",
            responses={200: {"content": {"image/png": {}}}})
def get_overlay(session: SessionDep, files: FilesDep, setup_id: int) -> Response:
    s = svc.get_setup(session, setup_id)
    if not (s.result and s.result.get("overlay_sha256")):
        raise NotFound(f"setup {setup_id} has no overlay yet (status {s.status})")
    return _png(files, s.result["overlay_sha256"])


@router.get("/{setup_id}/stages/{index}.png", response_class=Response, summary="Picture of one stage",
            responses={200: {"content": {"image/png": {}}}})
def get_stage_image(session: SessionDep, files: FilesDep, setup_id: int, index: int) -> Response:
    s = svc.get_setup(session, setup_id)
    if not 0 <= index < len(s.stages) or not s.stages[index].get("image_sha256"):
        raise NotFound(f"setup {setup_id} has no picture for stage {index}")
    return _png(files, s.stages[index]["image_sha256"])


@router.get("/{setup_id}/image", response_class=Response, summary="The captured image",
            responses={200: {"content": {"image/jpeg": {}}}})
def get_image(session: SessionDep, files: FilesDep, setup_id: int) -> Response:
    data, media_type = svc.captured_image(session, files, setup_id)
    return Response(data, media_type=media_type)


class Nudge(BaseModel):
    model_config = {"allow_inf_nan": False}

    dx_mm: float = Field(default=0.0, ge=-50, le=50, description="Shift along table x, mm (at most 50 per step)")
    dy_mm: float = Field(default=0.0, ge=-50, le=50)
    dz_mm: float = Field(default=0.0, ge=-50, le=50)
    dc_deg: float = Field(default=0.0, ge=-30, le=30,
                          description="Rotation about table z through the object's origin, degrees (at most 30)")


class AdjustBody(BaseModel):
    object_index: int = Field(ge=0, description="Index into result.objects")
    T_table_obj: list[list[float]] | None = Field(default=None, description="New pose on the table (4x4, mm)")
    nudge: Nudge | None = None


class RefineBody(BaseModel):
    object_index: int = Field(ge=0, description="Index into result.objects")


@router.post("/{setup_id}/refine", response_model=SetupPublic,
             summary="Refine from here: re-fit the object's edges starting at its current pose -> new revision",
             responses={422: {"description": "the fit did not converge from this pose (with the reason)"}})
def refine(session: SessionDep, files: FilesDep, settings: SettingsDep, who: OperatorPrincipal, setup_id: int,
           body: RefineBody) -> SetupPublic:
    return to_public(svc.refine_object(session, files, settings, setup_id, object_index=body.object_index,
                                       by=who.label()))


class DatumBody(RefineBody):
    choice: int = Field(ge=0, description="0 = the pose as located, k = result.objects[i].equivalent_poses[k-1]")


@router.post("/{setup_id}/datum", response_model=SetupPublic,
             summary="Choose which of the equivalent poses (symmetric part) is meant -> new result revision",
             responses={422: {"description": "no equivalent poses, or the choice is out of range"}})
def choose_datum(session: SessionDep, files: FilesDep, settings: SettingsDep, who: OperatorPrincipal, setup_id: int,
                 body: DatumBody) -> SetupPublic:
    return to_public(svc.choose_datum(session, files, settings, setup_id, object_index=body.object_index,
                                      choice=body.choice, by=who.label()))


@router.post("/{setup_id}/dismiss", response_model=SetupPublic,
             summary="A located workpiece is not there (recognised in error) -> new revision without it",
             responses={422: {"description": "not a workpiece, or the only one located"}})
def dismiss(session: SessionDep, files: FilesDep, settings: SettingsDep, who: OperatorPrincipal, setup_id: int,
            body: RefineBody) -> SetupPublic:
    return to_public(svc.dismiss_object(session, files, settings, setup_id, object_index=body.object_index,
                                        by=who.label()))


class ConfirmBody(BaseModel):
    result_revision: int = Field(ge=1, description="The result revision the operator saw and confirms")


@router.post("/{setup_id}/adjust", response_model=SetupPublic, summary="Operator adjustment -> new result revision")
def adjust(session: SessionDep, files: FilesDep, settings: SettingsDep, who: OperatorPrincipal, setup_id: int,
           body: AdjustBody) -> SetupPublic:
    s = svc.adjust_object(session, files, settings, setup_id, object_index=body.object_index,
                          T_table_obj=body.T_table_obj, nudge=body.nudge.model_dump() if body.nudge else None, by=who.label())
    return to_public(s)


@router.post("/{setup_id}/confirm", response_model=SetupPublic,
             summary="Confirm the exact result revision (required before any export)",
             responses={409: {"description": "the revision is not the current one"}})
def confirm(request: Request, session: SessionDep, who: OperatorPrincipal, setup_id: int,
            body: ConfirmBody) -> SetupPublic:
    return to_public(svc.confirm_setup(session, setup_id, result_revision=body.result_revision, by=who.label(),
                                       events=request.app.state.events))


class ExportBody(BaseModel):
    slot: str = Field(default="G54", max_length=20, examples=["G54"],
                      description="Work offset slot: G54..G59, G59.1..G59.3")
    acknowledge_change: bool = Field(default=False, description="Accept a change against the controller's "
                                                                "current offset beyond the configured limit")
    idempotency_key: str | None = Field(default=None, max_length=100,
                                        description="The client's key for this export (also as the Idempotency-Key "
                                                    "header); default: setup, result revision and slot")


class ExportPublic(BaseModel):
    id: int
    setup_id: int
    result_revision: int
    slot: str
    status: str = Field(description="pending -> writing -> written | failed | unknown (unknown: the write or its "
                                    "read-back broke off; read back again before any retry and at start-up)")
    agree: bool = Field(description="Read-back equals the written values within the controller's rounding")
    idempotency_key: str | None
    written: dict | None
    read_back: dict | None
    before: dict | None = Field(description="The slot's values before the write")
    reason: str
    actor: str
    created_at: datetime


def export_public(row) -> ExportPublic:
    return ExportPublic(**row.model_dump(), agree=row.status == "written")


@router.post("/{setup_id}/export", response_model=ExportPublic,
             summary="Write the confirmed work offset into the controller and read it back",
             responses={409: {"description": "not confirmed, changed since, or change beyond the limit"},
                        422: {"description": "implausible (tilt, uncertainty, travel) or no controller"},
                        502: {"description": "controller unreachable (nothing written) or the outcome is unknown "
                                             "(status unknown: it is read back before any retry)"}})
def export(request: Request, session: SessionDep, settings: SettingsDep, who: OperatorPrincipal, setup_id: int,
           body: ExportBody,
           idempotency_key: Annotated[str | None, Header(alias="Idempotency-Key", max_length=100)] = None,
           ) -> ExportPublic:
    row = export_svc.export_offset(session, settings, request.app.state.events, setup_id, slot=body.slot, actor=who.label(),
                        acknowledge_change=body.acknowledge_change,
                        idempotency_key=idempotency_key or body.idempotency_key)
    return export_public(row)


@router.get("/{setup_id}/exports", response_model=list[ExportPublic], summary="Exports of a setup")
def list_exports(session: SessionDep, setup_id: int) -> list[ExportPublic]:
    return [export_public(r) for r in export_svc.list_exports(session, setup_id)]


class ExportRefusalPublic(BaseModel):
    slot: str
    reason: str
    actor: str
    at: datetime


@router.get("/{setup_id}/export-refusals", response_model=list[ExportRefusalPublic],
            summary="Exports of a setup refused before anything was written, with the reason")
def list_export_refusals(session: SessionDep, setup_id: int) -> list[ExportRefusalPublic]:
    svc.get_setup(session, setup_id)
    return [ExportRefusalPublic(slot=str(e.detail.get("slot", "")), reason=str(e.detail.get("reason", "")),
                                actor=e.actor, at=e.at) for e in export_refusals(session, setup_id)]
