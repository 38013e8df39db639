"""The 1-sigma of a located pose (:func:`pose_covariance`): the fit's scatter (cluster-robust, times
the CAD engine's :data:`~app.vision.object_pose.uncertainty.SIGMA_SCALE`), the table-pose error of the
search and the teach picture propagated through the fit (:func:`table_sensitivity`), and the
view-dependent edge bias of both pictures (:data:`EDGE_BIAS_PX`, the one constant calibrated for photo
models). Covariances of (x mm, y mm, theta rad)."""

from __future__ import annotations

import numpy as np

from app.geometry.transforms import inv
from app.vision.object_pose.uncertainty import (
    CONTACT_SIGMA_DEG,
    CONTACT_SIGMA_MM,
    SIGMA_SCALE,
)
from app.vision.photo_model.fit import Fit
from app.vision.photo_model.model import PhotoModel, rot, transform
from app.vision.photo_model.plane import camera_mm_per_px
from app.vision.photo_model.view import View

# Edge bias (camera px) common to a picture's whole outline: where a top face's edge is found depends
# on the view (blur mixing the side wall or the table below into the edge's profile, the perspective of
# the rounded corner), so the template of the teach picture and the edges of a search picture are both
# displaced by a fraction of a camera pixel, the same way all along the outline (it does not average
# out over the edges). Its size is the one constant calibrated for photo models: fitted on the first
# half of benchmarks/photo_model.py's placements (BENCHMARKS.md#photo-model), checked on the second.
EDGE_BIAS_PX = 0.054


def _inliers(fit: Fit) -> np.ndarray:
    """The fit's robust inliers (residual within 3 MAD-sigmas, at least 0.1 mm): the points sigma uses."""
    r = fit.residual_mm
    scale = 1.4826 * float(np.nanmedian(np.abs(r))) + 1e-6
    return fit.found & (np.abs(np.nan_to_num(r, nan=1e9)) < max(3 * scale, 0.1))


def fit_cov(fit: Fit, model: PhotoModel) -> np.ndarray:
    """Covariance (3x3 of x mm, y mm, theta rad; table axes, about the obj origin) of the fit's own
    scatter, unscaled: the classical ``(J^T J)^-1 s^2`` plus the cluster-robust ("sandwich") term for
    errors shared by neighbouring edge samples (same ``CLUSTER_MM`` square: one image edge, blur,
    the rectification's interpolation), with the small-sample factor ``G / (G - 3)``."""
    inl = _inliers(fit)
    Ji, ri = fit.J[inl], fit.residual_mm[inl]
    Ainv = np.linalg.pinv(Ji.T @ Ji)
    s2 = float(ri @ ri) / max(len(ri) - 3, 1)
    G = np.zeros((3, 3))
    cl = model.cluster[inl]
    for c in np.unique(cl):
        gvec = Ji[cl == c].T @ ri[cl == c]
        G += np.outer(gvec, gvec)
    n_cl = len(np.unique(cl))
    G *= n_cl / max(n_cl - 3, 1)
    return Ainv @ G @ Ainv + Ainv * s2


def table_sensitivity(fit: Fit, model: PhotoModel, view: View) -> np.ndarray:
    """d(x mm, y mm, theta rad of the fit) / d(table-pose error): 3x6, the table error in
    :class:`~app.vision.fiducials.TablePose`'s parameters (rotation vector about the table axes, rad;
    shift along them, mm; both at ``view.table_centroid_mm``).

    If the true table is the estimated one moved by (omega, s) about the centroid c, a point p of the
    top face (z = h) lies in the estimated table frame at ``q = p + omega x (p - c) + s``; the
    rectification follows the camera ray through q down (or up) to the plane z = h of the estimated
    frame: ``q' = q - (q_z - h) (q - C) / (q_z - C_z)`` with C the camera centre (table frame). So every
    template point seems displaced by ``dq'/d(omega, s)`` (the same error for all of them: it does not
    average out over the edges), and the least-squares fit follows the displacement along the normals:
    ``d pose = (J^T J)^-1 J^T (n . dq')`` over the fit's inliers."""
    inl = _inliers(fit)
    Q, N = transform(model, fit.x, fit.y, fit.theta)
    Q, N, Ji = Q[inl], N[inl], fit.J[inl]
    h = float(model.height_mm)
    P = np.column_stack([Q, np.full(len(Q), h)])
    C = inv(np.asarray(view.T_cam_table, float))[:3, 3]
    c = np.zeros(3) if view.table_centroid_mm is None else np.asarray(view.table_centroid_mm, float)
    d = P - c
    dq = np.zeros((len(P), 3, 6))              # dq / d(omega, s): -[p - c]x and I
    dq[:, 0, 1], dq[:, 0, 2] = d[:, 2], -d[:, 1]
    dq[:, 1, 0], dq[:, 1, 2] = -d[:, 2], d[:, 0]
    dq[:, 2, 0], dq[:, 2, 1] = d[:, 1], -d[:, 0]
    dq[:, :, 3:] = np.eye(3)
    ray = (P - C) / (h - C[2])                 # along the ray per unit of height
    dxy = dq[:, :2, :] - ray[:, :2, None] * dq[:, 2:3, :]
    M = np.einsum("ij,ijk->ik", N, dxy)        # (n, 6): normal displacement per table-error component
    return np.linalg.pinv(Ji.T @ Ji) @ Ji.T @ M


def table_term(fit: Fit, model: PhotoModel, view: View) -> np.ndarray:
    """3x3 covariance (x mm, y mm, theta rad; table axes) that the picture's table-pose error gives
    the fit (zero when the view has no table covariance)."""
    if view.table_cov is None:
        return np.zeros((3, 3))
    S = np.asarray(view.table_cov, float)
    if not np.all(np.isfinite(S)):
        return np.full((3, 3), np.inf)
    B = table_sensitivity(fit, model, view)
    return B @ S @ B.T


def _turned(cov: np.ndarray, theta: float) -> np.ndarray:
    """A 3x3 covariance of (x, y, theta) in obj axes seen in table axes (the obj turned by theta)."""
    R = np.eye(3)
    R[:2, :2] = rot(theta)
    return R @ np.asarray(cov, float) @ R.T


def pose_covariance(fit: Fit, model: PhotoModel, view: View) -> tuple[np.ndarray, np.ndarray, dict]:
    """Covariance of a located pose: (3x3 of x mm, y mm, theta rad in table axes about the obj
    origin, the 6x6 of (x, y, z mm, rotation vector rad) with the table contact's height and tilt as
    the CAD engine's, and the parts). The 3x3 is the sum of

    * fit: :func:`fit_cov` of this picture times the CAD engine's :data:`SIGMA_SCALE` squared, and the
      model's ``teach_cov`` (the template's own placement in its first picture) turned into table axes;
    * table: this picture's table-pose error propagated through the fit (:func:`table_sensitivity`),
      and the first teach picture's (``teach_table_cov``, obj axes, turned; a model without it takes
      this picture's term in its stead);
    * edge bias: :data:`EDGE_BIAS_PX` camera pixels of the teach picture and of this one (mm on the top
      face at the object), in x and in y: a shift of the whole outline that no fit can see.

    Returns (cov3, cov6, parts) with parts {"fit", "table": 3x3 lists, "edge_bias_mm2": teach px^2 +
    this px^2 (mm^2), "edge_bias_px"} so that a benchmark can refit the edge bias."""
    fit_c = SIGMA_SCALE ** 2 * fit_cov(fit, model) + _turned(model.teach_cov, fit.theta)
    table = table_term(fit, model, view)
    teach_table = table if model.teach_table_cov is None else _turned(model.teach_table_cov, fit.theta)
    here_px = camera_mm_per_px(view.K, view.T_cam_table, np.array([fit.x, fit.y]), model.height_mm)
    teach_px = here_px if model.teach_mm_per_px is None else float(model.teach_mm_per_px)
    px2 = teach_px ** 2 + here_px ** 2
    cov3 = fit_c + table + teach_table + np.diag([1.0, 1.0, 0.0]) * EDGE_BIAS_PX ** 2 * px2
    cov6 = np.zeros((6, 6))
    idx = [0, 1, 5]
    cov6[np.ix_(idx, idx)] = cov3
    cov6[2, 2] = CONTACT_SIGMA_MM ** 2
    cov6[3, 3] = cov6[4, 4] = np.radians(CONTACT_SIGMA_DEG) ** 2
    parts = {"fit": fit_c.tolist(), "table": (table + teach_table).tolist(), "edge_bias_mm2": px2,
             "edge_bias_px": EDGE_BIAS_PX}
    return cov3, cov6, parts
