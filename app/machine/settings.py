"""A machine's controller settings: pydantic models the API validates with, and the factory.

    {"kind": "linuxcnc", "host": "127.0.0.1", "port": 5007}
    {"kind": "opcua", "endpoint": "opc.tcp://10.0.0.5:4840",
     "nodes": {"x": "ns=2;s={slot}.X", "y": "ns=2;s={slot}.Y", "z": "ns=2;s={slot}.Z", "c": "ns=2;s={slot}.C"},
     "method": {"object": "ns=2;s=MachineTool", "method": "ns=2;s=SetWorkOffset",
                "args": ["slot", "x", "y", "z", "c"]}}          # method optional; nodes are read back
    {"kind": "file", "dialect": "heidenhain", "folder": "/mnt/tnc/setupcam"}
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, StringConstraints, TypeAdapter, ValidationError, field_validator, \
    model_validator

from app.machine.base import Controller, slot_number

#: an OPC UA node id in string form (ns=2;s=..., ns=3;i=42, nsu=urn:...;s=...), may hold {slot}/{p}
NodeIdText = Annotated[str, StringConstraints(strip_whitespace=True, pattern=r"^(ns=\d+;|nsu=[^;]+;)?[isgb]=.+$")]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class LinuxCncSettings(_Strict):
    """LinuxCNC reached through ``linuxcncrsh`` (its TCP text protocol)."""

    kind: Literal["linuxcnc"]
    host: str = Field(min_length=1, description="host name or address of the LinuxCNC computer")
    port: int = Field(5007, ge=1, le=65535, description="linuxcncrsh port")
    connect_password: str = Field("EMC", description="linuxcncrsh connect password (hello)")
    enable_password: str = Field("EMCTOO", description="linuxcncrsh enable password")
    timeout_s: float = Field(5.0, gt=0, le=120)


class OpcUaNodes(_Strict):
    x: NodeIdText
    y: NodeIdText
    z: NodeIdText
    c: NodeIdText | None = Field(None, description="rotation about Z; None: the machine takes no rotation")


class OpcUaPositionNodes(_Strict):
    """Where the machine reports its position: x, y, z of the tool tip in machine coordinates, mm."""

    x: NodeIdText
    y: NodeIdText
    z: NodeIdText


class OpcUaMethodSettings(_Strict):
    object: NodeIdText
    method: NodeIdText
    args: list[Literal["slot", "p", "x", "y", "z", "c"]] = Field(default_factory=lambda: ["x", "y", "z", "c"])


class OpcUaControllerSettings(_Strict):
    """An OPC UA server with writable X/Y/Z/C variables, or a method to call (variables are read back)."""

    kind: Literal["opcua"]
    endpoint: str = Field(pattern=r"^opc\.tcp://[^/\s]+", description="opc.tcp://host:port/path")
    nodes: OpcUaNodes
    method: OpcUaMethodSettings | None = None
    slot: str = Field("G54", description="the one slot, when node ids carry no {slot} or {p}")
    timeout_s: float = Field(5.0, gt=0, le=120)
    rounding_mm: float = Field(1e-6, gt=0, le=0.1)
    rounding_deg: float = Field(1e-6, gt=0, le=0.1)
    username: str | None = None
    password: str | None = None
    pause_method: OpcUaMethodSettings | None = None
    stop_method: OpcUaMethodSettings | None = None
    position_nodes: OpcUaPositionNodes | None = Field(
        None, description="tool tip position in machine coordinates (mm), for Read position on the machines page")

    @field_validator("slot")
    @classmethod
    def _known_slot(cls, v: str) -> str:
        slot_number(v)
        return v.upper()

    @model_validator(mode="after")
    def _method_has_xyz(self):
        if self.method is not None:
            missing = [a for a in ("x", "y", "z") if a not in self.method.args]
            if missing:
                raise ValueError(f"method args must include x, y and z; missing {', '.join(missing)}")
            if "c" not in self.method.args and self.nodes.c is not None:
                raise ValueError("nodes.c is set but the method takes no c argument")
        return self


class FileControllerSettings(_Strict):
    """NC files dropped into a folder the control reads (no live link, no read-back from the control)."""

    kind: Literal["file"]
    dialect: Literal["heidenhain", "fanuc", "siemens", "linuxcnc"]
    folder: str = Field(min_length=1)


ControllerSettings = Annotated[
    Union[LinuxCncSettings, OpcUaControllerSettings, FileControllerSettings], Field(discriminator="kind")
]
_ADAPTER = TypeAdapter(ControllerSettings)
KINDS = ("linuxcnc", "opcua", "file")


def parse_controller_settings(settings: dict | BaseModel) -> LinuxCncSettings | OpcUaControllerSettings | \
        FileControllerSettings:
    """Validate a settings dict; ValueError with every reason in one sentence when it is not valid."""
    if isinstance(settings, (LinuxCncSettings, OpcUaControllerSettings, FileControllerSettings)):
        return settings
    if not isinstance(settings, dict):
        raise ValueError(f"controller settings must be an object, got {type(settings).__name__}")
    kind = settings.get("kind")
    if kind not in KINDS:
        raise ValueError(f"controller settings: kind must be one of {', '.join(KINDS)}, got {kind!r}")
    try:
        return _ADAPTER.validate_python(settings)
    except ValidationError as exc:
        reasons = []
        for e in exc.errors():
            where = ".".join(str(p) for p in e["loc"][1:]) or "settings"
            reasons.append(f"{where}: {e['msg'].removeprefix('Value error, ')}")
        raise ValueError(f"{kind} controller settings are not valid: {'; '.join(reasons)}") from None


def make_controller(settings: dict | BaseModel) -> Controller:
    """The adapter for a machine's controller settings (see module docstring). Raises ValueError."""
    s = parse_controller_settings(settings)
    if isinstance(s, LinuxCncSettings):
        from app.machine.linuxcnc import LinuxCncController

        return LinuxCncController(s.host, s.port, connect_password=s.connect_password,
                                  enable_password=s.enable_password, timeout_s=s.timeout_s)
    if isinstance(s, OpcUaControllerSettings):
        from app.machine.opcua import OpcUaController, OpcUaMethod, OpcUaSettings

        def method(m):
            return None if m is None else OpcUaMethod(m.object, m.method, tuple(m.args))

        return OpcUaController(OpcUaSettings(
            endpoint=s.endpoint, nodes=s.nodes.model_dump(), method=method(s.method), slot=s.slot,
            timeout_s=s.timeout_s, rounding_mm=s.rounding_mm, rounding_deg=s.rounding_deg,
            username=s.username, password=s.password,
            pause_method=method(s.pause_method), stop_method=method(s.stop_method),
            position_nodes=s.position_nodes.model_dump() if s.position_nodes else None))
    from app.machine.nc_files import FileController

    return FileController(s.dialect, s.folder)


# ------------------------------------------------------------------ a rotary table in the kinematic chain
Matrix4 = list[list[float]]
#: no rotary axis or table lies 100 m from the machine's origin
MAX_POSE_MM = 100_000.0


class RotaryAxisSettings(_Strict):
    """The rotary axis that carries the table (app/geometry/rotary_chain.py):
    ``T_machine_table(angle) = T_machine_axis @ R(angle) @ T_axis_table``, R about the axis frame's x (A),
    y (B) or z (C). ``angle_from``: where the angle at a picture comes from (read from the controller, or
    typed by the operator); ``export_at_deg``: the angle the NC program expects the offset at."""

    name: Literal["A", "B", "C"] = Field(description="the axis' name on the controller: C about Z, A about X, B about Y")
    T_machine_axis: Matrix4 = Field(description="pose of the axis frame in machine coordinates, mm: its origin on "
                                                "the axis, its x (A) / y (B) / z (C) along it, positive angles "
                                                "turning the table right-handed about that direction")
    T_axis_table: Matrix4 = Field(description="pose of the table frame in the axis frame at angle 0, mm")
    angle_from: Literal["controller", "operator"] = Field(
        "controller", description="controller: the service reads the axis when the picture is taken; "
                                  "operator: the operator types the angle with the picture")
    export_at_deg: float = Field(0.0, ge=-360.0, le=360.0, allow_inf_nan=False,
                                 description="the axis angle at which the NC program expects the work offset, °")

    @field_validator("T_machine_axis", "T_axis_table")
    @classmethod
    def _rigid(cls, v: Matrix4, info) -> Matrix4:
        from app.geometry.transforms import PoseError, check_pose

        try:
            T = check_pose(v, info.field_name, tol=1e-5)
        except PoseError as exc:
            raise ValueError(f"must be a rigid 4x4 pose in mm ({exc})") from None
        if abs(T[:3, 3]).max() > MAX_POSE_MM:  # a typing error (and beyond, the chain's sums overflow)
            raise ValueError(f"translation {T[:3, 3].tolist()} mm is more than {MAX_POSE_MM / 1000:g} m from the origin")
        return T.tolist()


def parse_rotary_axis(value: dict | BaseModel | None) -> RotaryAxisSettings | None:
    """Validate a machine's ``rotary_axis`` (None: the table does not turn); ValueError with every reason."""
    if value is None or isinstance(value, RotaryAxisSettings):
        return value
    if isinstance(value, BaseModel):
        value = value.model_dump()
    try:
        return RotaryAxisSettings.model_validate(value)
    except ValidationError as exc:
        reasons = [f"{'.'.join(str(p) for p in e['loc']) or 'rotary_axis'}: {e['msg'].removeprefix('Value error, ')}"
                   for e in exc.errors()]
        raise ValueError(f"rotary_axis is not valid: {'; '.join(reasons)}") from None


def rotary_chain(value: dict | BaseModel | None):
    """The :class:`app.geometry.rotary_chain.RotaryChain` of a machine's ``rotary_axis`` (None without one)."""
    from app.geometry.rotary_chain import RotaryChain

    s = parse_rotary_axis(value)
    return None if s is None else RotaryChain(s.name, s.T_machine_axis, s.T_axis_table)
