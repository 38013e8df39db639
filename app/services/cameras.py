"""Camera use cases: register, configure a source, grab a frame, calibrate, accept a calibration."""

from __future__ import annotations

import logging
from typing import Any

import cv2
import numpy as np
from sqlmodel import Session, col, select

from app.services.errors import Invalid, NotFound, Unavailable
from app.services.jobs import JobRun, Outcome
from app.sources import SourceError, make_source
from app.store.db import session_scope
from app.store.files import FileStore
from app.store.models import Calibration, Camera, utcnow
from app.vision import calibration as calib
from app.vision.intrinsics import Intrinsics, parse_intrinsics  # Intrinsics: the routes' body schema too

log = logging.getLogger(__name__)


def validate_source(source: dict | None) -> dict:
    source = source or {"kind": "upload"}
    try:
        make_source(source)
    except ValueError as exc:
        raise Invalid(f"source: {exc}") from None
    return source


def validate_intrinsics(intrinsics: dict | None) -> dict | None:
    if intrinsics is None:
        return None
    try:
        # an absent sigma (the engine's default) is stored as absent
        return parse_intrinsics(intrinsics).model_dump(exclude_none=True)
    except ValueError as exc:
        raise Invalid(str(exc)) from None


def create_camera(session: Session, *, name: str, intrinsics: dict | None = None, source: dict | None = None) -> Camera:
    cam = Camera(name=name, intrinsics=validate_intrinsics(intrinsics), source=validate_source(source))
    session.add(cam)
    session.flush()
    return cam


def get_camera(session: Session, camera_id: int) -> Camera:
    cam = session.get(Camera, camera_id)
    if cam is None or cam.deleted_at is not None:
        raise NotFound(f"camera {camera_id} not found")
    return cam


def list_cameras(session: Session) -> list[Camera]:
    return list(session.exec(select(Camera).where(col(Camera.deleted_at).is_(None)).order_by(Camera.id)).all())


def update_camera(session: Session, camera_id: int, changes: dict[str, Any]) -> Camera:
    cam = get_camera(session, camera_id)
    if "name" in changes and changes["name"] is None:
        raise Invalid("name: must not be null (leave it out to keep the current name)")
    if "name" in changes:
        cam.name = changes["name"]
    if "intrinsics" in changes:
        cam.intrinsics = validate_intrinsics(changes["intrinsics"])
    if "source" in changes:
        cam.source = validate_source(changes["source"])
    session.add(cam)
    session.flush()
    return cam


def delete_camera(session: Session, camera_id: int) -> None:
    cam = get_camera(session, camera_id)
    cam.deleted_at = utcnow()
    session.add(cam)


def grab_frame(cam: Camera) -> np.ndarray:
    """One BGR frame from the camera's source; 409 for upload-only cameras, 502 when the source fails."""
    if cam.source.get("kind", "upload") == "upload":
        raise Invalid(f"camera {cam.id} ({cam.name}) has no image source (upload only); "
                      "configure an HTTP snapshot URL, a folder or an OpenCV device, or upload an image", code="camera_upload_only")
    try:
        return make_source(cam.source).grab()
    except SourceError as exc:
        raise Unavailable(str(exc), code="camera_unavailable") from None


def read_image(data: bytes, what: str = "image") -> np.ndarray:
    """Uploaded or stored image bytes (JPEG/PNG/...) decoded to BGR (:func:`app.vision.calibration.decode_image`);
    422 with the reason when they are not an image."""
    if not data:
        raise Invalid(f"{what} is empty")
    try:
        return calib.decode_image(data)
    except ValueError:
        raise Invalid(f"{what} is not a readable image (JPEG, PNG, BMP or TIFF expected)") from None


IMAGE_MAGIC = ((b"\x89PNG", "image/png"), (b"\xff\xd8", "image/jpeg"), (b"BM", "image/bmp"),
               (b"II*\x00", "image/tiff"), (b"MM\x00*", "image/tiff"))


def image_media_type(data: bytes) -> str:
    """The media type of encoded image bytes as their first bytes tell (stored with the file, so the
    image is answered with its real type): PNG, JPEG, BMP, TIFF, else ``application/octet-stream``."""
    for magic, media in IMAGE_MAGIC:
        if data.startswith(magic):
            return media
    return "application/octet-stream"


def prepare_calibration(session: Session, files: FileStore, camera_id: int, *, images: list[tuple[str, bytes]],
                        board: dict, fix_aspect_ratio: bool = False,
                        subpix_half_window_px: int | None = None) -> dict:
    """Check what can be checked at once (camera, board, images present; 4xx with the reason) and
    store the images: the calibration job's arguments (ids and sha256s, nothing decoded here)."""
    get_camera(session, camera_id)
    if not images:
        raise Invalid("no images: upload at least 3 views of the board")
    try:
        calib.BoardSpec.model_validate(board)
    except ValueError as exc:
        raise Invalid(f"board: {_first_error(exc)}") from None
    return {"camera_id": camera_id, "board": board, "names": [n for n, _ in images],
            "image_sha256": [files.put(session, data, "image/jpeg") for _name, data in images],
            "fix_aspect_ratio": fix_aspect_ratio, "subpix_half_window_px": subpix_half_window_px}


def run_calibration_job(run: JobRun, *, camera_id: int, board: dict, names: list[str], image_sha256: list[str],
                        fix_aspect_ratio: bool = False, subpix_half_window_px: int | None = None) -> Outcome:
    """The job: decode the stored views, calibrate, keep the run (images, per-view reasons) whether it
    succeeds or not."""
    ctx = run.ctx
    spec = calib.BoardSpec.model_validate(board)
    try:
        decoded = [read_image(ctx.files.read(sha), f"image {name!r}") for name, sha in zip(names, image_sha256)]
    except Invalid as exc:  # stored as a failed run, like too few usable views
        return _store_calibration(run, camera_id, board, image_sha256, calib.CalibrationFailure(exc.detail, ()))
    result = calib.calibrate(decoded, spec, fix_aspect_ratio=fix_aspect_ratio, names=names,
                             subpix_half_window_px=subpix_half_window_px)
    return _store_calibration(run, camera_id, board, image_sha256, result)


def _store_calibration(run: JobRun, camera_id: int, board: dict, shas: list[str], result: Any) -> Outcome:
    run.check()  # a run that timed out or lost its job stores nothing
    ok = not isinstance(result, calib.CalibrationFailure)
    reason = "" if ok else result.reason
    row = Calibration(camera_id=camera_id, board=board, image_sha256=shas, ok=ok, reason=reason,
                      result=result.to_dict(), rms_px=getattr(result, "rms_px", None))
    with session_scope(run.ctx.engine) as session:
        session.add(row)
        session.flush()
    log.info("calibration", extra={"camera_id": camera_id, "ok": ok, "rms_px": row.rms_px})
    link = {"resource": "calibration", "id": row.id, "camera_id": camera_id}
    return Outcome(ok, "" if ok else f"calibration {row.id} failed: {reason}", link)


def _first_error(exc: ValueError) -> str:
    errors = getattr(exc, "errors", None)
    if callable(errors) and errors():
        e = errors()[0]
        where = ".".join(str(p) for p in e.get("loc", ()))
        return f"{where + ': ' if where else ''}{str(e.get('msg', exc)).removeprefix('Value error, ')}"
    return str(exc)


def get_calibration(session: Session, camera_id: int, calibration_id: int) -> Calibration:
    row = session.get(Calibration, calibration_id)
    if row is None or row.camera_id != camera_id:
        raise NotFound(f"calibration {calibration_id} of camera {camera_id} not found")
    return row


def list_calibrations(session: Session, camera_id: int) -> list[Calibration]:
    get_camera(session, camera_id)
    return list(session.exec(select(Calibration).where(Calibration.camera_id == camera_id)
                             .order_by(Calibration.id)).all())


def accept_calibration(session: Session, camera_id: int, calibration_id: int) -> Camera:
    """Make a successful calibration the camera's intrinsics."""
    cam = get_camera(session, camera_id)
    row = get_calibration(session, camera_id, calibration_id)
    if not row.ok:
        raise Invalid(f"calibration {calibration_id} failed ({row.reason}); it cannot be accepted")
    cam.intrinsics = validate_intrinsics(row.result["intrinsics"])
    row.accepted = True
    session.add_all([cam, row])
    session.flush()
    return cam
