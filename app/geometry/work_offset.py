"""From located poses to the work offset a controller stores (pure maths, no I/O).

The offset is ``T_machine_datum = T_machine_table @ T_table_obj @ T_obj_datum`` (DESIGN.md). A
3-axis controller slot holds X, Y, Z (mm) and one rotation C (degrees) about machine Z, so the
rotation is split as ``R = Rz(C) @ Ry(B) @ Rx(A)`` (fixed axes, the machine-tool reading used by
:func:`app.geometry.transforms.pose_from_xyz_euler`). ``C = atan2(R[1,0], R[0,0])`` is the angle of the
datum's x axis projected into the machine XY plane. A and B are the residual tilt the controller
cannot take; it is reported and checked against ``max_tilt_deg``, never dropped silently.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.geometry.transforms import check_pose, tilt_deg, xyz_euler_from_pose


@dataclass(frozen=True)
class OffsetResult:
    """A work offset in machine coordinates, or the reason it cannot be used.

    ``x_mm, y_mm, z_mm``: datum origin in machine coordinates. ``c_deg``: rotation about machine Z,
    in (-180, 180]. ``a_deg, b_deg``: residual rotation about machine X and Y (``R = Rz(C) Ry(B) Rx(A)``).
    ``tilt_deg``: angle between the datum's z axis and machine Z. ``T_machine_datum``: the full pose,
    shape (4, 4). ``reason`` is empty when the offset may be exported, else one plain sentence.
    """

    x_mm: float
    y_mm: float
    z_mm: float
    c_deg: float
    a_deg: float
    b_deg: float
    tilt_deg: float
    max_tilt_deg: float
    T_machine_datum: np.ndarray
    reason: str = ""

    @property
    def ok(self) -> bool:
        return not self.reason

    def __bool__(self) -> bool:  # a refused result is falsy, like a failed estimate
        return self.ok


def work_offset_from_poses(
    T_machine_table: np.ndarray,
    T_table_obj: np.ndarray,
    T_obj_datum: np.ndarray,
    *,
    max_tilt_deg: float,
    max_tilt_from: str = "",
) -> OffsetResult:
    """Work offset of the datum in machine coordinates.

    Parameters
    ----------
    T_machine_table : ndarray, shape (4, 4)
        Pose of the table frame in machine coordinates (machine configuration), mm.
    T_table_obj : ndarray, shape (4, 4)
        Located pose of the workpiece model frame on the table, mm.
    T_obj_datum : ndarray, shape (4, 4)
        The NC program zero defined on the workpiece model, mm.
    max_tilt_deg : float
        Largest residual tilt (angle between datum z and machine Z) a 3-axis offset may ignore.
    max_tilt_from : str
        Where that limit comes from, named in the refusal (e.g. "machine 'Mill 3'"); "" names nothing.

    Returns
    -------
    OffsetResult
        Always filled with the numbers; ``reason`` says why it must not be exported when the tilt
        exceeds ``max_tilt_deg`` (falsy result).

    Raises
    ------
    app.geometry.transforms.PoseError
        If an input is not a rigid 4x4 transform. ValueError if ``max_tilt_deg`` is negative.
    """
    if not np.isfinite(max_tilt_deg) or max_tilt_deg < 0:
        raise ValueError(f"max_tilt_deg must be a finite number >= 0, got {max_tilt_deg}")
    T = (
        check_pose(T_machine_table, "T_machine_table")
        @ check_pose(T_table_obj, "T_table_obj")
        @ check_pose(T_obj_datum, "T_obj_datum")
    )
    x, y, z, a, b, _ = xyz_euler_from_pose(T)
    R = T[:3, :3]
    c = float(np.degrees(np.arctan2(R[1, 0], R[0, 0])))  # equals the Euler C; robust near B = ±90°
    tilt = tilt_deg(T)
    reason = tilt_reason(tilt, a, b, max_tilt_deg, max_tilt_from) if tilt > max_tilt_deg else ""
    return OffsetResult(
        x_mm=x, y_mm=y, z_mm=z, c_deg=c, a_deg=a, b_deg=b, tilt_deg=tilt,
        max_tilt_deg=float(max_tilt_deg), T_machine_datum=T, reason=reason,
    )


def tilt_reason(tilt: float, a_deg: float, b_deg: float, max_tilt_deg: float, max_tilt_from: str = "") -> str:
    """The sentence refusing a work offset whose residual ``tilt`` (degrees; ``a_deg``, ``b_deg`` about
    machine X and Y) exceeds ``max_tilt_deg``; ``max_tilt_from`` says where that limit comes from."""
    err_mm = 100.0 * np.sin(np.radians(min(tilt, 90.0)))
    source = f" (limit from {max_tilt_from})" if max_tilt_from else ""
    return (f"residual tilt {tilt:.3f}° (A {a_deg:+.3f}°, B {b_deg:+.3f}°) exceeds the allowed {max_tilt_deg:.3f}°"
            f"{source}: a 3-axis work offset cannot hold it (≈{err_mm:.2f} mm error 100 mm from the datum); "
            "check that the part sits flat on the table or vise, or use a tilted-plane (A/B) setup")


def sheet_work_offset(T_machine_bed: np.ndarray, x_mm: float, y_mm: float, c_deg: float,
                      thickness_mm: float) -> tuple[float, float, float]:
    """Machine X, Y (mm) and C (degrees) of a sheet's work origin found in the bed frame.

    The origin is ``T_bed_datum = [Rz(c_deg) | (x_mm, y_mm, thickness_mm)]`` (bed frame: slat tips at
    z = 0, so the sheet's top face is at ``thickness_mm``); the offset is ``T_machine_bed @ T_bed_datum``
    reduced to its translation in X, Y and its rotation about machine Z. Z is not returned: the
    controller keeps its own (height sensing sets it on laser and plasma machines).
    """
    c = np.radians(c_deg)
    T_bed_datum = np.eye(4)
    T_bed_datum[:2, :2] = [[np.cos(c), -np.sin(c)], [np.sin(c), np.cos(c)]]
    T_bed_datum[:3, 3] = (x_mm, y_mm, thickness_mm)
    T = np.asarray(T_machine_bed, float) @ T_bed_datum
    return float(T[0, 3]), float(T[1, 3]), float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))
