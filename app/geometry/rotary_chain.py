"""A table carried by a rotary axis: where the table is in machine coordinates at an axis angle (pure maths).

The kinematic chain of a rotary table (C about Z, or an A/B trunnion)::

    T_machine_table(angle) = T_machine_axis @ R(angle) @ T_axis_table

* ``T_machine_axis``: the pose of the axis frame in machine coordinates (mm). Its origin lies on the
  axis of rotation; the axis of rotation is the frame's own z for C, x for A and y for B, and the
  positive angle turns the table right-handed about that direction. A table that turns the other way
  round for a positive angle (ISO's C' convention) has that axis of the frame pointing the other way.
* ``R(angle)``: ``Rz`` for C, ``Rx`` for A, ``Ry`` for B, angle in degrees (radians only inside).
* ``T_axis_table``: the pose of the table frame (its model's frame, the one the markers are drawn in)
  in the axis frame at angle 0, mm.

The markers are on the turning table, so ``T_cam_table`` and ``T_table_obj`` from a picture do not
depend on the angle at which it was taken; the angle only places the table in the machine (the 3D view)
and the offset is the chain evaluated at the angle the NC program expects (``export_at_deg``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.geometry.transforms import check_pose, inv

AXIS_NAMES = ("A", "B", "C")
#: the axis frame's column that is the axis of rotation, per axis name
AXIS_INDEX = {"A": 0, "B": 1, "C": 2}


def axis_rotation(name: str, angle_deg: float) -> np.ndarray:
    """The 4x4 right-handed rotation by ``angle_deg`` about x (A), y (B) or z (C); no translation."""
    if name not in AXIS_INDEX:
        raise ValueError(f"rotary axis name must be one of {', '.join(AXIS_NAMES)}, got {name!r}")
    a = np.radians(float(angle_deg))
    c, s = np.cos(a), np.sin(a)
    i = AXIS_INDEX[name]
    j, k = (i + 1) % 3, (i + 2) % 3
    T = np.eye(4)
    T[j, j], T[j, k], T[k, j], T[k, k] = c, -s, s, c
    return T


@dataclass(frozen=True, eq=False)
class RotaryChain:
    """A rotary axis carrying the table: ``name`` (A, B or C), ``T_machine_axis`` and ``T_axis_table``
    (4x4, mm; see the module docstring)."""

    name: str
    T_machine_axis: np.ndarray
    T_axis_table: np.ndarray

    def __post_init__(self) -> None:
        if self.name not in AXIS_INDEX:
            raise ValueError(f"rotary axis name must be one of {', '.join(AXIS_NAMES)}, got {self.name!r}")
        object.__setattr__(self, "T_machine_axis", check_pose(self.T_machine_axis, "T_machine_axis", tol=1e-5))
        object.__setattr__(self, "T_axis_table", check_pose(self.T_axis_table, "T_axis_table", tol=1e-5))

    def T_machine_table(self, angle_deg: float) -> np.ndarray:
        """Pose of the table frame in machine coordinates with the axis at ``angle_deg`` (degrees), mm."""
        return self.T_machine_axis @ axis_rotation(self.name, angle_deg) @ self.T_axis_table

    def turn(self, from_deg: float, to_deg: float) -> np.ndarray:
        """``T_table(from)_table(to)``: the table at ``to_deg`` seen from the table frame at ``from_deg``
        (what turning the axis from one angle to the other does to the table, in its own frame)."""
        return inv(self.T_machine_table(from_deg)) @ self.T_machine_table(to_deg)

    def axis_direction(self) -> np.ndarray:
        """The axis of rotation (unit vector, machine coordinates; positive angles turn right-handed about it)."""
        return self.T_machine_axis[:3, AXIS_INDEX[self.name]].copy()

    def axis_point(self) -> np.ndarray:
        """A point on the axis of rotation (the axis frame's origin), machine coordinates, mm."""
        return self.T_machine_axis[:3, 3].copy()


def angle_of_turn(chain: RotaryChain, T_machine_table_a: np.ndarray, T_machine_table_b: np.ndarray) -> float:
    """The axis angle (degrees, (-180, 180]) that turns the table from pose ``a`` to pose ``b`` (both in
    machine coordinates); the inverse of :meth:`RotaryChain.T_machine_table` for angle differences.
    ValueError when the two poses do not differ by a turn about the chain's axis (within 0.01 mm/deg)."""
    # T_b = T_ma @ R(d) @ inv(T_ma) @ T_a  ->  R(d) = inv(T_ma) @ T_b @ inv(T_a) @ T_ma
    R = inv(chain.T_machine_axis) @ np.asarray(T_machine_table_b, float) @ inv(np.asarray(T_machine_table_a, float)) \
        @ chain.T_machine_axis
    i = AXIS_INDEX[chain.name]
    j, k = (i + 1) % 3, (i + 2) % 3
    angle = float(np.degrees(np.arctan2(R[k, j], R[j, j])))
    if not np.allclose(R, axis_rotation(chain.name, angle), atol=1e-4):
        raise ValueError(f"the two table poses do not differ by a turn about the {chain.name} axis")
    return angle
