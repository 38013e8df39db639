"""Error of an estimated object pose against the truth, to the nearest look-alike pose of the part.

Used by the benchmarks and the accuracy tests; the engine never sees the truth.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from app.geometry.model_edges import PreparedModel


def pose_error_6dof(T_est: np.ndarray, T_true: np.ndarray, model: PreparedModel) -> np.ndarray:
    """(dx, dy, dz mm, drx, dry, drz deg) of ``T_est - T_true`` (both ``T_table_obj``): the origin's
    offset in table axes and the small rotation ``R_est @ R_true^T`` about the table axes, taken to
    the nearest pose that looks the same (the part's symmetries). A rotation about a round part's
    axis is not observable: its component along that axis is NaN."""
    best, best_key = None, np.inf
    for S in [np.eye(4)] + [s.S for s in model.symmetries if s.exact]:
        Te = np.asarray(T_est, float) @ S
        d = Te[:3, 3] - np.asarray(T_true, float)[:3, 3]
        rv = np.degrees(Rotation.from_matrix(Te[:3, :3] @ np.asarray(T_true, float)[:3, :3].T).as_rotvec())
        if model.continuous_axis_obj is not None:
            ax = np.asarray(T_true, float)[:3, :3] @ model.continuous_axis_obj
            rv = rv - (rv @ ax) * ax           # the spin about the axis is free
            rv = np.where(np.abs(ax) > 0.9, np.nan, rv)
        key = float(np.linalg.norm(d) + 10 * np.linalg.norm(np.nan_to_num(rv)))
        if key < best_key:
            best, best_key = np.concatenate([d, rv]), key
    return best
