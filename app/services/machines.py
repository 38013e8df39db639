"""Machine use cases: a machine = table model (with fiducials) + T_machine_table + travel + cameras + controller."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from sqlmodel import Session, col, select

from app.config import Settings
from app.geometry.table_figure import table_figure_svg
from app.geometry.table_frame import TableFrameError, table_frame_from_points
from app.geometry.transforms import PoseError, check_pose
from app.machine import ControllerError, PositionUnavailable, make_controller, parse_controller_settings
from app.machine.settings import parse_rotary_axis, rotary_chain
from app.services import library
from app.services.errors import Conflict, Invalid, NotFound, Unavailable
from app.store.models import Camera, Machine, utcnow


MAX_TRAVEL_MM = 100_000.0  # 100 m: more than any machine tool's axis
NOT_NULL = ("name", "table_model_id", "T_machine_table", "travel_mm", "camera_ids")


def validate_travel(travel: dict) -> dict:
    out = {}
    for axis in ("x", "y", "z"):
        lim = travel.get(axis)
        if lim is None or len(lim) != 2:
            raise Invalid(f"travel_mm.{axis}: give [min, max] in mm")
        lo, hi = float(lim[0]), float(lim[1])
        if not (math.isfinite(lo) and math.isfinite(hi)) or max(abs(lo), abs(hi)) > MAX_TRAVEL_MM:
            # an infinite limit would switch the travel check of every export off
            raise Invalid(f"travel_mm.{axis}: limits must be finite numbers within ±{MAX_TRAVEL_MM:.0f} mm, "
                          f"got [{lo}, {hi}]")
        if not lo < hi:
            raise Invalid(f"travel_mm.{axis}: min {lo} must be below max {hi}")
        out[axis] = [lo, hi]
    return out


# ------------------------------------------------------------------ limits: the machine's own or the global one
#: the pydantic bounds of each per-machine limit: a tilt beyond 10° is no "small residual" a 3-axis offset may
#: ignore (17 mm error 100 mm from the datum); a change limit must be positive (0 would refuse even a
#: re-export of the same offset) and below 1 m / a half turn (above, it would never ask)
LIMIT_BOUNDS: dict[str, dict[str, float]] = {
    "max_tilt_deg": {"ge": 0.0, "le": 10.0},
    "max_offset_change_mm": {"gt": 0.0, "le": 1000.0},
    "max_offset_change_deg": {"gt": 0.0, "le": 180.0},
}
LIMIT_UNITS = {"max_tilt_deg": "°", "max_offset_change_mm": " mm", "max_offset_change_deg": "°"}


def setting_name(limit: str) -> str:
    """The environment variable of a global limit, e.g. SETUPCAM_MAX_TILT_DEG."""
    return str(Settings.model_fields[limit].validation_alias)


@dataclass(frozen=True)
class Limit:
    """A limit in force on a machine: ``value`` (mm or degrees, see LIMIT_UNITS) and ``source``, where it
    comes from in words ("machine 'Mill 3'" or "the global setting SETUPCAM_MAX_TILT_DEG") for refusals."""

    name: str
    value: float
    source: str


def machine_limit(machine: Machine, settings: Settings, name: str) -> Limit:
    """The machine's own ``name`` limit when it has one, else the global setting's."""
    own = getattr(machine, name, None)
    if own is not None:
        return Limit(name, float(own), f"machine '{machine.name}'")
    return Limit(name, float(getattr(settings, name)), f"the global setting {setting_name(name)}")


def validate_limit(name: str, value: Any) -> float | None:
    """A per-machine limit as stored (None: use the global setting); Invalid when it is not a finite
    number within LIMIT_BOUNDS (the REST schema checks the same; this guards other callers)."""
    if value is None:
        return None
    b, unit = LIMIT_BOUNDS[name], LIMIT_UNITS[name]
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = math.nan  # refused below with the same sentence
    low_ok = v >= b["ge"] if "ge" in b else v > b["gt"]
    if not (math.isfinite(v) and low_ok and v <= b["le"]):
        low = f">= {b['ge']:g}" if "ge" in b else f"> {b['gt']:g}"
        raise Invalid(f"{name}: must be a number {low} and <= {b['le']:g}{unit} (empty: use "
                      f"{setting_name(name)}), got {value}")
    return v


#: controller settings the API never shows (answered as MASK)
SECRET_KEYS = ("password", "connect_password", "enable_password")
MASK = "***"


def keep_masked_secrets(new: dict | None, old: dict | None) -> dict | None:
    """A settings dict sent back as it was read has MASK for each secret: keep the stored value then
    (same controller kind only), so editing a machine never turns its password into "***"."""
    if not new or not old or new.get("kind") != old.get("kind"):
        return new
    return {k: (old.get(k) if k in SECRET_KEYS and v == MASK else v) for k, v in new.items()}


def validate_controller(controller: dict | None) -> dict | None:
    if controller is None:
        return None
    try:
        return parse_controller_settings(controller).model_dump(mode="json")
    except ValueError as exc:
        raise Invalid(f"controller: {exc}") from None


# ------------------------------------------------------------------ a rotary table in the kinematic chain
#: the controller kinds that report a rotary axis' position (Controller.read_axis_deg)
AXIS_READING_KINDS = ("linuxcnc",)
#: the largest difference (mm, and the same in 1e-3 of a radian) a T_machine_table sent along with a rotary
#: axis may have from the chain at the export angle it is derived from
DERIVED_POSE_TOL = 1e-3


def validate_rotary_axis(value: Any) -> dict | None:
    """A machine's ``rotary_axis`` as stored (None: the table does not turn); Invalid with every reason."""
    try:
        s = parse_rotary_axis(value)
    except ValueError as exc:
        raise Invalid(str(exc)) from None
    return None if s is None else s.model_dump(mode="json")


def table_pose_at(machine: Machine, angle_deg: float | None = None) -> np.ndarray:
    """``T_machine_table`` (4x4, mm) of ``machine`` with its rotary axis at ``angle_deg`` (None: the export
    angle); the fixed ``T_machine_table`` of a machine whose table does not turn, whatever the angle."""
    chain = rotary_chain(machine.rotary_axis)
    if chain is None:
        return np.asarray(machine.T_machine_table, float)
    return chain.T_machine_table(machine.rotary_axis["export_at_deg"] if angle_deg is None else angle_deg)


def picture_turn(machine: Machine, angle_deg: float | None) -> tuple[np.ndarray, np.ndarray] | None:
    """How the 3D view shows the table of a picture taken with the rotary axis at ``angle_deg``: the table's
    pose at that angle seen from the table at the export angle (the view's world), 4x4 mm, and the axis of
    rotation in that world as two points 500 mm either side of the axis frame's origin, (2, 3) mm. None
    on a machine whose table does not turn, or when no angle was recorded."""
    chain = rotary_chain(machine.rotary_axis)
    if chain is None or angle_deg is None:
        return None
    export = machine.rotary_axis["export_at_deg"]
    T_world_machine = np.linalg.inv(chain.T_machine_table(export))
    ends = [chain.axis_point() + k * 500.0 * chain.axis_direction() for k in (-1.0, 1.0)]
    axis = np.array([T_world_machine[:3, :3] @ p + T_world_machine[:3, 3] for p in ends])
    return chain.turn(export, angle_deg), axis


def _keep_chain_in_step(m: Machine, given_pose: Any) -> None:
    """With a rotary axis ``T_machine_table`` is the chain at ``export_at_deg`` (what every offset, travel
    check and probing plan uses); a pose given along must be that one (Invalid otherwise), and the axis'
    ``angle_from`` must be one the controller can serve."""
    if not m.rotary_axis:
        return
    derived = table_pose_at(m)
    if given_pose is not None:
        given = np.asarray(_pose(given_pose))
        if np.max(np.abs(given[:3, 3] - derived[:3, 3])) > DERIVED_POSE_TOL or \
                np.max(np.abs(given[:3, :3] - derived[:3, :3])) > DERIVED_POSE_TOL:
            raise Invalid(f"T_machine_table: with a rotary axis the table's pose follows the axis "
                          f"(T_machine_axis @ R{m.rotary_axis['name']}({m.rotary_axis['export_at_deg']:g}°) @ "
                          f"T_axis_table = {np.round(derived, 4).tolist()}); leave T_machine_table out or send that one",
                          code="table_pose_follows_axis")
    m.T_machine_table = derived.tolist()
    kind = (m.controller or {}).get("kind")
    if m.rotary_axis["angle_from"] == "controller" and kind not in AXIS_READING_KINDS:
        raise Invalid(f"rotary_axis.angle_from: 'controller' needs a controller that reports the "
                      f"{m.rotary_axis['name']} axis ({', '.join(AXIS_READING_KINDS)}); this machine has "
                      f"{f'a {kind} controller' if kind else 'no controller'}: use 'operator' (the operator types "
                      "the angle with each picture)", code="angle_not_readable")


def read_table_angle(session: Session, machine_id: int) -> tuple[str, float]:
    """(axis name, degrees) of the machine's rotary axis now, read from its controller (machine coordinates):
    409 (``no_rotary_axis``, ``position_unavailable``) when there is none or the controller cannot tell, 502
    when it does not answer."""
    m = get_machine(session, machine_id)
    if not m.rotary_axis:
        raise Conflict(f"machine {m.id} ({m.name}) has no rotary axis", code="no_rotary_axis")
    if not m.controller:
        raise Conflict(f"machine {m.id} ({m.name}) has no controller saved; type the angle the controller shows",
                       code="no_controller")
    name = m.rotary_axis["name"]
    controller = make_controller(m.controller)
    try:
        return name, controller.read_axis_deg(name)
    except PositionUnavailable as exc:
        raise Conflict(str(exc), code="position_unavailable") from None
    except ControllerError as exc:
        raise Unavailable(f"reading the {name} axis: {exc}") from None
    finally:
        controller.close()


def _check_table(session: Session, table_model_id: int, table_revision: int | None) -> int:
    model = library.get_model(session, table_model_id, include_deleted=False)
    if model.kind != "table":
        raise Invalid(f"model {table_model_id} ({model.name}) is a {model.kind}, not a table")
    rev = library.get_revision(session, table_model_id, table_revision)
    if not rev.fiducials:
        raise Invalid(f"table model {table_model_id} revision {rev.revision} has no fiducial layout; "
                      "add one (POST /api/v1/models/{id}/revisions with fiducials) before using it on a machine")
    return rev.revision


def _check_cameras(session: Session, camera_ids: list[int]) -> list[int]:
    for cid in camera_ids:
        cam = session.get(Camera, cid)
        if cam is None or cam.deleted_at is not None:
            raise Invalid(f"camera {cid} not found")
    return list(camera_ids)


def _pose(value: Any) -> list[list[float]]:
    try:
        return check_pose(value, "T_machine_table", tol=1e-5).tolist()
    except PoseError as exc:
        raise Invalid(str(exc)) from None


def create_machine(session: Session, *, name: str, table_model_id: int, table_revision: int | None,
                   T_machine_table: Any, travel_mm: dict, camera_ids: list[int], controller: dict | None,
                   rotary_axis: Any = None, **limits: float | None) -> Machine:
    """A new machine; ``limits``: any of LIMIT_BOUNDS' names (None or left out: the global setting).
    ``T_machine_table`` None: the identity, or with ``rotary_axis`` the chain at its export angle."""
    unknown = set(limits) - set(LIMIT_BOUNDS)
    if unknown:
        raise Invalid(f"unknown machine field(s): {', '.join(sorted(unknown))}")
    rotary = validate_rotary_axis(rotary_axis)
    m = Machine(name=name, table_model_id=table_model_id,
                table_revision=_check_table(session, table_model_id, table_revision),
                T_machine_table=_pose(np.eye(4) if T_machine_table is None else T_machine_table),
                travel_mm=validate_travel(travel_mm),
                camera_ids=_check_cameras(session, camera_ids), controller=validate_controller(controller),
                rotary_axis=rotary, **{k: validate_limit(k, v) for k, v in limits.items()})
    _keep_chain_in_step(m, T_machine_table)
    session.add(m)
    session.flush()
    return m


def get_machine(session: Session, machine_id: int) -> Machine:
    m = session.get(Machine, machine_id)
    if m is None or m.deleted_at is not None:
        raise NotFound(f"machine {machine_id} not found")
    return m


def list_machines(session: Session) -> list[Machine]:
    return list(session.exec(select(Machine).where(col(Machine.deleted_at).is_(None)).order_by(Machine.id)).all())


def update_machine(session: Session, machine_id: int, changes: dict[str, Any]) -> Machine:
    m = get_machine(session, machine_id)
    for key in NOT_NULL:
        if key in changes and changes[key] is None:
            raise Invalid(f"{key}: must not be null (leave it out to keep the current value)")
    if "name" in changes:
        m.name = changes["name"]
    if "table_model_id" in changes or "table_revision" in changes:
        tid = changes.get("table_model_id", m.table_model_id)
        m.table_revision = _check_table(session, tid, changes.get("table_revision"))
        m.table_model_id = tid
    if "T_machine_table" in changes:
        m.T_machine_table = _pose(changes["T_machine_table"])
    if "travel_mm" in changes:
        m.travel_mm = validate_travel(changes["travel_mm"])
    if "camera_ids" in changes:
        m.camera_ids = _check_cameras(session, changes["camera_ids"])
    if "controller" in changes:
        m.controller = validate_controller(keep_masked_secrets(changes["controller"], m.controller))
    for name in LIMIT_BOUNDS:
        if name in changes:  # null: back to the global setting
            setattr(m, name, validate_limit(name, changes[name]))
    if "rotary_axis" in changes:  # null: the table stops turning, its pose stays where the chain put it
        m.rotary_axis = validate_rotary_axis(changes["rotary_axis"])
    _keep_chain_in_step(m, changes.get("T_machine_table"))
    session.add(m)
    session.flush()
    return m


def delete_machine(session: Session, machine_id: int) -> None:
    m = get_machine(session, machine_id)
    m.deleted_at = utcnow()
    session.add(m)


def read_position(session: Session, machine_id: int):
    """Where the machine's tool tip is now (MachinePosition, machine coordinates, mm), read from its
    saved controller: 409 (code ``position_unavailable``) when that kind of controller cannot tell,
    502 when it does not answer."""
    m = get_machine(session, machine_id)
    if not m.controller:
        raise Conflict(f"machine {m.id} ({m.name}) has no controller saved; type the position the controller shows",
                       code="no_controller")
    controller = make_controller(m.controller)
    try:
        return controller.read_position()
    except PositionUnavailable as exc:
        raise Conflict(str(exc), code="position_unavailable") from None
    except ControllerError as exc:
        raise Unavailable(str(exc)) from None
    finally:
        controller.close()


def table_frame(session: Session, *, table_model_id: int, table_revision: int | None, corner,
                x_point=None, y_point=None, c_deg: float | None = None) -> dict:
    """T_machine_table from jogged points (see app/geometry/table_frame.py) and a top-view SVG of the
    table model where that puts it, with its markers and the points."""
    model = library.get_model(session, table_model_id, include_deleted=False)
    if model.kind != "table":
        raise Invalid(f"model {table_model_id} ({model.name}) is a {model.kind}, not a table")
    rev = library.get_revision(session, table_model_id, table_revision)
    try:
        fit = table_frame_from_points(corner, x_point, y_point, c_deg)
    except TableFrameError as exc:
        raise Invalid(str(exc)) from None
    lo, hi = rev.summary.get("bbox_min_mm"), rev.summary.get("bbox_max_mm")
    if not lo or not hi:
        raise Invalid(f"table model {table_model_id} revision {rev.revision} has no extent on record")
    markers = [(m["id"], (m["T_table_marker"][0][3], m["T_table_marker"][1][3]), m["size_mm"])
               for m in (rev.fiducials or {}).get("markers", [])]
    points = [(label, p[:2]) for label, p in (("1", corner), ("2", x_point), ("3", y_point)) if p is not None]
    T = fit.T_machine_table
    return {"T_machine_table": T.tolist(), "x_mm": float(T[0, 3]), "y_mm": float(T[1, 3]), "z_mm": float(T[2, 3]),
            "c_deg": fit.c_deg, "notes": list(fit.notes), "edge_disagreement_deg": fit.edge_disagreement_deg,
            "c_sensitivity_deg_per_mm": fit.c_sensitivity_deg_per_mm,
            "svg": table_figure_svg(lo, hi, T, markers=markers, points=points, title=f"{model.name} on the machine")}
