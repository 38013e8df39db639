"""Stage 4a: is the pose the part's? Pose distances up to the part's symmetries and the share of
image edges inside the part's outline that it leaves unexplained."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from app.geometry.model_edges import PreparedModel, render_depth, visible_edge_samples
from app.geometry.transforms import transform_points
from app.vision.object_pose.edge_image import EdgeImage


def pose_distance(T1, T2, c_obj):
    p1 = transform_points(T1, c_obj[None])[0]
    p2 = transform_points(T2, c_obj[None])[0]
    R = T1[:3, :3].T @ T2[:3, :3]
    ang = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(p1 - p2)), float(ang)


def same_up_to_symmetry(model: PreparedModel, T1, T2, pos_tol, ang_tol, exact_only: bool = False) -> bool:
    """T1 ~ T2 @ S for a symmetry S (``exact_only``: exact symmetries and near ones that turn about
    the table normal; near-symmetric flips onto another face then count as different poses)."""
    Ss = [np.eye(4)] + [s.S for s in model.symmetries
                        if s.exact or not exact_only or abs(float((T2[:3, :3] @ s.axis_obj)[2])) > 0.99]
    for S in Ss:
        d, a = pose_distance(T1, T2 @ S, model.center_obj)
        if d < pos_tol and (a < ang_tol or model.continuous_axis_obj is not None and
                            abs(float((T1[:3, :3] @ model.continuous_axis_obj) @ (T2[:3, :3] @ model.continuous_axis_obj))) > np.cos(np.radians(ang_tol))):
            return True
    return False



def unexplained_edges(eimg: EdgeImage, model: PreparedModel, T_cam_obj, K, dist, inset_px: float = 3.0,
                       tol_px: float = 2.0, lines_across: bool = True) -> float:
    """Share of the image's edge pixels inside the model's projected outline that lie farther than
    ``tol_px`` from every visible model edge (pinhole coordinates; the outline shrunk by ``inset_px``);
    with ``lines_across``, the pixels on straight lines across the outline (:func:`on_lines_across`)
    are left out of both counts."""
    key = ("undist", K.tobytes(), np.asarray(dist).tobytes())
    if key not in eimg.cache:
        eimg.cache[key] = (cv2.undistortPoints(eimg.edge_uv.reshape(-1, 1, 2), K, dist, P=K).reshape(-1, 2)
                           if len(eimg.edge_uv) else np.zeros((0, 2)))
    uv_u = eimg.cache[key]
    V = transform_points(T_cam_obj, model.mesh.vertices)
    if len(uv_u) == 0 or np.any(V[:, 2] <= 1.0):
        return 0.0
    u = K[0, 0] * V[:, 0] / V[:, 2] + K[0, 2]
    v = K[1, 1] * V[:, 1] / V[:, 2] + K[1, 2]
    x0, x1 = max(u.min(), 0.0), min(u.max(), eimg.width - 1.0)
    y0, y1 = max(v.min(), 0.0), min(v.max(), eimg.height - 1.0)
    if x1 <= x0 + 2 or y1 <= y0 + 2:
        return 0.0
    s = min(1.0, 400.0 / max(x1 - x0, y1 - y0))
    Wb, Hb = int(np.ceil((x1 - x0) * s)) + 2, int(np.ceil((y1 - y0) * s)) + 2
    Kb = np.array([[K[0, 0] * s, 0, (K[0, 2] - x0) * s], [0, K[1, 1] * s, (K[1, 2] - y0) * s], [0, 0, 1.0]])
    depth, _ = render_depth([(V, model.mesh.faces)], Kb, Wb, Hb)
    mask = np.isfinite(depth).astype(np.uint8)
    r = max(1, int(round(inset_px * s)))
    mask = cv2.erode(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    iu = np.rint((uv_u[:, 0] - x0) * s).astype(np.int64)
    iv = np.rint((uv_u[:, 1] - y0) * s).astype(np.int64)
    ok = (iu >= 0) & (iu < Wb) & (iv >= 0) & (iv < Hb)
    inside = np.zeros(len(uv_u), bool)
    inside[ok] = mask[iv[ok], iu[ok]] > 0
    if inside.sum() < 10:
        return 0.0
    es = visible_edge_samples(model, T_cam_obj, K, None, eimg.width, eimg.height, occlusion_test=True)
    if len(es.index) == 0:
        return 1.0
    d, _ = cKDTree(es.uv_px).query(uv_u[inside], distance_upper_bound=tol_px + model.sample_step_mm * s * 4)
    far = d > tol_px + 0.5 * model.sample_step_mm * K[0, 0] / float(np.median(V[:, 2]))
    across = on_lines_across(iu[inside], iv[inside], far, mask) if lines_across else np.zeros(len(far), bool)
    if (~across).sum() < 10:
        return 0.0
    return float(np.mean(far[~across]))


#: a straight run of unexplained edge pixels at least this share of the outline's longer side is a
#: line across the part (cast shadows: the spindle's across the plate in our generator's vshade_004 and
#: 011, 75-79 % of the edges inside the right poses' outlines)
LINE_ACROSS_SHARE = 0.4
#: at most this many such lines are set aside (a shadow band has two sides); clutter makes many
MAX_LINES_ACROSS = 2


def on_lines_across(iu: np.ndarray, iv: np.ndarray, far: np.ndarray, outline: np.ndarray) -> np.ndarray:
    """Which edge pixels (``iu, iv``: integer positions in the outline's box, px) lie on one of the
    :data:`MAX_LINES_ACROSS` longest straight runs of the ``far`` (unexplained) ones that span at least
    :data:`LINE_ACROSS_SHARE` of the ``outline`` mask's longer side. Such a line says neither that the
    part is there nor that it is not: a cast shadow draws one across its faces, as a straight edge
    behind it does; a part read on clutter leaves many short edges. These pixels are left out of the
    unexplained share (both counts)."""
    out = np.zeros(len(iu), bool)
    if far.sum() < 10:
        return out
    ys, xs = np.nonzero(outline)
    side = float(max(np.ptp(xs), np.ptp(ys))) + 1.0 if len(xs) else 0.0
    img = np.zeros(outline.shape, np.uint8)
    img[iv[far], iu[far]] = 255
    min_len = LINE_ACROSS_SHARE * side
    lines = cv2.HoughLinesP(img, 1, np.pi / 360, threshold=max(10, int(0.5 * min_len)), minLineLength=min_len,
                            maxLineGap=max(5.0, 0.05 * side))
    if lines is None:
        return out
    segs = np.asarray(lines, float).reshape(-1, 4)
    segs = segs[np.argsort(-np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]))]
    P = np.stack([iu, iv], axis=1).astype(float)
    kept: list[tuple[np.ndarray, np.ndarray]] = []     # (a point, unit direction) of each line
    for x0, y0, x1, y1 in segs:
        a, t = np.array([x0, y0]), np.array([x1 - x0, y1 - y0])
        t /= max(float(np.linalg.norm(t)), 1e-9)
        if any(abs(float(t @ tk)) > np.cos(np.radians(3.0)) and _off_line(a[None], ak, tk)[0] < 3.0
               for ak, tk in kept):
            continue                            # the same line again
        kept.append((a, t))
        if len(kept) == MAX_LINES_ACROSS:
            break
    for a, t in kept:
        out |= _off_line(P, a, t) <= 1.5
    return out


def _off_line(P: np.ndarray, a: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Distance of the points ``P`` (N, 2) from the line through ``a`` along the unit ``t``."""
    rel = P - a
    return np.abs(rel[:, 0] * t[1] - rel[:, 1] * t[0])
