"""Rotary-axis check use case: decode the images, measure the run, evaluate ISO 230-2, keep the report."""

from __future__ import annotations

from sqlmodel import Session, col, select

from app.services.cameras import read_image, get_camera
from app.services.errors import Invalid, NotFound
from app.services.jobs import JobRun, Outcome
from app.machine.compensation import fanuc_pitch_proposal, heidenhain_com_proposal
from app.store.db import session_scope
from app.store.files import FileStore
from app.store.models import RotaryRun
from app.vision.image_header import ImageHeaderError, image_size
from app.vision.intrinsics import parse_intrinsics
from app.vision.rotary import measure_run
from app.vision.rotary_report import Iso230Report, correction_grid, report_files
from app.vision.rotary_target import TargetError, default_target, target_from_dict

MEDIA = {".csv": "text/csv", ".png": "image/png", ".svg": "image/svg+xml", ".com": "text/plain", ".txt": "text/plain"}


def prepare_rotary(session: Session, files: FileStore, *, camera_id: int, images: list[tuple[str, bytes]],
                   angles_deg: list[float], target: dict | None, method: str = "direct",
                   directions: list[int] | None = None, axis_name: str = "C", by: str | None = None) -> dict:
    """Check the run at once (4xx with the reason: camera, counts, method, target, image sizes read from
    the headers) and store the images: the rotary job's arguments. Nothing is decoded here."""
    cam = get_camera(session, camera_id)
    if not cam.intrinsics:
        raise Invalid(f"camera {cam.id} ({cam.name}) has no intrinsics; calibrate it first")
    if len(images) < 2:
        raise Invalid("a run needs at least 2 images (the first is the zero position)")
    if len(images) != len(angles_deg):
        raise Invalid(f"{len(images)} images but {len(angles_deg)} commanded angles; give one angle per image")
    if directions is not None and len(directions) != len(angles_deg):
        raise Invalid(f"{len(directions)} directions for {len(angles_deg)} angles")
    if method not in ("direct", "reference"):
        raise Invalid(f"unknown method {method!r}; use direct or reference")
    try:
        tgt = target_from_dict(target) if target else default_target()
    except TargetError as exc:
        raise Invalid(f"target: {exc}") from None
    w, h = cam.intrinsics["width"], cam.intrinsics["height"]
    for name, data in images:
        try:
            size = image_size(data)
        except ImageHeaderError as exc:
            raise Invalid(f"image {name!r} {exc}") from None
        if size != (w, h):
            raise Invalid(f"image {name!r} is {size[0]} x {size[1]} px but camera {cam.id} is calibrated "
                          f"for {w} x {h} px; every image of a run must come from this camera at that resolution")
    return {"camera_id": cam.id, "angles_deg": list(angles_deg), "target": tgt.to_dict(), "method": method,
            "directions": directions, "axis_name": axis_name, "by": by, "names": [n for n, _ in images],
            "image_sha256": [files.put(session, d, "image/jpeg") for _, d in images]}


def run_rotary_job(run: JobRun, *, camera_id: int, angles_deg: list[float], target: dict, method: str,
                   directions: list[int] | None, axis_name: str, by: str | None, names: list[str],
                   image_sha256: list[str]) -> Outcome:
    """The job: decode the stored images, measure the run, evaluate ISO 230-2, keep run and report."""
    ctx = run.ctx
    with Session(ctx.engine) as session:
        intrinsics = get_camera(session, camera_id).intrinsics
    tgt = target_from_dict(target)
    decoded = [read_image(ctx.files.read(sha), f"image {name!r}") for name, sha in zip(names, image_sha256)]
    result = measure_run(decoded, angles_deg, parse_intrinsics(intrinsics), tgt, method=method)
    run.check()  # a run that timed out or lost its job stores nothing
    with session_scope(ctx.engine) as session:
        row = RotaryRun(camera_id=camera_id, axis_name=axis_name, target=target, angles_deg=list(angles_deg),
                        image_sha256=list(image_sha256), ok=result.ok, reason=result.reason,
                        result=result.to_dict(), created_by=by)
        if result.ok:
            report, named = rotary_report(result.angles_deg, result.measured_deg, result.error_arcsec, directions,
                                          axis_name)
            row.report = report.to_dict()
            row.files = {name: ctx.files.put(session, data, media_type_of(name)) for name, data in named.items()}
        session.add(row)
        session.flush()
    return Outcome(result.ok, result.reason, {"resource": "rotary_run", "id": row.id})


def media_type_of(name: str) -> str:
    """The media type of a report file, from its name's suffix (text/plain when unknown)."""
    return MEDIA.get("." + name.rsplit(".", 1)[-1].lower(), "text/plain")


def rotary_report(angles_deg, measured_deg, error_arcsec, directions=None,
                  axis_name: str = "C") -> tuple[Iso230Report, dict[str, bytes]]:
    """The ISO 230-2 report of a run and its files as bytes: run.csv, positions.csv, error.svg, error.png
    and the compensation-table proposals ``<axis>_proposal.COM`` (HEIDENHAIN) and
    ``fanuc_pitch_proposal.txt`` (the CLI writes them to a folder, the service stores them)."""
    report, named = report_files(angles_deg, measured_deg, error_arcsec, directions)
    grid = correction_grid(report)
    named[f"{axis_name}_proposal.COM"] = heidenhain_com_proposal(*grid, axis=axis_name).encode()
    named["fanuc_pitch_proposal.txt"] = fanuc_pitch_proposal(*grid).encode()
    return report, named


def get_run(session: Session, run_id: int) -> RotaryRun:
    run = session.get(RotaryRun, run_id)
    if run is None:
        raise NotFound(f"rotary run {run_id} not found")
    return run


def list_runs(session: Session, limit: int = 50) -> list[RotaryRun]:
    return list(session.exec(select(RotaryRun).order_by(col(RotaryRun.id).desc()).limit(limit)).all())
