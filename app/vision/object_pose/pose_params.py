"""How the fits move a pose: small motions about a point in the table frame (mm, rad)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from app.geometry.transforms import make_pose


def _public_rotvec_matrix(rotvec: np.ndarray) -> np.ndarray:
    """``Rotation.from_rotvec(rotvec).as_matrix()``, (3,) -> (3, 3)."""
    return Rotation.from_rotvec(rotvec).as_matrix()


try:            # SciPy's compiled rotations (>= 1.17) without the Rotation object's per-call overhead:
    from scipy.spatial.transform import _rotation_cy     # the fits call this ~10^4 times per image

    def _compiled_rotvec_matrix(rotvec: np.ndarray) -> np.ndarray:
        """``Rotation.from_rotvec(rotvec).as_matrix()``, the same numbers, (3,) -> (3, 3)."""
        return _rotation_cy.as_matrix(_rotation_cy.from_rotvec(np.asarray(rotvec, float).reshape(1, 3)))[0]

    # a private module: used only where it gives the public numbers here, on this SciPy
    _probe = np.array([1e-3, -2e-3, 0.5])
    rotvec_matrix = (_compiled_rotvec_matrix
                     if np.array_equal(_compiled_rotvec_matrix(_probe), _public_rotvec_matrix(_probe))
                     else _public_rotvec_matrix)
except Exception:  # noqa: BLE001 - another SciPy (missing, renamed, other signature): the public way
    rotvec_matrix = _public_rotvec_matrix


def perturb(T_table_obj: np.ndarray, c_table: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``T_table_obj`` moved by p = (dx, dy, dz mm, rotation vector rad) about the point c_table."""
    R = rotvec_matrix(p[3:6])
    T = make_pose(R, c_table + p[:3] - R @ c_table)
    return T @ T_table_obj


def perturb3(T_table_obj: np.ndarray, c_table: np.ndarray, q: np.ndarray) -> np.ndarray:
    return perturb(T_table_obj, c_table, np.array([q[0], q[1], 0.0, 0.0, 0.0, q[2]]))


FREE_6DOF = (0, 1, 2, 3, 4, 5)
FREE_REST = (0, 1, 2, 5)      # x, y, z, rotation about the table normal: part lying flat

