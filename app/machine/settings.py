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
