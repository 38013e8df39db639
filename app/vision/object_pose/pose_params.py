"""How the fits move a pose: small motions about a point in the table frame (mm, rad)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from app.geometry.transforms import make_pose


def perturb(T_table_obj: np.ndarray, c_table: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``T_table_obj`` moved by p = (dx, dy, dz mm, rotation vector rad) about the point c_table."""
    R = Rotation.from_rotvec(p[3:6]).as_matrix()
    T = make_pose(R, c_table + p[:3] - R @ c_table)
    return T @ T_table_obj


def perturb3(T_table_obj: np.ndarray, c_table: np.ndarray, q: np.ndarray) -> np.ndarray:
    return perturb(T_table_obj, c_table, np.array([q[0], q[1], 0.0, 0.0, 0.0, q[2]]))


FREE_6DOF = (0, 1, 2, 3, 4, 5)
FREE_REST = (0, 1, 2, 5)      # x, y, z, rotation about the table normal: part lying flat

