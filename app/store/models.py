"""SQLModel tables and their API families (Base / Create / table / Public).

Poses are stored as 4x4 nested lists (mm) under their frame names (``T_obj_datum``,
``T_machine_table``); everything in mm and degrees.
"""

from __future__ import annotations

from datetime import datetime, timezone
from typing import Any, Literal

from sqlalchemy import JSON, Column, Index, UniqueConstraint, text
from sqlmodel import Field, SQLModel

ModelKind = Literal["workpiece", "clamp", "support", "table"]
Units = Literal["mm", "inch"]


def utcnow() -> datetime:
    return datetime.now(timezone.utc)


def json_field(nullable: bool = True, **kw: Any) -> Any:
    """A JSON column (works on SQLite and PostgreSQL); default None unless a default_factory is given."""
    if "default_factory" not in kw:
        kw["default"] = None
    return Field(sa_column=Column(JSON, nullable=nullable), **kw)


# --------------------------------------------------------------------------------------- files
class StoredFile(SQLModel, table=True):
    """A content-addressed file under ``data_dir/files`` (named by its sha256)."""

    sha256: str = Field(primary_key=True, max_length=64)
    size_bytes: int
    media_type: str = Field(max_length=100)
    created_at: datetime = Field(default_factory=utcnow)


# --------------------------------------------------------------------------------------- library
class LibraryModel(SQLModel, table=True):
    """A library entry (workpiece, clamp, support or table). Its geometry and frames live in revisions."""

    __tablename__ = "library_model"
    id: int | None = Field(default=None, primary_key=True)
    key: str | None = Field(default=None, max_length=120, unique=True,
                            description="Stable key of an example-library model (idempotent loading).")
    kind: str = Field(max_length=20, index=True)
    name: str = Field(max_length=200, index=True)
    description: str = Field(default="", max_length=2000)
    source: str = Field(default="cad", max_length=20,
                        description="cad: from a CAD file; photo: taught from pictures (docs/photo-models.md)")
    current_revision: int = 1
    created_at: datetime = Field(default_factory=utcnow)
    deleted_at: datetime | None = None


class ModelRevision(SQLModel, table=True):
    """One immutable revision: geometry file + frames. Anything referencing it reproduces."""

    __tablename__ = "model_revision"
    __table_args__ = (UniqueConstraint("model_id", "revision"),)
    id: int | None = Field(default=None, primary_key=True)
    model_id: int = Field(foreign_key="library_model.id", index=True)
    revision: int
    source_filename: str = Field(max_length=255)
    source_sha256: str = Field(foreign_key="storedfile.sha256", max_length=64)
    glb_sha256: str = Field(foreign_key="storedfile.sha256", max_length=64)
    thumbnail_sha256: str = Field(foreign_key="storedfile.sha256", max_length=64)
    units: str = Field(max_length=10, description="Units of the uploaded file; geometry is stored in mm.")
    T_obj_datum: list[list[float]] | None = json_field()
    fiducials: dict | None = json_field()
    # fixtures: plane patches a part can rest on, model frame ({"name", "z_mm", "outline_xy"}, mm);
    # None: derived from the mesh's upward faces; []: carries nothing
    support_surfaces: list[dict] | None = json_field()
    # fixtures: what carries the model and how it moves there (app/geometry/guides.py: carrier,
    # T_carrier_obj, axis, travel_mm; carrier frame, mm); None: it stands free
    guide: dict | None = json_field()
    summary: dict = json_field(default_factory=dict, nullable=False)
    resting_poses: list[dict] = json_field(default_factory=list, nullable=False)
    # a photo model: its edge template, pictures and teach picture (app/vision/photo_model/); None: CAD
    photo: dict | None = json_field()
    note: str = Field(default="", max_length=500)
    created_at: datetime = Field(default_factory=utcnow)


# --------------------------------------------------------------------------------------- cameras
class CameraBase(SQLModel):
    name: str = Field(max_length=200, min_length=1)
    intrinsics: dict | None = json_field(description="DESIGN format: width, height, K, dist")
    source: dict = json_field(default_factory=lambda: {"kind": "upload"}, nullable=False)


class Camera(CameraBase, table=True):
    id: int | None = Field(default=None, primary_key=True)
    created_at: datetime = Field(default_factory=utcnow)
    deleted_at: datetime | None = None


class Calibration(SQLModel, table=True):
    """One calibration run of a camera: the board, the images and the numbers found."""

    id: int | None = Field(default=None, primary_key=True)
    camera_id: int = Field(foreign_key="camera.id", index=True)
    board: dict = json_field(nullable=False)
    image_sha256: list[str] = json_field(default_factory=list, nullable=False)
    ok: bool
    reason: str = Field(default="", max_length=2000)
    result: dict | None = json_field()
    rms_px: float | None = None
    accepted: bool = False
    created_at: datetime = Field(default_factory=utcnow)


# --------------------------------------------------------------------------------------- machines
class Machine(SQLModel, table=True):
    id: int | None = Field(default=None, primary_key=True)
    name: str = Field(max_length=200)
    table_model_id: int = Field(foreign_key="library_model.id")
    table_revision: int
    T_machine_table: list[list[float]] = json_field(nullable=False)
    travel_mm: dict = json_field(nullable=False, description="{x: [min, max], y: [...], z: [...]} in mm")
    camera_ids: list[int] = json_field(default_factory=list, nullable=False)
    controller: dict | None = json_field()
    # this machine's own limits; None: the global setting (SETUPCAM_MAX_TILT_DEG, _OFFSET_CHANGE_MM/_DEG)
    max_tilt_deg: float | None = Field(default=None, description="Residual tilt a 3-axis offset may ignore, °")
    max_offset_change_mm: float | None = Field(default=None, description="X/Y/Z change without acknowledgement, mm")
    max_offset_change_deg: float | None = Field(default=None, description="C change without acknowledgement, °")
    # the rotary axis carrying the table (app.machine.settings.RotaryAxisSettings); None: the table does not
    # turn. With one, T_machine_table is the chain at its export_at_deg (kept in step by the service)
    rotary_axis: dict | None = json_field()
    created_at: datetime = Field(default_factory=utcnow)
    deleted_at: datetime | None = None


# --------------------------------------------------------------------------------------- setups
class Capture(SQLModel, table=True):
    """One stored image (uploaded or grabbed) that a setup was computed from."""

    id: int | None = Field(default=None, primary_key=True)
    camera_id: int | None = Field(default=None, foreign_key="camera.id")
    image_sha256: str = Field(foreign_key="storedfile.sha256", max_length=64)
    width: int
    height: int
    origin: str = Field(default="upload", max_length=20, description="upload | grab")
    created_at: datetime = Field(default_factory=utcnow)


class Setup(SQLModel, table=True):
    """A setup job: queued -> running -> located | failed; then confirmed and exported.

    ``result`` holds revision ``result_revision`` of the located poses (a refine or an operator
    adjustment makes a new revision); ``stages`` the per-stage record (name, ok, ms, message, picture);
    ``progress`` where a long stage stands while it runs.
    """

    id: int | None = Field(default=None, primary_key=True)
    machine_id: int = Field(foreign_key="machine.id", index=True)
    camera_id: int | None = Field(default=None, foreign_key="camera.id")
    capture_id: int = Field(foreign_key="capture.id")
    intrinsics: dict = json_field(nullable=False, description="Intrinsics used (copied: reproducible)")
    models: list[dict] = json_field(default_factory=list, nullable=False,
                                    description="[{model_id, revision}] asked for; empty = recognise")
    status: str = Field(default="queued", max_length=20, index=True)
    reason: str = Field(default="", max_length=2000)
    stages: list[dict] = json_field(default_factory=list, nullable=False)
    # the stage running now, while it runs long (recognition): {stage, done, total, message}; None between
    progress: dict | None = json_field()
    result: dict | None = json_field()
    result_revision: int = 0
    history: list[dict] = json_field(default_factory=list, nullable=False,
                                     description="Earlier result revisions, oldest first")
    # a machine with a rotary table: the axis angle when the picture was taken (degrees, machine coordinates)
    # and where it came from ("controller" | "operator"); None on a machine whose table does not turn
    table_angle_deg: float | None = None
    table_angle_from: str | None = Field(default=None, max_length=20)
    confirmed_revision: int | None = None
    confirmed_by: str | None = Field(default=None, max_length=200)
    confirmed_at: datetime | None = None
    created_by: str | None = Field(default=None, max_length=200)
    created_at: datetime = Field(default_factory=utcnow)
    updated_at: datetime = Field(default_factory=utcnow)


# --------------------------------------------------------------------------------------- access
class User(SQLModel, table=True):
    """An operator or admin who signs in with a password (scrypt hash, never the password)."""

    id: int | None = Field(default=None, primary_key=True)
    name: str = Field(max_length=100, unique=True, index=True)
    role: str = Field(max_length=20, description="operator | admin")
    password_hash: str = Field(max_length=300)
    created_at: datetime = Field(default_factory=utcnow)
    disabled_at: datetime | None = None


class ApiKey(SQLModel, table=True):
    """A key for scripts and the MES: only its sha256 is stored; the secret is shown once."""

    id: int | None = Field(default=None, primary_key=True)
    name: str = Field(max_length=100)
    prefix: str = Field(max_length=16, index=True, description="First characters of the key, to recognise it")
    key_hash: str = Field(max_length=64, unique=True)
    scope: str = Field(max_length=20, description="mes | admin")
    created_at: datetime = Field(default_factory=utcnow)
    revoked_at: datetime | None = None


class LoginSession(SQLModel, table=True):
    """A signed-in browser: the cookie holds the token, the table its sha256."""

    __tablename__ = "login_session"
    id: int | None = Field(default=None, primary_key=True)
    token_hash: str = Field(max_length=64, unique=True)
    user_id: int = Field(foreign_key="user.id", index=True)
    created_at: datetime = Field(default_factory=utcnow)
    expires_at: datetime


class AuditEntry(SQLModel, table=True):
    """Append-only log of what changed a controller or a result: who, what, when, before, after."""

    __tablename__ = "audit_entry"
    id: int | None = Field(default=None, primary_key=True)
    at: datetime = Field(default_factory=utcnow, index=True)
    actor: str = Field(max_length=200)
    action: str = Field(max_length=50, index=True)
    setup_id: int | None = Field(default=None, index=True)
    machine_id: int | None = None
    detail: dict = json_field(default_factory=dict, nullable=False)


class Export(SQLModel, table=True):
    """One export of a confirmed result to a controller slot (idempotency: one per setup/revision/slot)."""

    __table_args__ = (UniqueConstraint("setup_id", "result_revision", "slot"),)
    id: int | None = Field(default=None, primary_key=True)
    setup_id: int = Field(foreign_key="setup.id", index=True)
    result_revision: int
    slot: str = Field(max_length=20)
    status: str = Field(max_length=20, description="pending | writing | written | failed | unknown "
                                                   "(app/services/export.py)")
    idempotency_key: str | None = Field(default=None, max_length=100, unique=True,
                                        description="The client's key (or setup/revision/slot): one export per key")
    written: dict | None = json_field()
    read_back: dict | None = json_field()
    before: dict | None = json_field()
    reason: str = Field(default="", max_length=2000)
    actor: str = Field(max_length=200)
    created_at: datetime = Field(default_factory=utcnow)
    updated_at: datetime = Field(default_factory=utcnow)


# --------------------------------------------------------------------------------------- rotary axis checks
class RotaryRun(SQLModel, table=True):
    """One rotary-axis measurement: images at commanded angles -> errors, ISO 230-2 figures, report files."""

    __tablename__ = "rotary_run"
    id: int | None = Field(default=None, primary_key=True)
    camera_id: int | None = Field(default=None, foreign_key="camera.id")
    axis_name: str = Field(default="C", max_length=10)
    target: dict = json_field(nullable=False)
    angles_deg: list[float] = json_field(default_factory=list, nullable=False)
    image_sha256: list[str] = json_field(default_factory=list, nullable=False)
    ok: bool
    reason: str = Field(default="", max_length=2000)
    result: dict | None = json_field()
    report: dict | None = json_field()
    files: dict = json_field(default_factory=dict, nullable=False, description="report file name -> sha256")
    created_by: str | None = Field(default=None, max_length=200)
    created_at: datetime = Field(default_factory=utcnow)


# --------------------------------------------------------------------------------------- sheet metal (cutting beds)
class SheetBedPose(SQLModel, table=True):
    """The bed pose ``T_cam_bed`` (mm) of a camera over a cutting bed, used when a request gives none."""

    __tablename__ = "sheet_bed_pose"
    camera_id: int = Field(foreign_key="camera.id", primary_key=True)
    T_cam_bed: list[list[float]] = json_field(nullable=False)
    set_by: str = Field(max_length=200)
    updated_at: datetime = Field(default_factory=utcnow)


class SheetAlignment(SQLModel, table=True):
    """One sheet found (or not) on a cutting bed: corners, angle and the work offset in the bed frame.

    ``result`` is :meth:`app.vision.sheet.SheetResult.as_dict` (or ``{"error", "stage"}``); confirmation
    covers this exact result and the re-datums of its monitors within their L2.
    """

    __tablename__ = "sheet_alignment"
    id: int | None = Field(default=None, primary_key=True)
    machine_id: int = Field(foreign_key="machine.id", index=True)
    camera_id: int = Field(foreign_key="camera.id")
    intrinsics: dict = json_field(nullable=False, description="Intrinsics used (copied: reproducible)")
    T_cam_bed: list[list[float]] = json_field(nullable=False)
    thickness_mm: float
    margin_mm: float
    image_sha256: str = Field(foreign_key="storedfile.sha256", max_length=64)
    picture_sha256: str | None = Field(default=None, max_length=64, description="draw_sheet picture (PNG)")
    origin: str = Field(default="upload", max_length=20, description="upload | grab")
    status: str = Field(max_length=20, index=True, description="located | failed")
    reason: str = Field(default="", max_length=2000)
    result: dict | None = json_field()
    confirmed_by: str | None = Field(default=None, max_length=200)
    confirmed_at: datetime | None = None
    created_by: str | None = Field(default=None, max_length=200)
    created_at: datetime = Field(default_factory=utcnow)


class SheetMonitor(SQLModel, table=True):
    """Drift monitoring of a confirmed alignment: thresholds, the slot it re-datums, its state."""

    __tablename__ = "sheet_monitor"
    # one running monitor per camera: two would re-datum the same machine from the same pictures
    __table_args__ = (Index("uq_sheet_monitor_running_camera", "camera_id", unique=True,
                            sqlite_where=text("state = 'running'"), postgresql_where=text("state = 'running'")),)
    id: int | None = Field(default=None, primary_key=True)
    alignment_id: int = Field(foreign_key="sheet_alignment.id", index=True)
    camera_id: int | None = Field(default=None, description="the alignment's camera, copied here for the index "
                                                            "that allows one running monitor per camera")
    l1_mm: float
    l2_mm: float
    interval_s: float | None = Field(default=None, description="camera polling period; None = frames are posted")
    slot: str = Field(default="G54", max_length=20)
    roi_px: int = 100
    hold_after_unseen: int | None = Field(default=None, description="hold the program after this many frames "
                                                                     "in a row without all four corners; None = never")
    state: str = Field(default="running", max_length=20, index=True, description="running | stopped | finished")
    reason: str = Field(default="", max_length=2000)
    last_decision: dict | None = json_field()
    drift_state: dict | None = json_field(description="DriftMonitor.state() after the last frame: resumes after a "
                                                      "restart")
    frames: int = 0
    created_by: str | None = Field(default=None, max_length=200)
    created_at: datetime = Field(default_factory=utcnow)
    updated_at: datetime = Field(default_factory=utcnow)


class SheetMonitorEvent(SQLModel, table=True):
    """One frame's decision: ok | redatum | stop | frame_missing | corner_not_found, errors, picture, action."""

    __tablename__ = "sheet_monitor_event"
    id: int | None = Field(default=None, primary_key=True)
    monitor_id: int = Field(foreign_key="sheet_monitor.id", index=True)
    frame_index: int
    decision: str = Field(max_length=20)
    reason: str = Field(default="", max_length=2000)
    errors_mm: list = json_field(default_factory=list, nullable=False, description="4 corner errors (mm) or null")
    detail: dict = json_field(default_factory=dict, nullable=False,
                              description="DriftDecision.as_dict() plus the controller action taken")
    frame_sha256: str | None = Field(default=None, max_length=64, description="the frame as received (None: no frame)")
    picture_sha256: str | None = Field(default=None, max_length=64, description="draw_drift picture (PNG)")
    at: datetime = Field(default_factory=utcnow)


# --------------------------------------------------------------------------------------- jobs
class Job(SQLModel, table=True):
    """One piece of long work (localisation, sheet alignment, calibration, rotary run) and where it is.

    ``args`` holds ids and small parameters only (images are in the file store by sha256); ``attempts``
    counts the starts and is the claim token: a run that lost its claim (timed out, or its worker was
    declared dead and another took the job) cannot finish the row. ``heartbeat_at`` is renewed while
    it runs; a stale one means its worker died."""

    __tablename__ = "job"
    id: int | None = Field(default=None, primary_key=True)
    kind: str = Field(max_length=40, index=True, description="localize | sheet_align | calibrate | rotary")
    args: dict = json_field(default_factory=dict, nullable=False)
    status: str = Field(default="queued", max_length=20, index=True, description="queued | running | done | failed")
    reason: str = Field(default="", max_length=2000)
    result: dict | None = json_field(description="what the job made: {resource, id, url}")
    attempts: int = 0
    max_attempts: int = 3
    timeout_s: float = 600.0
    worker: str | None = Field(default=None, max_length=200, description="host:pid/thread of the current run")
    heartbeat_at: datetime | None = None
    started_at: datetime | None = None
    finished_at: datetime | None = None
    created_by: str | None = Field(default=None, max_length=200)
    created_at: datetime = Field(default_factory=utcnow)
    updated_at: datetime = Field(default_factory=utcnow)
