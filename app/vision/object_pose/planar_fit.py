"""Stage 2: a start aligned in the table plane (x, y, rotation about the normal) by iterated
point-to-line matching against the nearest image edge of compatible direction (oriented chamfer ICP),
scored by the share of the model's visible edges with an image edge within 2 px."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from app.geometry.model_edges import PreparedModel, project_points_px, visible_edge_samples
from app.geometry.transforms import transform_points
from app.vision.object_pose.edge_image import EdgeImage
from app.vision.object_pose.pose_params import perturb3

if TYPE_CHECKING:
    from app.vision.object_pose.search import Hyp


def sample_subset(model: PreparedModel, px_per_mm: float, spacing_px: float, max_n: int) -> np.ndarray:
    stride = max(1, int(round(spacing_px / max(model.sample_step_mm * px_per_mm, 1e-9))))
    idx = np.arange(0, len(model.samples_obj), stride)
    if len(idx) > max_n:
        idx = np.linspace(0, len(model.samples_obj) - 1, max_n).astype(np.int64)
    return idx


def _chamfer_support(eimg: EdgeImage, uv: np.ndarray, normal: np.ndarray, tol_px: float,
                     max_angle_deg: float = 25.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest edge pixel per projected sample: (supported (N,) bool, residual along normal, q (N,2))."""
    iu = np.clip(np.rint(uv[:, 0]).astype(int), 0, eimg.width - 1)
    iv = np.clip(np.rint(uv[:, 1]).astype(int), 0, eimg.height - 1)
    d = eimg.dist_px[iv, iu]
    if len(eimg.edge_uv) == 0:
        return np.zeros(len(uv), bool), np.zeros(len(uv)), uv.copy()
    j = eimg.nearest[iv, iu]
    q = eimg.edge_uv[j]
    a = eimg.edge_angle[j]
    cosang = np.abs(np.cos(a) * normal[:, 0] + np.sin(a) * normal[:, 1])
    ok = (d <= tol_px) & (cosang >= np.cos(np.radians(max_angle_deg)))
    r = np.einsum("ij,ij->i", normal, uv - q)
    return ok, r, q


def planar_fit(eimg, model, hyp: Hyp, T_cam_table, K, dist, subset, radii=(14.0, 8.0, 4.0, 2.5)):
    T = hyp.T_table_obj
    W, H = eimg.width, eimg.height
    for r in radii:
        for _ in range(2):
            T_cam_obj = T_cam_table @ T
            es = visible_edge_samples(model, T_cam_obj, K, dist, W, H, occlusion_test=False, subset=subset)
            if len(es.index) < 8:
                hyp.score = 0.0
                hyp.T_table_obj = T
                return hyp
            ok, res, _ = _chamfer_support(eimg, es.uv_px, es.normal_uv, r)
            if ok.sum() < 6:
                break
            c_table = transform_points(T, model.center_obj[None])[0]
            X = es.points_obj[ok]
            n = es.normal_uv[ok]
            e = res[ok]
            J = np.zeros((len(X), 3))
            base = es.uv_px[ok]
            # the three moved poses' points projected in one call (pointwise arithmetic: the same
            # numbers as one call each, a third of the calls' overhead on a few hundred points)
            steps = (0.5, 0.5, 0.002)
            moved = [transform_points(T_cam_table @ perturb3(T, c_table, q), X) for q in np.diag(steps)]
            uvs = project_points_px(np.concatenate(moved), K, dist).reshape(3, len(X), 2)
            for k, h in enumerate(steps):
                J[:, k] = np.einsum("ij,ij->i", n, (uvs[k] - base) / h)
            w = np.minimum(1.0, (0.5 * r) / np.maximum(np.abs(e), 1e-9))   # Huber weights
            A = J.T @ (J * w[:, None]) + np.diag([1e-6, 1e-6, 1e-2])
            dq = -np.linalg.solve(A, J.T @ (w * e))
            dq[:2] = np.clip(dq[:2], -r * 3, r * 3)
            T = perturb3(T, c_table, dq)
    T_cam_obj = T_cam_table @ T
    es = visible_edge_samples(model, T_cam_obj, K, dist, W, H, occlusion_test=False, subset=subset)
    ok, _, _ = _chamfer_support(eimg, es.uv_px, es.normal_uv, 2.0)
    hyp.T_table_obj = T
    hyp.score = float(ok.mean()) if len(ok) else 0.0
    return hyp
