"""The located part drawn over the image (for the overlay and diagnostics)."""

from __future__ import annotations

import cv2
import numpy as np

from app.geometry.model_edges import PreparedModel, visible_edge_samples
from app.vision.object_pose.results import ObjectPose


def draw_object(image: np.ndarray, K, dist, pose: ObjectPose, model: PreparedModel,
                color=(0, 255, 0), T_cam_table: np.ndarray | None = None) -> np.ndarray:
    """BGR copy of ``image`` with the model's visible edges at ``pose`` (supported or not) drawn,
    its name, score and position; for a failure, its best candidate in red with the reason."""
    out = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    H, W = out.shape[:2]
    dist = np.zeros(5) if dist is None else np.asarray(dist, float)
    if isinstance(pose, ObjectPose):
        T_cam_obj, label, col = pose.T_cam_obj, (f"{pose.model_name} {pose.score:.0%} "
                                                 f"x{pose.T_table_obj[0, 3]:.1f} y{pose.T_table_obj[1, 3]:.1f} "
                                                 f"C{np.degrees(np.arctan2(pose.T_table_obj[1, 0], pose.T_table_obj[0, 0])):.2f}"), color
    else:
        if not pose.candidates or T_cam_table is None:
            cv2.putText(out, pose.reason[:120], (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 255), 2)
            return out
        T_cam_obj = np.asarray(T_cam_table) @ np.asarray(pose.candidates[0]["T_table_obj"])
        label, col = pose.reason[:120], (0, 0, 255)
    es = visible_edge_samples(model, T_cam_obj, np.asarray(K, float), dist, W, H, occlusion_test=True)
    for u, v in es.uv_px:
        cv2.circle(out, (int(round(u * 4)), int(round(v * 4))), 4, col, -1, lineType=cv2.LINE_AA, shift=2)
    if len(es.uv_px):
        u0, v0 = es.uv_px.min(axis=0)
        cv2.putText(out, label, (int(u0), max(15, int(v0) - 8)), cv2.FONT_HERSHEY_SIMPLEX, 0.5, col, 1,
                    cv2.LINE_AA)
    return out
