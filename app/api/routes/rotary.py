"""/api/v1/rotary: rotary-axis angular positioning error from images of a circular target."""

from __future__ import annotations

import math
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Depends, File, Form, Request, Response, UploadFile, status
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool

from app.api.deps import CurrentPrincipal, FilesDep, SessionDep, SettingsDep, get_principal
from app.api.routes.jobs import JobAccepted, enqueue
from app.api.uploads import content_disposition, json_form, read_uploads
from app.services import printing
from app.services import rotary as svc
from app.services.errors import Invalid, NotFound

router = APIRouter(prefix="/rotary", tags=["rotary"], dependencies=[Depends(get_principal)])


class RotaryRunPublic(BaseModel):
    id: int
    camera_id: int | None
    axis_name: str
    ok: bool
    reason: str
    angles_deg: list[float]
    result: dict | None = Field(description="measured_deg and error_arcsec per image (first image = 0)")
    report: dict | None = Field(description="ISO 230-2 figures: per position mean errors, reversal, "
                                            "repeatability, accuracy (arc-seconds)")
    files: dict[str, str] = Field(description="report file name -> download URL (CSV, PNG/SVG plot, "
                                              "compensation PROPOSALS for HEIDENHAIN and Fanuc)")
    created_at: datetime


def _public(run) -> RotaryRunPublic:
    return RotaryRunPublic(**run.model_dump(exclude={"files"}),
                           files={name: f"/api/v1/rotary/runs/{run.id}/files/{name}" for name in run.files})


def _floats(text: str, what: str) -> list[float]:
    try:
        values = [float(x) for x in text.replace(";", ",").replace(" ", ",").split(",") if x.strip()]
    except ValueError:
        raise Invalid(f"{what}: give numbers separated by commas, got {text!r}") from None
    if not all(math.isfinite(v) and abs(v) <= 1e6 for v in values):
        raise Invalid(f"{what}: give finite numbers (within ±1e6), got {text!r}")
    return values


@router.post("/runs", status_code=status.HTTP_202_ACCEPTED, response_model=JobAccepted,
             summary="Measure a run: images of the target at commanded angles (first = zero position); a job "
                     "whose result is the run",
             responses={422: {"description": "bad angles, target, images or camera without intrinsics"}})
async def create_run(
    request: Request, session: SessionDep, files: FilesDep, settings: SettingsDep, who: CurrentPrincipal,
    camera_id: Annotated[int, Form()],
    images: Annotated[list[UploadFile], File(description="Images in the order of angles_deg")],
    angles_deg: Annotated[str, Form(description="Commanded angles, comma-separated", examples=["0,10,20,30"])],
    target: Annotated[str | None, Form(description='{"groups": [{"center_mm": [x, y], "circle_radii_mm": [r, ...]}], '
                                                  '"mark_mm": [x, y]}; default: the printable default target')] = None,
    directions: Annotated[str | None, Form(description="+1/-1 per image; default: inferred")] = None,
    method: Annotated[str, Form(description="direct (ours) | reference")] = "direct",
    axis_name: Annotated[str, Form(max_length=10)] = "C",
) -> JobAccepted:
    tgt = json_form(target, "target")  # the cheap checks first, then the images
    loaded = await read_uploads(images, settings)
    dirs = [int(d) for d in _floats(directions, "directions")] if directions else None
    args = await run_in_threadpool(svc.prepare_rotary, session, files, camera_id=camera_id, images=loaded,
                                   angles_deg=_floats(angles_deg, "angles_deg"), target=tgt, method=method,
                                   directions=dirs, axis_name=axis_name, by=who.label())
    return enqueue(request, session, "rotary", args, who.label())


@router.get("/runs", response_model=list[RotaryRunPublic], summary="Recent rotary runs")
def list_runs(session: SessionDep) -> list[RotaryRunPublic]:
    return [_public(r) for r in svc.list_runs(session)]


@router.get("/runs/{run_id}", response_model=RotaryRunPublic, summary="One rotary run")
def get_run(session: SessionDep, run_id: int) -> RotaryRunPublic:
    return _public(svc.get_run(session, run_id))


@router.get("/runs/{run_id}/files/{name}", response_class=Response, summary="A report file of a run")
def get_file(session: SessionDep, files: FilesDep, run_id: int, name: str) -> Response:
    run = svc.get_run(session, run_id)
    if name not in run.files:
        raise NotFound(f"rotary run {run_id} has no file {name!r}; it has {', '.join(sorted(run.files)) or 'none'}")
    data = files.read(run.files[name])
    return Response(data, media_type=svc.media_type_of(name), headers={"Content-Disposition": content_disposition(name)})


@router.get("/target.{fmt}", response_class=Response, summary="The printable default target at true scale")
def default_target_file(fmt: str) -> Response:
    data, media = printing.rotary_target(fmt)
    return Response(data, media_type=media)
