"""/api/v1/machines: machine tools with their table, cameras and controller settings."""

from __future__ import annotations

from datetime import datetime
from typing import Any

from fastapi import APIRouter, Depends, Response, status
from pydantic import BaseModel, Field

from app.api.deps import AdminPrincipal, SessionDep, SettingsDep, get_principal
from app.machine.settings import RotaryAxisSettings
from app.services import machines as svc
from app.services.audit import audit

router = APIRouter(prefix="/machines", tags=["machines"], dependencies=[Depends(get_principal)])

IDENTITY = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
CONTROLLER_DOC = ('{"kind": "linuxcnc", "host": "127.0.0.1", "port": 5007} | '
                  '{"kind": "opcua", "endpoint": "opc.tcp://...", "nodes": {...}} | '
                  '{"kind": "file", "dialect": "heidenhain", "folder": "/srv/nc"}')


class Travel(BaseModel):
    x: list[float] = Field(min_length=2, max_length=2, examples=[[0, 1000]])
    y: list[float] = Field(min_length=2, max_length=2, examples=[[0, 500]])
    z: list[float] = Field(min_length=2, max_length=2, examples=[[-500, 0]])


def _limit(name: str, what: str) -> Any:
    """An optional per-machine limit: finite, within the service's bounds; null = the global setting."""
    return Field(default=None, allow_inf_nan=False, **svc.LIMIT_BOUNDS[name],
                 description=f"{what}; null: the global setting {svc.setting_name(name)}")


TILT_DOC = "Residual tilt (°) a 3-axis work offset may ignore on this machine; above it export is refused"
CHANGE_MM_DOC = "X/Y/Z change (mm) against the controller's current slot that needs no acknowledgement"
CHANGE_DEG_DOC = "C change (°) against the controller's current slot that needs no acknowledgement"
ROTARY_DOC = ("The rotary axis carrying the table (C about Z, A/B trunnion): T_machine_table(angle) = "
              "T_machine_axis @ R(angle) @ T_axis_table; with one, T_machine_table is that chain at export_at_deg. "
              "null: the table does not turn")


class MachineCreate(BaseModel):
    name: str = Field(min_length=1, max_length=200, examples=["Mill 3"])
    table_model_id: int = Field(description="A library model of kind table with a fiducial layout")
    table_revision: int | None = Field(default=None, description="Default: the model's current revision")
    T_machine_table: list[list[float]] = Field(default_factory=lambda: IDENTITY,
                                               description="Pose of the table frame in machine coordinates, mm "
                                                           "(with a rotary axis: derived from it, may be left out)")
    travel_mm: Travel
    camera_ids: list[int] = Field(default_factory=list)
    controller: dict[str, Any] | None = Field(default=None, description=CONTROLLER_DOC)
    max_tilt_deg: float | None = _limit("max_tilt_deg", TILT_DOC)
    max_offset_change_mm: float | None = _limit("max_offset_change_mm", CHANGE_MM_DOC)
    max_offset_change_deg: float | None = _limit("max_offset_change_deg", CHANGE_DEG_DOC)
    rotary_axis: RotaryAxisSettings | None = Field(default=None, description=ROTARY_DOC)


class MachineUpdate(BaseModel):
    name: str | None = Field(default=None, min_length=1, max_length=200)
    table_model_id: int | None = None
    table_revision: int | None = None
    T_machine_table: list[list[float]] | None = None
    travel_mm: Travel | None = None
    camera_ids: list[int] | None = None
    controller: dict[str, Any] | None = Field(default=None, description=CONTROLLER_DOC)
    max_tilt_deg: float | None = _limit("max_tilt_deg", TILT_DOC)
    max_offset_change_mm: float | None = _limit("max_offset_change_mm", CHANGE_MM_DOC)
    max_offset_change_deg: float | None = _limit("max_offset_change_deg", CHANGE_DEG_DOC)
    rotary_axis: RotaryAxisSettings | None = Field(default=None, description=ROTARY_DOC)


class MachinePublic(BaseModel):
    id: int
    name: str
    table_model_id: int
    table_revision: int
    T_machine_table: list[list[float]]
    travel_mm: dict
    camera_ids: list[int]
    controller: dict | None
    max_tilt_deg: float | None = Field(description=f"{TILT_DOC}; null: the global setting")
    max_offset_change_mm: float | None = Field(description=f"{CHANGE_MM_DOC}; null: the global setting")
    max_offset_change_deg: float | None = Field(description=f"{CHANGE_DEG_DOC}; null: the global setting")
    rotary_axis: RotaryAxisSettings | None = Field(default=None, description=ROTARY_DOC)
    created_at: datetime


class LimitDefault(BaseModel):
    value: float = Field(description="mm or ° as the name says")
    setting: str = Field(description="the environment variable it is read from")


def _public(m) -> MachinePublic:
    """Controller passwords never leave the service."""
    pub = MachinePublic.model_validate(m, from_attributes=True)
    if pub.controller:
        pub.controller = {k: (svc.MASK if k in svc.SECRET_KEYS and v else v) for k, v in pub.controller.items()}
    return pub


@router.post("", status_code=status.HTTP_201_CREATED, response_model=MachinePublic, summary="Register a machine")
def create_machine(session: SessionDep, admin: AdminPrincipal, body: MachineCreate) -> MachinePublic:
    fields = body.model_dump()
    if "T_machine_table" not in body.model_fields_set:
        fields["T_machine_table"] = None  # the identity, or the rotary axis' chain at its export angle
    m = svc.create_machine(session, **fields)
    audit(session, admin.label(), "machine.create", machine_id=m.id, name=m.name)
    return _public(m)


@router.get("/default-limits", response_model=dict[str, LimitDefault],
            summary="The global limits a machine without its own uses (max tilt, offset change)")
def default_limits(settings: SettingsDep) -> dict[str, LimitDefault]:
    return {name: LimitDefault(value=getattr(settings, name), setting=svc.setting_name(name))
            for name in svc.LIMIT_BOUNDS}


@router.get("", response_model=list[MachinePublic], summary="List machines")
def list_machines(session: SessionDep) -> list[MachinePublic]:
    return [_public(m) for m in svc.list_machines(session)]


@router.get("/{machine_id}", response_model=MachinePublic, summary="One machine")
def get_machine(session: SessionDep, machine_id: int) -> MachinePublic:
    return _public(svc.get_machine(session, machine_id))


@router.patch("/{machine_id}", response_model=MachinePublic, summary="Change a machine")
def update_machine(session: SessionDep, admin: AdminPrincipal, machine_id: int, body: MachineUpdate) -> MachinePublic:
    changes = body.model_dump(exclude_unset=True)
    m = svc.update_machine(session, machine_id, changes)
    audit(session, admin.label(), "machine.update", machine_id=m.id, changed=sorted(changes),
          travel_mm=m.travel_mm, T_machine_table=m.T_machine_table,
          limits={name: getattr(m, name) for name in svc.LIMIT_BOUNDS}, rotary_axis=m.rotary_axis)
    return _public(m)


class OffsetPublic(BaseModel):
    slot: str
    x_mm: float
    y_mm: float
    z_mm: float
    c_deg: float


@router.get("/{machine_id}/offsets/{slot}", response_model=OffsetPublic,
            summary="The controller's current work offset in a slot (read live)",
            responses={502: {"description": "controller unreachable"}})
def read_offset(session: SessionDep, machine_id: int, slot: str) -> OffsetPublic:
    from app.services.export import read_current_offset

    return OffsetPublic(slot=slot.upper(), **read_current_offset(session, machine_id, slot.upper()).as_dict())


class PositionPublic(BaseModel):
    x_mm: float = Field(description="tool tip, machine coordinates")
    y_mm: float
    z_mm: float
    tool_offset_mm: list[float] = Field(description="the active tool length offset (x, y, z) taken off, mm")


@router.get("/{machine_id}/position", response_model=PositionPublic,
            summary="Where the tool tip is now, in machine coordinates (read live from the controller)",
            responses={409: {"description": "this controller cannot report its position (code position_unavailable)"},
                       502: {"description": "controller unreachable"}})
def read_position(session: SessionDep, machine_id: int) -> PositionPublic:
    return PositionPublic(**svc.read_position(session, machine_id).as_dict())


class AxisPublic(BaseModel):
    name: str = Field(description="the rotary axis: A, B or C")
    angle_deg: float = Field(description="its position now, machine coordinates, degrees")


@router.get("/{machine_id}/rotary-axis", response_model=AxisPublic,
            summary="Where the machine's rotary table axis is now (read live from the controller)",
            responses={409: {"description": "no rotary axis, or the controller cannot report it"},
                       502: {"description": "controller unreachable"}})
def read_rotary_axis(session: SessionDep, machine_id: int) -> AxisPublic:
    name, angle = svc.read_table_angle(session, machine_id)
    return AxisPublic(name=name, angle_deg=angle)


#: a machine position beyond this is a typing error (no machine tool's axis is 100 m long)
_MM = {"ge": -svc.MAX_TRAVEL_MM, "le": svc.MAX_TRAVEL_MM, "allow_inf_nan": False}


class JoggedPoint(BaseModel):
    x_mm: float = Field(**_MM)
    y_mm: float = Field(**_MM)
    z_mm: float | None = Field(default=None, **_MM)

    def xyz(self) -> list[float]:
        return [self.x_mm, self.y_mm] + ([] if self.z_mm is None else [self.z_mm])


class TableFrameRequest(BaseModel):
    table_model_id: int
    table_revision: int | None = None
    corner: JoggedPoint = Field(description="1: the table's front-left top corner (its origin), Z required")
    x_edge: JoggedPoint | None = Field(default=None, description="2: a point on the front (x) edge")
    y_edge: JoggedPoint | None = Field(default=None, description="3: a point on the left (y) edge")
    c_deg: float | None = Field(default=None, ge=-360, le=360, allow_inf_nan=False,
                                description="C as typed (degrees), used only without edge points")


class TableFramePublic(BaseModel):
    T_machine_table: list[list[float]]
    x_mm: float
    y_mm: float
    z_mm: float
    c_deg: float
    notes: list[str]
    edge_disagreement_deg: float | None
    c_sensitivity_deg_per_mm: float | None
    svg: str = Field(description="top view of the table at this pose with its frame and the points (SVG)")


@router.post("/table-frame", response_model=TableFramePublic,
             summary="T_machine_table from jogged points of the table (corner, front edge, left edge), with a picture")
def table_frame(session: SessionDep, body: TableFrameRequest) -> TableFramePublic:
    return TableFramePublic(**svc.table_frame(
        session, table_model_id=body.table_model_id, table_revision=body.table_revision, corner=body.corner.xyz(),
        x_point=body.x_edge.xyz() if body.x_edge else None, y_point=body.y_edge.xyz() if body.y_edge else None,
        c_deg=body.c_deg))


@router.delete("/{machine_id}", status_code=status.HTTP_204_NO_CONTENT, response_class=Response,
               summary="Remove a machine (soft delete)")
def delete_machine(session: SessionDep, admin: AdminPrincipal, machine_id: int) -> Response:
    svc.delete_machine(session, machine_id)
    audit(session, admin.label(), "machine.delete", machine_id=machine_id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)
