"""The one small interface every controller adapter implements.

A work offset here is the pose of the NC program zero (``datum``) in machine coordinates, reduced
to what a 3-axis controller stores in a work-offset slot: X, Y, Z in mm and a rotation C in degrees
about the machine Z axis (``T_machine_datum = [Rz(C) | (X, Y, Z)]``). A program point ``p_datum``
lands at ``p_machine = Rz(C) @ p_datum + (X, Y, Z)``; positive C turns the datum's x axis from
machine +X towards machine +Y (counter-clockwise seen from +Z). Each adapter maps this to its
controller's own words and signs (see docs/controller-conventions.md).

The interface is synchronous on purpose: the service calls it from a worker, once per export.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

#: Work-offset slot names and their G10 L2 ``P`` numbers (the LinuxCNC / Fanuc numbering).
SLOT_P_NUMBERS: dict[str, int] = {
    "G54": 1, "G55": 2, "G56": 3, "G57": 4, "G58": 5, "G59": 6,
    "G59.1": 7, "G59.2": 8, "G59.3": 9,
}


class ControllerError(RuntimeError):
    """A controller could not do what was asked; the message is one plain sentence that names the
    controller and what went wrong, e.g. ``"LinuxCNC at 127.0.0.1:5007: connection refused"``."""


class NoOffsetYet(ControllerError):
    """The controller answered, but holds nothing for the slot yet (a file drop never written for it).
    Not a failure of the link: the slot simply has no value to compare a new offset with."""


class PositionUnavailable(ControllerError):
    """The controller has no way to report where the spindle is (a file drop, an OPC UA server without
    position nodes): not a failure of the link; the admin types the position the controller shows."""


@dataclass(frozen=True)
class MachinePosition:
    """Where the tool tip is, in machine coordinates (mm): the frame work offsets are written in.

    ``x_mm, y_mm, z_mm``: the controlled point as the controller's machine-coordinate display shows it,
    minus the active tool length offset (``tool_offset_mm``, the x/y/z of G43/G43.1), so a point touched
    with a probe or a tool is where its tip is, whatever tool is loaded.
    """

    x_mm: float
    y_mm: float
    z_mm: float
    tool_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        values = (self.x_mm, self.y_mm, self.z_mm, *self.tool_offset_mm)
        if len(self.tool_offset_mm) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise ValueError(f"machine position must be finite numbers, got {self!r}")

    def as_dict(self) -> dict:
        return {"x_mm": float(self.x_mm), "y_mm": float(self.y_mm), "z_mm": float(self.z_mm),
                "tool_offset_mm": [float(v) for v in self.tool_offset_mm]}


@dataclass(frozen=True)
class WorkOffset:
    """A work offset in machine coordinates: translation in mm, rotation about machine Z in degrees."""

    x_mm: float
    y_mm: float
    z_mm: float
    c_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("x_mm", "y_mm", "z_mm", "c_deg"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"work offset {name} must be a finite number, got {value!r}")
            object.__setattr__(self, name, float(value))

    def as_dict(self) -> dict[str, float]:
        return {"x_mm": self.x_mm, "y_mm": self.y_mm, "z_mm": self.z_mm, "c_deg": self.c_deg}

    def to_pose(self) -> np.ndarray:
        """``T_machine_datum``, shape (4, 4), translation in mm."""
        c = math.radians(self.c_deg)
        T = np.eye(4)
        T[:2, :2] = [[math.cos(c), -math.sin(c)], [math.sin(c), math.cos(c)]]
        T[:3, 3] = (self.x_mm, self.y_mm, self.z_mm)
        return T

    def difference(self, other: "WorkOffset") -> tuple[float, float]:
        """(largest |ΔX|,|ΔY|,|ΔZ| in mm, |ΔC| in degrees wrapped to [0, 180])."""
        d_mm = max(abs(self.x_mm - other.x_mm), abs(self.y_mm - other.y_mm), abs(self.z_mm - other.z_mm))
        return d_mm, abs(wrap_deg(self.c_deg - other.c_deg))

    def agrees_with(self, other: "WorkOffset", rounding_mm: float, rounding_deg: float) -> bool:
        """True when ``other`` equals this offset within a controller's rounding (read-back check)."""
        d_mm, d_deg = self.difference(other)
        # a tiny slack so that a value printed with exactly `rounding` resolution still agrees
        return d_mm <= rounding_mm * (1 + 1e-9) + 1e-12 and d_deg <= rounding_deg * (1 + 1e-9) + 1e-12

    def __str__(self) -> str:
        return f"X{self.x_mm:+.4f} Y{self.y_mm:+.4f} Z{self.z_mm:+.4f} mm C{self.c_deg:+.4f}°"


def wrap_deg(angle_deg: float) -> float:
    """Angle wrapped to (-180, 180] degrees."""
    a = math.fmod(angle_deg, 360.0)
    if a <= -180.0:
        a += 360.0
    elif a > 180.0:
        a -= 360.0
    return a




def slot_number(slot: str) -> int:
    """``"G54"`` → 1 … ``"G59.3"`` → 9 (the G10 L2 ``P`` number). Raises ValueError with the list."""
    key = str(slot).strip().upper()
    if key not in SLOT_P_NUMBERS:
        raise ValueError(f"unknown work offset slot {slot!r}; use one of {', '.join(SLOT_P_NUMBERS)}")
    return SLOT_P_NUMBERS[key]


def slot_name(p_number: int) -> str:
    """Inverse of :func:`slot_number`: 1 → ``"G54"``."""
    for name, p in SLOT_P_NUMBERS.items():
        if p == p_number:
            return name
    raise ValueError(f"no work offset slot has P number {p_number}; use 1..9")


@runtime_checkable
class Controller(Protocol):
    """What the service needs from a CNC controller. All methods block; failures raise ControllerError.

    ``rounding_mm`` / ``rounding_deg``: the resolution with which the controller stores or reports
    a value, so a read-back is compared with ``WorkOffset.agrees_with(read, rounding_mm, rounding_deg)``.
    ``describe`` names the controller in messages ("LinuxCNC at 127.0.0.1:5007").
    """

    rounding_mm: float
    rounding_deg: float
    describe: str

    def read_offset(self, slot: str) -> WorkOffset:
        """The offset currently stored in ``slot`` ("G54".."G59.3")."""
        ...

    def write_offset(self, slot: str, offset: WorkOffset) -> None:
        """Store ``offset`` in ``slot``. Does not read back; the caller does (read_offset)."""
        ...

    def read_position(self) -> MachinePosition:
        """Where the tool tip is now, in machine coordinates (mm); never moves the machine.
        Raises PositionUnavailable when this kind of controller cannot tell."""
        ...

    def read_axis_deg(self, name: str) -> float:
        """Where rotary axis ``name`` ("A", "B" or "C") is now, degrees, in machine coordinates (the
        angle the kinematic chain takes, no work offset applied); never moves the machine.
        Raises PositionUnavailable when this kind of controller cannot tell."""
        ...

    def pause(self) -> None:
        """Hold a running program (feed hold)."""
        ...

    def stop(self) -> None:
        """Abort a running program."""
        ...

    def close(self) -> None:
        """Release connections; the object must not be used afterwards."""
        ...
