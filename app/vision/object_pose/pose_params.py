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


def left_jacobian(rotvec: np.ndarray) -> np.ndarray:
    """(3, 3) left Jacobian ``J_l`` of SO(3) at ``rotvec`` (rad): ``R(w + dw) ~ R(J_l dw) R(w)``."""
    w = np.asarray(rotvec, float)
    th = float(np.linalg.norm(w))
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-5:       # series: 1/2 - th^2/24, 1/6 - th^2/120
        return np.eye(3) + (0.5 - th * th / 24.0) * W + (1.0 / 6.0 - th * th / 120.0) * (W @ W)
    return np.eye(3) + (1.0 - np.cos(th)) / th ** 2 * W + (th - np.sin(th)) / th ** 3 * (W @ W)


def perturb_point_jacobian(Y_table: np.ndarray, c_table: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(N, 3, 6): d(point) / dp (mm per mm, mm per rad) of the table-frame points ``Y_table`` (where
    ``T_table_obj`` puts them) moved by :func:`perturb` with p (dx, dy, dz mm, rotation vector rad)
    about ``c_table``: ``[I | -[R (Y - c)]x J_l]``."""
    R = rotvec_matrix(p[3:6])
    v = (np.asarray(Y_table, float) - c_table) @ R.T             # R (Y - c)
    Jl = left_jacobian(p[3:6])
    out = np.zeros((len(v), 3, 6))
    out[:, 0, 0] = out[:, 1, 1] = out[:, 2, 2] = 1.0
    # -[v]x Jl: rows of -[v]x are (0, v2, -v1), (-v2, 0, v0), (v1, -v0, 0)
    Vx = np.zeros((len(v), 3, 3))
    Vx[:, 0, 1], Vx[:, 0, 2] = v[:, 2], -v[:, 1]
    Vx[:, 1, 0], Vx[:, 1, 2] = -v[:, 2], v[:, 0]
    Vx[:, 2, 0], Vx[:, 2, 1] = v[:, 1], -v[:, 0]
    out[:, :, 3:] = Vx @ Jl
    return out


def perturb3(T_table_obj: np.ndarray, c_table: np.ndarray, q: np.ndarray) -> np.ndarray:
    return perturb(T_table_obj, c_table, np.array([q[0], q[1], 0.0, 0.0, 0.0, q[2]]))


def flat_at(T_flat: np.ndarray, T_table_obj: np.ndarray, c_obj: np.ndarray) -> np.ndarray:
    """``T_flat`` (a part lying flat, ``T_table_obj``) turned about the table normal and moved in the
    table plane so that its point ``c_obj`` (obj frame, mm) lies over that point at ``T_table_obj`` and
    it faces the same way; its height and its stance stay ``T_flat``'s. Where a 6-DoF fit put a part,
    as a flat start."""
    turn = Rotation.from_matrix(T_table_obj[:3, :3] @ T_flat[:3, :3].T).as_rotvec()[2]
    R = Rotation.from_rotvec([0.0, 0.0, turn]).as_matrix() @ T_flat[:3, :3]
    t = T_flat[:3, 3].copy()
    t[:2] = (T_table_obj[:3, :3] @ c_obj + T_table_obj[:3, 3])[:2] - (R @ c_obj)[:2]
    return make_pose(R, t)


FREE_6DOF = (0, 1, 2, 3, 4, 5)
FREE_REST = (0, 1, 2, 5)      # x, y, z, rotation about the table normal: part lying flat

