"""Homogeneous transforms in the project's convention.

A pose is a 4x4 array ``T_a_b``: the pose of frame ``b`` expressed in frame ``a``, so
``p_a = T_a_b @ p_b`` and ``T_a_c = T_a_b @ T_b_c``. Translations are in mm, angles at every
boundary in degrees (radians only inside the maths here).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation


class PoseError(ValueError):
    """A pose that is not a proper rigid transform; the message says which and why."""


def check_pose(T: ArrayLike, name: str = "pose", tol: float = 1e-6) -> np.ndarray:
    """Validate a 4x4 rigid transform and return it as a float64 array.

    Parameters
    ----------
    T : array-like, shape (4, 4)
        Candidate pose (translation in mm).
    name : str
        What the pose is, used in the error message ("T_table_marker of marker 7").
    tol : float
        Allowed deviation of ``R.T @ R`` from identity and of the last row from ``[0, 0, 0, 1]``.

    Raises
    ------
    PoseError
        With a sentence naming the pose and what is wrong with it.
    """
    try:
        A = np.asarray(T, dtype=float)
    except (TypeError, ValueError) as exc:
        raise PoseError(f"{name}: not a numeric 4x4 matrix ({exc})") from None
    if A.shape != (4, 4):
        raise PoseError(f"{name}: expected shape (4, 4), got {A.shape}")
    if not np.all(np.isfinite(A)):
        raise PoseError(f"{name}: contains NaN or infinity")
    if np.max(np.abs(A[3] - [0, 0, 0, 1])) > tol:
        raise PoseError(f"{name}: last row must be [0, 0, 0, 1], got {A[3].tolist()}")
    R = A[:3, :3]
    ortho = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if ortho > max(tol, 1e-6):
        raise PoseError(f"{name}: rotation not orthonormal (max |RᵀR − I| = {ortho:.1e})")
    if np.linalg.det(R) < 0:
        raise PoseError(f"{name}: rotation is a reflection (det R = -1)")
    return A


def make_pose(R: ArrayLike | None = None, t: ArrayLike | None = None) -> np.ndarray:
    """Build ``T`` from a 3x3 rotation ``R`` and a translation ``t`` (mm)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = np.asarray(R, dtype=float)
    if t is not None:
        T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform: ``inv(T_a_b) = T_b_a`` (exact, no general matrix inverse)."""
    R = T[:3, :3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def transform_points(T_a_b: np.ndarray, p_b: ArrayLike) -> np.ndarray:
    """Map points ``p_b`` (N, 3) in frame b to frame a: ``p_a = R p_b + t``."""
    p = np.asarray(p_b, dtype=float).reshape(-1, 3)
    return p @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def pose_from_xyz_euler(
    x_mm: float = 0.0, y_mm: float = 0.0, z_mm: float = 0.0,
    a_deg: float = 0.0, b_deg: float = 0.0, c_deg: float = 0.0,
) -> np.ndarray:
    """Pose from a translation and rotations about the fixed x, y, z axes (A, B, C), degrees.

    ``R = Rz(C) @ Ry(B) @ Rx(A)``: the usual machine-tool reading, C being the rotation about
    the table/machine Z axis.
    """
    R = Rotation.from_euler("xyz", [a_deg, b_deg, c_deg], degrees=True).as_matrix()
    return make_pose(R, [x_mm, y_mm, z_mm])


def xyz_euler_from_pose(T: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """Inverse of :func:`pose_from_xyz_euler`: (x_mm, y_mm, z_mm, a_deg, b_deg, c_deg)."""
    a, b, c = Rotation.from_matrix(T[:3, :3]).as_euler("xyz", degrees=True)
    x, y, z = T[:3, 3]
    return float(x), float(y), float(z), float(a), float(b), float(c)


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray | None = None) -> float:
    """Angle (degrees) of the rotation ``R_a`` (or of ``R_a.T @ R_b`` when ``R_b`` is given)."""
    R = R_a[:3, :3] if R_b is None else R_a[:3, :3].T @ R_b[:3, :3]
    c = (np.trace(R) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def tilt_deg(T: np.ndarray) -> float:
    """Angle (degrees) between the pose's z axis and the parent's z axis: residual tilt."""
    z = T[:3, 2]
    return float(np.degrees(np.arccos(np.clip(z[2], -1.0, 1.0))))


def rvec_tvec_to_pose(rvec: ArrayLike, tvec: ArrayLike) -> np.ndarray:
    """OpenCV's (rvec, tvec) from solvePnP is ``T_cam_obj``: build the 4x4."""
    R = Rotation.from_rotvec(np.asarray(rvec, dtype=float).reshape(3)).as_matrix()
    return make_pose(R, np.asarray(tvec, dtype=float).reshape(3))


def pose_to_rvec_tvec(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`rvec_tvec_to_pose`: (rvec (3,), tvec (3,) mm)."""
    rvec = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    return rvec, T[:3, 3].copy()
