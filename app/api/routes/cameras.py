"""/api/v1/cameras: cameras, their image source, a snapshot, and calibration."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any

import cv2
from fastapi import APIRouter, Depends, File, Form, Query, Request, Response, UploadFile, status
from pydantic import BaseModel, Field
from starlette.concurrency import run_in_threadpool

from app.api.deps import AdminPrincipal, FilesDep, SessionDep, SettingsDep, get_principal
from app.api.routes.jobs import JobAccepted, enqueue
from app.api.uploads import json_form, read_uploads
from app.services import cameras as svc
from app.services import printing
from app.services.cameras import Intrinsics
from app.services.audit import audit

router = APIRouter(prefix="/cameras", tags=["cameras"], dependencies=[Depends(get_principal)])

SOURCE_DOC = ('Image source: {"kind": "upload"} | {"kind": "http", "url": "http://cam/snapshot.jpg"} | '
              '{"kind": "folder", "path": "/srv/cam1", "pattern": "*.jpg"} | {"kind": "opencv", "device": 0}')


class CameraCreate(BaseModel):
    name: str = Field(min_length=1, max_length=200, examples=["Mill 3 cabin camera"])
    intrinsics: Intrinsics | None = None
    source: dict[str, Any] = Field(default_factory=lambda: {"kind": "upload"}, description=SOURCE_DOC,
                                   examples=[{"kind": "http", "url": "http://192.0.2.10/snapshot.jpg"}])


class CameraUpdate(BaseModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)
    intrinsics: Intrinsics | None = None
    source: dict[str, Any] | None = Field(default=None, description=SOURCE_DOC)


class CameraPublic(BaseModel):
    id: int
    name: str
    intrinsics: dict | None
    source: dict
    created_at: datetime


class CalibrationPublic(BaseModel):
    id: int
    camera_id: int
    ok: bool
    reason: str
    rms_px: float | None
    accepted: bool
    board: dict
    result: dict | None = Field(description="intrinsics, per-image errors, coverage and warnings")
    created_at: datetime


def _public(cam) -> CameraPublic:
    return CameraPublic.model_validate(cam, from_attributes=True)


@router.post("", status_code=status.HTTP_201_CREATED, response_model=CameraPublic, summary="Register a camera")
def create_camera(session: SessionDep, admin: AdminPrincipal, body: CameraCreate) -> CameraPublic:
    intr = body.intrinsics.model_dump() if body.intrinsics else None
    cam = svc.create_camera(session, name=body.name, intrinsics=intr, source=body.source)
    audit(session, admin.label(), "camera.create", camera_id=cam.id, name=cam.name)
    return _public(cam)


@router.get("", response_model=list[CameraPublic], summary="List cameras")
def list_cameras(session: SessionDep) -> list[CameraPublic]:
    return [_public(c) for c in svc.list_cameras(session)]


@router.get("/board.pdf", response_class=Response, summary="A calibration board to print, at true scale (PDF)",
            responses={200: {"content": {"application/pdf": {}}},
                       422: {"description": "bad board description, or a board larger than A3"}})
def board_pdf(board: Annotated[str, Query(description="Board JSON, as for a calibration run", examples=[
        '{"kind": "charuco", "squares": [5, 7], "square_mm": 40, "marker_mm": 20, "dictionary": "DICT_6X6_250"}'])]
              ) -> Response:
    pdf, name = printing.calibration_board_pdf(json_form(board, "board"))
    return Response(pdf, media_type="application/pdf", headers={"Content-Disposition": f'inline; filename="{name}"'})


@router.get("/{camera_id}", response_model=CameraPublic, summary="One camera")
def get_camera(session: SessionDep, camera_id: int) -> CameraPublic:
    return _public(svc.get_camera(session, camera_id))


@router.patch("/{camera_id}", response_model=CameraPublic, summary="Change name, intrinsics or source")
def update_camera(session: SessionDep, admin: AdminPrincipal, camera_id: int, body: CameraUpdate) -> CameraPublic:
    changes = body.model_dump(exclude_unset=True)
    cam = svc.update_camera(session, camera_id, changes)
    audit(session, admin.label(), "camera.update", camera_id=cam.id, changed=sorted(changes))
    return _public(cam)


@router.delete("/{camera_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response,
               summary="Remove a camera (soft delete)")
def delete_camera(session: SessionDep, admin: AdminPrincipal, camera_id: int) -> Response:
    svc.delete_camera(session, camera_id)
    audit(session, admin.label(), "camera.delete", camera_id=camera_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post("/{camera_id}/snapshot", response_class=Response, summary="Grab one frame from the camera's source",
             responses={200: {"content": {"image/jpeg": {}}}, 422: {"description": "upload-only camera"},
                        502: {"description": "the source did not deliver"}})
def snapshot(session: SessionDep, camera_id: int) -> Response:
    frame = svc.grab_frame(svc.get_camera(session, camera_id))
    ok, buf = cv2.imencode(".jpg", frame, [cv2.IMWRITE_JPEG_QUALITY, 95])
    return Response(buf.tobytes(), media_type="image/jpeg",
                    headers={"X-Image-Width": str(frame.shape[1]), "X-Image-Height": str(frame.shape[0])})


@router.post("/{camera_id}/calibrations", status_code=status.HTTP_202_ACCEPTED, response_model=JobAccepted,
             summary="Calibrate from images of a chessboard or ChArUco board (a job; its result is the run)",
             responses={422: {"description": "bad board description, unreadable image, or too few usable views"}})
async def calibrate(
    request: Request, session: SessionDep, files: FilesDep, settings: SettingsDep, admin: AdminPrincipal, camera_id: int,
    images: Annotated[list[UploadFile], File(description="Board images (JPEG/PNG), at least 3")],
    board: Annotated[str, Form(description="Board JSON", examples=[
        '{"kind": "chessboard", "inner_corners": [9, 6], "square_mm": 25}',
        '{"kind": "charuco", "squares": [5, 7], "square_mm": 40, "marker_mm": 20, "dictionary": "DICT_6X6_250"}'])],
    fix_aspect_ratio: Annotated[bool, Form(description="Keep fx/fy fixed (OpenCV CALIB_FIX_ASPECT_RATIO)")] = False,
    subpix_window_px: Annotated[int | None, Form(ge=2, le=30, description=(
        "Half window of the corner refinement in px. Default: 40 % of the corner spacing. 11 reproduces "
        "OpenCV's calibration sample exactly (its published figures), at the cost of corners pulled "
        "onto neighbours in oblique views."))] = None,
) -> CalibrationPublic:
    board_dict = json_form(board, "board")
    loaded = await read_uploads(images, settings)
    args = await run_in_threadpool(svc.prepare_calibration, session, files, camera_id, images=loaded,
                                   board=board_dict, fix_aspect_ratio=fix_aspect_ratio,
                                   subpix_half_window_px=subpix_window_px)
    return enqueue(request, session, "calibrate", args, admin.label())


@router.get("/{camera_id}/calibrations", response_model=list[CalibrationPublic], summary="Calibration runs")
def list_calibrations(session: SessionDep, camera_id: int) -> list[CalibrationPublic]:
    return [CalibrationPublic.model_validate(c, from_attributes=True) for c in svc.list_calibrations(session, camera_id)]


@router.get("/{camera_id}/calibrations/{calibration_id}", response_model=CalibrationPublic,
            summary="One calibration run")
def get_calibration(session: SessionDep, camera_id: int, calibration_id: int) -> CalibrationPublic:
    return CalibrationPublic.model_validate(svc.get_calibration(session, camera_id, calibration_id),
                                            from_attributes=True)


@router.post("/{camera_id}/calibrations/{calibration_id}/accept", response_model=CameraPublic,
             summary="Use this calibration's intrinsics for the camera")
def accept_calibration(session: SessionDep, admin: AdminPrincipal, camera_id: int, calibration_id: int) -> CameraPublic:
    cam = svc.accept_calibration(session, camera_id, calibration_id)
    audit(session, admin.label(), "camera.calibration_accepted", camera_id=camera_id, calibration_id=calibration_id)
    return _public(cam)
