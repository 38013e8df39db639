"""Stage 3: subpixel image edges along the model's edge normals and the least-squares pose fit
(``scipy.optimize.least_squares``, soft-L1 loss against occlusion and shadow edges), plus the edge
support used to verify a pose. Hidden lines are removed with a z-buffer of the part and the known
occluders. Units: mm and rad (table frame), px (image)."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree

from app.geometry.model_edges import (PreparedModel, project_points_jacobian, project_points_px,
                                      visible_edge_samples)
from app.geometry.transforms import transform_points
from app.vision.object_pose.edge_image import EdgeImage
from app.vision.object_pose.pose_params import FREE_6DOF, perturb, perturb_point_jacobian
from app.vision.object_pose.uncertainty import (PRIOR_PX, cauchy_weights, prior_jacobian, prior_noise_px,
                                                prior_offsets)


def edges_along_normals(lin: np.ndarray, uv: np.ndarray, normal: np.ndarray, search_px: float,
                         plateau_px: float = 2.5, step_px: float = 0.25, gamma: float | None = None):
    """Find the image edge near each point along its normal; position at the 50 % crossing.

    For each sample a profile of the gamma-decoded image is read along the normal (bilinear, every
    ``step_px``); the edge is the gradient peak within ``search_px`` that is strongest after a
    Gaussian preference for small offsets; its position is where the profile crosses the mean of the
    two plateaus ``plateau_px`` before and after the peak (linear interpolation).

    Returns offset (N,) px along the normal, contrast (N,) (plateau difference, linear units). With
    the image's ``gamma``, a contrast between plateaus darker than mid-grey is given as at mid-grey:
    scaled up by the decode's slope at mid-grey over its slope at the plateaus' levels (RMS of the
    two). Noise is even in grey levels, and decoding squeezes the dark ones: a floor set for
    mid-grey dropped a dark edge that stood as far above its noise as a bright one (on the devset
    under-exposed and noisy, 0-17 % of the true poses' edges passed it). Brighter plateaus are left
    as they are: raising their floor lost right results on the devset as rendered.
    """
    offs = np.arange(-(search_px + plateau_px + 1.0), search_px + plateau_px + 1.0 + 1e-9, step_px)
    L = len(offs)
    pts = uv[:, None, :] + offs[None, :, None] * normal[:, None, :]
    mapx = pts[..., 0].astype(np.float32)
    mapy = pts[..., 1].astype(np.float32)
    prof = cv2.remap(lin, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
    g = np.diff(prof, axis=1) / step_px                  # at mid offsets
    mid = 0.5 * (offs[:-1] + offs[1:])
    inwin = np.abs(mid) <= search_px
    wgt = np.abs(g) * np.exp(-0.5 * (mid / max(search_px * 0.75, 1.0)) ** 2)[None, :]
    wgt[:, ~inwin] = -1.0
    k = np.argmax(wgt, axis=1)                           # gradient between samples k and k+1
    kw = int(round(plateau_px / step_px))
    rows = np.arange(len(uv))
    a_idx = np.clip(k - kw, 0, L - 1)
    b_idx = np.clip(k + 1 + kw, 0, L - 1)
    lo = 0.5 * (prof[rows, a_idx] + prof[rows, np.clip(a_idx - 2, 0, L - 1)])
    hi = 0.5 * (prof[rows, b_idx] + prof[rows, np.clip(b_idx + 2, 0, L - 1)])
    level = 0.5 * (lo + hi)
    # crossing nearest to the peak within [a, b]
    win = np.arange(-kw, kw + 1)
    j0 = np.clip(k[:, None] + win[None, :], 0, L - 2)
    f0 = prof[rows[:, None], j0] - level[:, None]
    f1 = prof[rows[:, None], j0 + 1] - level[:, None]
    cross = (f0 * f1 <= 0) & (f0 != f1)
    dist_to_peak = np.where(cross, np.abs(win)[None, :], 10 ** 6)
    jj = np.argmin(dist_to_peak, axis=1)
    has = cross[rows, jj]
    j = j0[rows, jj]
    fa, fb = f0[rows, jj], f1[rows, jj]
    frac = np.where(has, fa / np.where(fa != fb, fa - fb, 1.0), 0.5)
    off = offs[j] + frac * step_px
    off = np.where(has, off, np.nan)
    contrast = np.abs(hi - lo)
    if gamma is not None:
        k = (gamma - 1.0) / gamma           # d(L) / d(grey) grows as grey^(gamma - 1) = L^k
        slope = np.sqrt(0.5 * (np.maximum(lo, 1e-6) ** (2 * k) + np.maximum(hi, 1e-6) ** (2 * k)))
        contrast = contrast * np.maximum(1.0, 0.5 ** (gamma - 1.0) / slope)
    return off, contrast


def near_clipped(clipped: np.ndarray | None, uv: np.ndarray, normal: np.ndarray, off: np.ndarray,
                 reach_px: float = 3.5) -> np.ndarray:
    """(N,) bool: a clipped pixel (``clipped``, (H, W) bool) lies on the sample's normal within
    ``reach_px`` of the image edge found there (``uv + off * normal``, px): the plateau the 50 %
    crossing is taken against is cut off, and the crossing sits toward the darker side by an
    amount the image does not tell (a fraction of the blur's width). The reach covers
    :func:`edges_along_normals`' plateaus (2.5 px, read 0.5 px further out)."""
    n = len(uv)
    if clipped is None or n == 0:
        return np.zeros(n, bool)
    ts = np.arange(-reach_px, reach_px + 1e-9, 0.5)
    at = np.nan_to_num(np.asarray(off, float))[:, None] + ts[None, :]
    P = uv[:, None, :] + at[..., None] * normal[:, None, :]
    hit = cv2.remap(clipped.view(np.uint8), P[..., 0].astype(np.float32), P[..., 1].astype(np.float32),
                    cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return hit.any(axis=1)


def _clear_of_other_edges(model: PreparedModel, es, radius_px: float, max_turn_deg: float = 20.0) -> np.ndarray:
    """(N,) bool: no other visible edge comes within ``radius_px`` of the sample in the image, apart
    from the continuation of its own line (same direction, on the line). Profiles near corners,
    junctions of a rim with a silhouette, or a second parallel edge close by are biased."""
    uv = es.uv_px
    if len(uv) < 2:
        return np.ones(len(uv), bool)
    tree = cKDTree(uv)
    pairs = tree.query_pairs(radius_px, output_type="ndarray")
    ok = np.ones(len(uv), bool)
    if len(pairs) == 0:
        return ok
    i, j = pairs[:, 0], pairs[:, 1]
    e = model.sample_edge[es.index]
    diff_edge = e[i] != e[j]
    n = es.normal_uv
    cos_t = np.abs(np.einsum("ij,ij->i", n[i], n[j]))
    d = uv[j] - uv[i]
    off_i = np.abs(np.einsum("ij,ij->i", n[i], d))
    off_j = np.abs(np.einsum("ij,ij->i", n[j], d))
    bad = diff_edge & ((cos_t < np.cos(np.radians(max_turn_deg))) | (np.maximum(off_i, off_j) > 0.75))
    ok[i[bad]] = False
    ok[j[bad]] = False
    return ok



def refine_pose(eimg: EdgeImage, model: PreparedModel, T_table_obj: np.ndarray, T_cam_table, K, dist,
            occluders_cam, subset, *, free=FREE_6DOF, radii=(5.0, 3.0, 2.0, 2.0), min_contrast: float,
            round_axis_table: np.ndarray | None = None, f_scale_px: float = 0.5,
            prior: tuple[np.ndarray, float, float, np.ndarray] | None = None, reweight: int = 0,
            drop_clipped: bool = False, prior_noise_scale: float | None = None):
    """Iterated least-squares fit of the free pose parameters to subpixel image edges.

    Parameters p = (dx, dy, dz mm, rotation vector rad) move the part about its centre of mass in
    the table frame; ``free`` selects which are fitted (``FREE_REST`` keeps the part flat). Each
    round re-computes the visible edges (z-buffer with the occluders) and looks for the image edge
    along each edge normal within the round's radius. Returns (T_table_obj, info).

    ``prior = (T_rest, sigma_z_mm, sigma_tilt_rad, hull_obj)``: the part rests on a surface, so its height and
    tilt are known beforehand to within the contact's sigmas (a chip under an edge, an unknown riser)
    about ``T_rest``: they enter as Gaussian prior residuals (in units of :data:`PRIOR_PX` pixels of
    edge noise, or of the fit's own: ``prior_noise_scale``) and as prior information in
    :func:`covariance` (a maximum a-posteriori fit).

    ``reweight``: after each round's soft-L1 solve, that many re-solves with Cauchy weights on the
    edge residuals (iteratively reweighted least squares, :func:`cauchy_weights`), the prior's
    residuals unweighted. At the true pose the devset's edges sit within 0.06 px (median) of the
    model's, while a few samples caught on a clamp's or a shadow's edge 1-2 px away still pull a
    soft-L1 fit (0.5 px scale) by tenths of a millimetre along the line of sight; the Cauchy weight
    at a scale from the residuals' own spread lets them go. The prior must not be robustified: it
    would be discounted exactly where it matters.

    ``prior_noise_scale``: in the re-solves, the prior is weighed against the edge noise this fit
    shows (:func:`prior_noise_px` with this factor, the covariance's ``data_scale``) instead of an
    assumed :data:`PRIOR_PX`: the fit then strikes the balance that :func:`covariance` states. With
    0.5 px assumed where the devset's final fits scatter by 0.10-0.15 px, the prior counted 3-8 times
    what the covariance gives it, and parts lying tilted on a chip were fitted with 40-95 % of their
    tilt taken out (setup_000: 0.50 deg fitted as 0.31, setup_007: 0.49 as 0.03).

    ``drop_clipped``: samples with a clipped pixel beside their edge (:func:`near_clipped`) are left
    out while 10 others remain: their crossings sit toward the dark side by an unknown amount.
    """
    W, H = eimg.width, eimg.height
    free = np.asarray(free, dtype=np.int64)
    T = T_table_obj.copy()
    info: dict = {}
    for r in radii:
        T_cam_obj = T_cam_table @ T
        es = visible_edge_samples(model, T_cam_obj, K, dist, W, H, occluders=occluders_cam,
                                  occlusion_test=True, subset=subset)
        if len(es.index) < 12:
            return T, {"n_visible": len(es.index), "failed": "too few of its edges are visible"}
        off, contrast = edges_along_normals(eimg.linear, es.uv_px, es.normal_uv, r, gamma=eimg.gamma)
        seen = np.isfinite(off) & (contrast >= min_contrast)
        good = seen & _clear_of_other_edges(model, es, r + 3.0)
        if good.sum() < 10:
            # a small part (a few dozen pixels) has every sample near another edge: look closer in
            good = seen & _clear_of_other_edges(model, es, min(r, 2.0) + 1.0)
        if good.sum() < 10:
            return T, {"n_visible": len(es.index), "failed": "too few image edges along the model's edges"}
        # an edge beside a clipped face is off toward the dark side by an amount the image does not
        # tell: fitted without those while enough others remain (the support score still counts
        # them: the edge is there, within a pixel)
        if drop_clipped:
            unclipped = good & ~near_clipped(eimg.clipped, es.uv_px, es.normal_uv, off)
            if unclipped.sum() >= 10:
                good = unclipped
        X = es.points_obj[good]
        n = es.normal_uv[good]
        target = es.uv_px[good] + off[good, None] * n
        c_table = transform_points(T, model.center_obj[None])[0]
        T0 = T
        # the samples along one model edge share its errors: the data carry about as much information
        # as that many edges, not samples; the prior is weighed against them accordingly
        n_cl = len(np.unique(model.sample_edge[es.index[good]]))
        per_edge = float(np.sqrt(max(good.sum() / max(n_cl, 1), 1.0)))
        w_prior = PRIOR_PX * per_edge
        pin = None
        if round_axis_table is not None and len(free) == 6:
            pin = round_axis_table

        def full(q, free=free):
            p = np.zeros(6)
            p[free] = q
            return p

        def fun(q, X=X, n=n, target=target, T0=T0, c_table=c_table, pin=pin, w_prior=w_prior, sw=None):
            p = full(q)
            T1 = perturb(T0, c_table, p)
            uv = project_points_px(transform_points(T_cam_table @ T1, X), K, dist)
            res = np.einsum("ij,ij->i", n, uv - target)
            if sw is not None:
                res = sw * res
            if pin is not None:   # round part: pin the unobservable spin
                res = np.append(res, 1e4 * float(p[3:6] @ pin))
            if prior is not None:
                res = np.append(res, w_prior * prior_offsets(T1, prior))
            return res

        Y = transform_points(T0, X)          # the samples in the table frame at the round's start
        R_ct = T_cam_table[:3, :3]

        def jac(q, X=X, Y=Y, n=n, T0=T0, c_table=c_table, pin=pin, w_prior=w_prior, sw=None):
            """Analytic Jacobian of ``fun`` (the prior's rows by central differences): one projection
            with its derivative instead of a projection per parameter."""
            p = full(q)
            T1 = perturb(T0, c_table, p)
            duv = project_points_jacobian(transform_points(T_cam_table @ T1, X), K, dist)   # (N, 2, 3)
            g = np.einsum("ni,nij->nj", n, duv) @ R_ct          # d(residual) / d(table point), px per mm
            J = np.einsum("nj,njk->nk", g, perturb_point_jacobian(Y, c_table, p))
            if sw is not None:
                J = sw[:, None] * J
            rows = [J]
            if pin is not None:
                rows.append(np.concatenate([np.zeros(3), 1e4 * pin])[None])
            if prior is not None:
                rows.append(w_prior * prior_jacobian(T0, c_table, p, prior, free))
            return np.concatenate(rows)[:, free]

        xs = np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3])[free]
        sol = least_squares(fun, np.zeros(len(free)), jac=jac, loss="soft_l1", f_scale=f_scale_px, method="trf",
                            x_scale=xs, max_nfev=60)
        w = None
        for _ in range(reweight):
            rd = fun(sol.x)[:len(X)]
            w = cauchy_weights(rd)
            kw = {"sw": np.sqrt(w)}
            if prior is not None and prior_noise_scale is not None:
                kw["w_prior"] = per_edge * prior_noise_px(rd, w, prior_noise_scale)
            sol = least_squares(fun, sol.x, jac=jac, kwargs=kw, method="trf", x_scale=xs, max_nfev=60)
        T = perturb(T0, c_table, full(sol.x))
        info = {"sol": sol, "X": X, "n": n, "target": target, "T0": T0, "c_table": c_table,
                "n_visible": len(es.index), "n_used": int(good.sum()), "free": free, "pin": pin, "prior": prior,
                "edge": model.sample_edge[es.index[good]], "weights": w}
    return T, info


def edge_support(eimg, model, T_table_obj, T_cam_table, K, dist, occluders_cam, subset, *, min_contrast,
            support_px: float = 1.5, search_px: float = 3.0):
    """Share of the visible model samples with an image edge within ``support_px`` (subpixel)."""
    W, H = eimg.width, eimg.height
    es = visible_edge_samples(model, T_cam_table @ T_table_obj, K, dist, W, H, occluders=occluders_cam,
                              occlusion_test=True, subset=subset)
    if len(es.index) == 0:
        return 0.0, es, np.zeros(0, bool)
    off, contrast = edges_along_normals(eimg.linear, es.uv_px, es.normal_uv, search_px, gamma=eimg.gamma)
    sup = np.isfinite(off) & (np.abs(np.nan_to_num(off, nan=99.0)) <= support_px) & (contrast >= min_contrast)
    return float(sup.mean()), es, sup

