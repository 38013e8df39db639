"""Rotary-axis angle measurement from images of a concentric-circle target.

Pixel convention: OpenCV (u, v), x right, y down, pixel centres at integer coordinates, a pixel
is ``img[v, u]``. Target frame ``tgt`` and the paint rule: :mod:`app.vision.rotary_target`.

Two methods, same detection front end (threshold -> contours -> concentric clusters -> which
cluster is which group):

``reference`` (the method of the source paper)
    Canny edge pixels near each circle, least-squares conic fit (``cv2.fitEllipse``, Fitzgibbon),
    the ellipse centre taken as the circle centre (mean of the group's ellipse centres,
    undistorted), and the rotation between two images as the mean change of direction of the
    lines joining all pairs of group centres (6 lines for 4 centres) in the image plane.

``direct`` (ours)
    1. Sub-pixel edge points: Devernay's correction of Canny's non-maximum suppression
       (F. Devernay, "A non-maxima suppression method for edge detection with sub-pixel accuracy",
       INRIA RR-2724, 1995; G. von Gioi & G. Randall, IPOL 2017): quadratic interpolation of the
       gradient magnitude along the axis closest to the gradient.
    2. Per circle a direct ellipse fit (Fitzgibbon, Pilu & Fisher, PAMI 1999, in the numerically
       stable form of Halir & Flusser, WSCG 1998) with iterative outlier rejection on the Sampson
       distance (3 x 1.4826 x MAD).
    3. The TRUE projected centres: the image of a circle's centre is not the centre of its
       ellipse (the offset grows with tilt and circle size). Instead of a per-group
       pole/polar construction we fit the pose ``T_cam_tgt`` of the whole target plane to all inlier
       edge points at once (intrinsics known): each undistorted edge point is back-projected onto
       the plane and its distance to the group centre must equal the printed radius
       (``scipy.optimize.least_squares``, residuals scaled to pixels, one nuisance parameter for
       the light/dark edge bias of gamma and blur). The projected centres are ``project(T_cam_tgt
       @ centre)``.
    4. Rotation from all images jointly: relative rotations ``R_i R_0^T`` (camera frame) share the
       rotary axis; the axis direction is their magnitude-weighted mean rotation vector and each
       image's angle is the twist of its relative rotation about that axis (swing-twist
       decomposition), so target eccentricity and mounting tilt do not enter.

Per run: ``E_i = (c_i - c_0) - (m_i - m_0)`` (commanded increment minus measured increment),
arc-seconds, ``E_0 = 0``.

Which detected group is which: clusters are matched to the layout by their number of circles and
radius ratios, then every assignment is scored by a planar pose (IPPE) of the centres. A symmetric
layout (the default: 4-fold) leaves several equally good labellings; the one whose rotation from
the first image is nearest to the commanded increment is taken, so axis errors must stay below
half the layout's symmetry angle (45 deg for the default). The orientation mark is printed for the
operator (mounting) and is not needed by the measurement.

Accuracy (benchmarks/rotary.md): limited by image noise; about 1-1.5" RMS at 1280x960 and 0.3-1"
at 5 MP with 2 grey levels of noise, 0-30 deg camera tilt; the reference: 4-8" at 0 deg tilt and
50-170" at 15-30 deg.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from app.geometry.transforms import pose_to_rvec_tvec, rvec_tvec_to_pose
from app.vision.intrinsics import Intrinsics
from app.vision.rotary_target import RotaryTarget

METHODS = ("direct", "reference")


class RotaryError(ValueError):
    """Bad input (intrinsics, angle list, image); the message says what and what to try."""


# --------------------------------------------------------------------------- camera

def _distort(m: np.ndarray, d: np.ndarray) -> np.ndarray:
    """OpenCV's radial-tangential model (k1, k2, p1, p2, k3) on normalised points (N, 2)."""
    k1, k2, p1, p2, k3 = d[:5]
    x, y = m[:, 0], m[:, 1]
    r2 = x * x + y * y
    rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return np.stack([x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                     y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y], axis=1)


def undistort_normalized(uv_px: np.ndarray, K: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Undistorted normalised coordinates (x/z, y/z) of distorted pixels, shape (N, 2).

    For the 4/5-coefficient model: fixed-point start and Newton steps on the forward model in
    numpy (round trip through ``cv2.projectPoints`` below 1e-9 px); other models: OpenCV's
    iterative ``cv2.undistortPoints`` with a tight stopping rule.
    """
    K = np.asarray(K, float)
    d = np.asarray(dist, float).reshape(-1)
    pts = np.asarray(uv_px, dtype=np.float64).reshape(-1, 1, 2)
    if len(pts) == 0:
        return np.zeros((0, 2))
    simple = d.size in (4, 5) or (d.size > 5 and not np.any(d[5:]))
    if not simple:
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
        return cv2.undistortPoints(pts, K, d, R=np.eye(3), P=np.eye(3), criteria=crit).reshape(-1, 2)
    d5 = np.zeros(5)
    d5[:min(5, d.size)] = d[:5]
    target = np.stack([(pts[:, 0, 0] - K[0, 2] - K[0, 1] / K[1, 1] * (pts[:, 0, 1] - K[1, 2])) / K[0, 0],
                       (pts[:, 0, 1] - K[1, 2]) / K[1, 1]], axis=1)
    m = target.copy()
    for _ in range(3):  # fixed-point start (OpenCV's scheme), then Newton on the forward model
        m = m + (target - _distort(m, d5))
    h = 1e-7
    for _ in range(2):
        f = _distort(m, d5) - target
        jx = (_distort(m + [h, 0], d5) - _distort(m - [h, 0], d5)) / (2 * h)
        jy = (_distort(m + [0, h], d5) - _distort(m - [0, h], d5)) / (2 * h)
        det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
        m = m - np.stack([(jy[:, 1] * f[:, 0] - jy[:, 0] * f[:, 1]) / det,
                          (-jx[:, 1] * f[:, 0] + jx[:, 0] * f[:, 1]) / det], axis=1)
    return m


def _project(intr: Intrinsics, T_cam_tgt: np.ndarray, xy_mm: np.ndarray) -> np.ndarray:
    P = np.c_[np.asarray(xy_mm, float).reshape(-1, 2), np.zeros(len(xy_mm))]
    rvec, tvec = pose_to_rvec_tvec(T_cam_tgt)
    uv, _ = cv2.projectPoints(P, rvec, tvec, intr.K_array, intr.dist_array)
    return uv.reshape(-1, 2)


# --------------------------------------------------------------------------- ellipses

@dataclass(frozen=True)
class EllipseFit:
    """Ellipse in pixel coordinates: centre (u, v) px, semi-axes (a >= b) px, angle of a (deg).

    ``conic``: (A, B, C, D, E, F) of ``A u² + B uv + C v² + D u + E v + F = 0``.
    ``rms_px``: RMS Sampson distance of the inliers; ``n_points``/``n_outliers``: edge points used
    and rejected.
    """

    center_uv_px: tuple[float, float]
    axes_px: tuple[float, float]
    angle_deg: float
    conic: tuple[float, ...]
    rms_px: float
    n_points: int
    n_outliers: int = 0

    def to_dict(self) -> dict[str, Any]:
        return {"center_uv_px": list(self.center_uv_px), "axes_px": list(self.axes_px),
                "angle_deg": self.angle_deg,
                "rms_px": self.rms_px if math.isfinite(self.rms_px) else None, "n_points": self.n_points,
                "n_outliers": self.n_outliers}


def _conic_matrix(c: Sequence[float]) -> np.ndarray:
    A, B, C, D, E, F = c
    return np.array([[A, B / 2, D / 2], [B / 2, C, E / 2], [D / 2, E / 2, F]])


def conic_to_ellipse(conic: Sequence[float]) -> tuple[tuple[float, float], tuple[float, float], float]:
    """(centre (u, v), semi-axes (a >= b), angle of a in deg) of an ellipse conic."""
    Q = _conic_matrix(conic)
    M = Q[:2, :2]
    c = np.linalg.solve(M, -Q[:2, 2])
    f = Q[2, 2] + Q[:2, 2] @ c  # value at the centre
    w, V = np.linalg.eigh(M)
    axes = np.sqrt(np.abs(-f / w))
    i = int(np.argmax(axes))
    ang = math.degrees(math.atan2(V[1, i], V[0, i])) % 180.0
    return (float(c[0]), float(c[1])), (float(axes.max()), float(axes.min())), ang


def _sampson(conic: np.ndarray, uv: np.ndarray) -> np.ndarray:
    A, B, C, D, E, F = conic
    x, y = uv[:, 0], uv[:, 1]
    val = A * x * x + B * x * y + C * y * y + D * x + E * y + F
    gx = 2 * A * x + B * y + D
    gy = B * x + 2 * C * y + E
    return val / np.maximum(np.hypot(gx, gy), 1e-300)


def fit_ellipse_direct(uv_px: np.ndarray) -> np.ndarray | None:
    """Direct least-squares ellipse fit (Halir & Flusser 1998, eqs. 13-29), conic (6,) or None.

    Points are centred and scaled first; the returned conic is in pixel coordinates.
    """
    uv = np.asarray(uv_px, dtype=float)
    if len(uv) < 6:
        return None
    m = uv.mean(axis=0)
    s = np.sqrt(((uv - m) ** 2).sum(axis=1).mean())
    if s <= 0:
        return None
    x, y = ((uv - m) / s).T
    D1 = np.stack([x * x, x * y, y * y], axis=1)
    D2 = np.stack([x, y, np.ones_like(x)], axis=1)
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
    except np.linalg.LinAlgError:
        return None
    M = S1 + S2 @ T
    M = np.array([M[2] / 2.0, -M[1], M[0] / 2.0])
    _, vecs = np.linalg.eig(M)
    vecs = np.real(vecs)
    cond = 4 * vecs[0] * vecs[2] - vecs[1] ** 2
    ok = np.flatnonzero(cond > 0)
    if ok.size == 0:
        return None
    a1 = vecs[:, ok[0]]
    cn = np.concatenate([a1, T @ a1])
    H = np.array([[1 / s, 0, -m[0] / s], [0, 1 / s, -m[1] / s], [0, 0, 1]])
    Q = H.T @ _conic_matrix(cn) @ H
    out = np.array([Q[0, 0], 2 * Q[0, 1], Q[1, 1], 2 * Q[0, 2], 2 * Q[1, 2], Q[2, 2]])
    return out / np.linalg.norm(out)


def fit_ellipse_robust(uv_px: np.ndarray, k_mad: float = 3.0, min_sigma_px: float = 0.02,
                       iterations: int = 5) -> tuple[EllipseFit, np.ndarray] | None:
    """Direct fit with outlier rejection: drop points with |Sampson| > k * 1.4826 * MAD, refit.

    Returns (fit, inlier mask over the input points) or None when no ellipse fits.
    """
    uv = np.asarray(uv_px, dtype=float)
    keep = np.ones(len(uv), bool)
    conic = None
    for _ in range(iterations):
        conic = fit_ellipse_direct(uv[keep])
        if conic is None:
            return None
        d = np.abs(_sampson(conic, uv))
        sigma = max(1.4826 * np.median(d[keep]), min_sigma_px)
        new = d < k_mad * sigma
        if new.sum() < 6:
            return None
        if np.array_equal(new, keep):
            break
        keep = new
    try:
        center, axes, ang = conic_to_ellipse(conic)
    except np.linalg.LinAlgError:
        return None
    d = _sampson(conic, uv[keep])
    return EllipseFit(center, axes, ang, tuple(float(c) for c in conic), float(np.sqrt(np.mean(d * d))),
                      int(keep.sum()), int((~keep).sum())), keep


# --------------------------------------------------------------------------- edges

def subpixel_edges(gray: np.ndarray, mask: np.ndarray, smooth_sigma_px: float = 1.0,
                   min_rel_magnitude: float = 0.25) -> np.ndarray:
    """Sub-pixel edge points (Devernay's NMS) inside ``mask``, shape (N, 2) (u, v) px.

    A pixel is an edge point when its gradient magnitude is a local maximum along the image axis
    closest to the gradient direction; its position is refined along that axis by the vertex of
    the parabola through the three magnitudes (Devernay 1995, eq. 1).
    """
    g = gray.astype(np.float32)
    if smooth_sigma_px > 0:
        g = cv2.GaussianBlur(g, (0, 0), smooth_sigma_px)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.hypot(gx, gy).astype(np.float64)
    H, W = mag.shape
    v, u = np.nonzero(mask)
    inner = (u > 0) & (u < W - 1) & (v > 0) & (v < H - 1)
    u, v = u[inner], v[inner]
    if u.size == 0:
        return np.zeros((0, 2))
    horiz = np.abs(gx[v, u]) >= np.abs(gy[v, u])
    du = horiz.astype(int)
    dv = 1 - du
    m0 = mag[v, u]
    ma = mag[v - dv, u - du]
    mb = mag[v + dv, u + du]
    peak = m0.max() if m0.size else 0.0
    is_max = (m0 > ma) & (m0 >= mb) & (m0 > min_rel_magnitude * peak)
    denom = ma - 2 * m0 + mb
    off = np.where(np.abs(denom) > 1e-12, 0.5 * (ma - mb) / np.where(denom == 0, 1, denom), 0.0)
    off = np.clip(off, -0.5, 0.5)
    uu = u + off * du
    vv = v + off * dv
    return np.stack([uu, vv], axis=1)[is_max]


def canny_edges(gray: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Integer Canny edge pixels (u, v) inside ``mask`` (thresholds from Otsu's level)."""
    otsu, _ = cv2.threshold(gray, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    e = cv2.Canny(gray, 0.5 * otsu, otsu)
    v, u = np.nonzero((e > 0) & mask)
    return np.stack([u, v], axis=1).astype(float)


# --------------------------------------------------------------------------- detection

@dataclass(frozen=True)
class _Cluster:
    ellipses: tuple  # cv2 RotatedRects ((cx, cy), (w, h), angle), largest first
    center_uv_px: np.ndarray


def _find_clusters(gray: np.ndarray, min_radius_px: float) -> list[_Cluster]:
    """Concentric groups of dark/bright region boundaries that are ellipses."""
    blur = cv2.GaussianBlur(gray, (0, 0), 1.0)
    _, binary = cv2.threshold(blur, 0, 255, cv2.THRESH_BINARY_INV + cv2.THRESH_OTSU)
    contours, _ = cv2.findContours(binary, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    ells = []
    for c in contours:
        if len(c) < 20:
            continue
        (cx, cy), (w, h), ang = cv2.fitEllipse(c)
        if min(w, h) < 2 * min_radius_px:
            continue
        area = abs(cv2.contourArea(c))
        e_area = math.pi * w * h / 4.0
        if e_area <= 0 or abs(area - e_area) > 0.06 * e_area:
            continue
        ells.append(((cx, cy), (w, h), ang))
    ells.sort(key=lambda e: -e[1][0] * e[1][1])
    used = [False] * len(ells)
    clusters = []
    for i, e in enumerate(ells):
        if used[i]:
            continue
        members = [e]
        used[i] = True
        for j in range(i + 1, len(ells)):
            if used[j]:
                continue
            f = ells[j]
            tol = max(2.0, 0.15 * min(f[1]) / 2.0)
            if math.dist(e[0], f[0]) < tol:
                members.append(f)
                used[j] = True
        c = np.array(members[-1][0])
        clusters.append(_Cluster(tuple(members), c))
    return clusters


def _compatible(cluster: _Cluster, radii: tuple[float, ...], tol: float = 0.2) -> bool:
    if len(cluster.ellipses) != len(radii):
        return False
    sizes = np.array([math.sqrt(e[1][0] * e[1][1]) for e in cluster.ellipses])
    ratio = sizes / sizes[0]
    want = np.array(radii) / radii[0]
    return bool(np.all(np.abs(ratio - want) < tol * want + 0.02))


@dataclass(frozen=True)
class _Assignment:
    cluster_of_group: tuple[int, ...]
    T_cam_tgt: np.ndarray
    rms_px: float


def _assignments(clusters: list[_Cluster], target: RotaryTarget, intr: Intrinsics,
                 max_combinations: int = 20000) -> list[_Assignment]:
    """Cluster-to-group assignments whose planar pose (IPPE on centres) fits, best first."""
    G = len(target.groups)
    cand = [[j for j, c in enumerate(clusters) if _compatible(c, g.circle_radii_mm)]
            for g in target.groups]
    obj = np.c_[target.centers_mm, np.zeros(G)]
    centers = np.array([c.center_uv_px for c in clusters]).reshape(-1, 2)
    m = undistort_normalized(centers, intr.K_array, intr.dist_array) if len(centers) else centers
    f = float(intr.K_array[0, 0])
    out = []
    n = 0
    for combo in itertools.product(*cand):
        if len(set(combo)) < G:
            continue
        n += 1
        if n > max_combinations:
            break
        img = m[list(combo)]
        try:
            ok, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, np.eye(3), None,
                                                         flags=cv2.SOLVEPNP_IPPE)
        except cv2.error:
            continue
        if not ok:
            continue
        for rv, tv in zip(rvecs, tvecs):
            T = rvec_tvec_to_pose(rv, tv)
            if T[2, 3] <= 0 or T[2, 2] > 0:  # target in front, printed face towards the camera
                continue
            proj, _ = cv2.projectPoints(obj, rv, tv, np.eye(3), None)
            rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1)))) * f
            out.append(_Assignment(tuple(combo), T, rms))
    out.sort(key=lambda a: a.rms_px)
    return out


# --------------------------------------------------------------------------- per image

@dataclass(frozen=True)
class GroupMeasurement:
    """One circle group in one image.

    center_uv_px : the measured image of the circle centre (direct: projected true centre;
        reference: mean ellipse centre), distorted pixel coordinates.
    ellipse_center_uv_px : mean centre of the group's fitted ellipses (for comparison).
    """

    group_index: int
    center_uv_px: tuple[float, float]
    ellipse_center_uv_px: tuple[float, float]
    ellipses: tuple[EllipseFit, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"group_index": self.group_index, "center_uv_px": list(self.center_uv_px),
                "ellipse_center_uv_px": list(self.ellipse_center_uv_px),
                "ellipses": [e.to_dict() for e in self.ellipses]}


@dataclass(frozen=True)
class RotaryImageResult:
    """Measurement of one image, or a failure with its reason (``ok`` False).

    T_cam_tgt : (4, 4) pose of the target in the camera (mm); for the reference method the
        coarse pose from the centres (only used to label the groups).
    rms_px : RMS residual of the final fit (direct: pose fit; reference: ellipse fits).
    """

    ok: bool
    reason: str
    method: str
    groups: tuple[GroupMeasurement, ...] = ()
    T_cam_tgt: np.ndarray | None = field(default=None, repr=False)
    rms_px: float = float("nan")
    n_edge_points: int = 0
    edge_bias_px: float = 0.0
    edges_uv_px: np.ndarray | None = field(default=None, repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "reason": self.reason, "method": self.method,
                "groups": [g.to_dict() for g in self.groups],
                "T_cam_tgt": None if self.T_cam_tgt is None else self.T_cam_tgt.tolist(),
                "rms_px": self.rms_px if math.isfinite(self.rms_px) else None,
                "n_edge_points": self.n_edge_points, "edge_bias_px": self.edge_bias_px}


def _gray(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        img = np.clip(img, 0, 255).astype(np.uint8)
    return img


def _edge_points(gray: np.ndarray, cluster: _Cluster, method: str, band_px: float) -> list[np.ndarray]:
    """Edge points of each circle of a cluster (largest first), by proximity to its rough ellipse.

    Works on a crop around the cluster (edge detection is local; keeps it fast).
    """
    H, W = gray.shape
    (cx, cy), (w, h), _ = cluster.ellipses[0]
    half = 0.5 * max(w, h) + band_px + 12
    u0, v0 = max(int(cx - half), 0), max(int(cy - half), 0)
    u1, v1 = min(int(cx + half) + 1, W), min(int(cy + half) + 1, H)
    crop = gray[v0:v1, u0:u1]
    labels = np.zeros(crop.shape, np.int16)
    th = max(3, int(round(2 * band_px + 1)))
    for k, e in enumerate(cluster.ellipses):
        (ex, ey), (ew, eh), ang = e
        cv2.ellipse(labels, ((ex - u0, ey - v0), (ew, eh), ang), k + 1, th)
    mask = labels > 0
    pts = subpixel_edges(crop, mask) if method == "direct" else canny_edges(crop, mask)
    if len(pts) == 0:
        return [np.zeros((0, 2)) for _ in cluster.ellipses]
    hh, ww = crop.shape
    lab = labels[np.clip(np.round(pts[:, 1]).astype(int), 0, hh - 1),
                 np.clip(np.round(pts[:, 0]).astype(int), 0, ww - 1)]
    pts = pts + [u0, v0]
    return [pts[lab == k + 1] for k in range(len(cluster.ellipses))]


def _plane_points(m: np.ndarray, T_cam_tgt: np.ndarray) -> np.ndarray:
    """Back-project normalised points (N, 2) onto the target plane: (N, 2) mm in ``tgt``."""
    R, t = T_cam_tgt[:3, :3], T_cam_tgt[:3, 3]
    n = R[:, 2]
    rays = np.c_[m, np.ones(len(m))]
    s = (n @ t) / (rays @ n)
    P = rays * s[:, None] - t
    return P @ R[:, :2]


def _fit_pose(m: np.ndarray, centers_mm: np.ndarray, radii_mm: np.ndarray, polarity: np.ndarray,
              scale_px_per_mm: np.ndarray, inv_rho_px: np.ndarray,
              T0: np.ndarray) -> tuple[np.ndarray, float, float, float]:
    """Least-squares pose of the target plane from edge points of known circles.

    m : (N, 2) undistorted normalised edge points; centers_mm (N, 2), radii_mm (N,): the circle
    each point belongs to; polarity (N,): +1 if the circle's inside is dark, else -1;
    scale_px_per_mm (N,): pixel scale used to express residuals in pixels; inv_rho_px (N,): local
    curvature (1/px) of the point's ellipse.
    Residual_i = scale_i * (|x_i - c_i| - r_i) - polarity_i * bias_px + kappa_px2 * inv_rho_i,
    with x_i the point back-projected onto the plane of the pose. Two nuisance parameters absorb
    the edge detector's known biases: ``bias_px`` the shift towards the dark side (gamma, blur
    asymmetry), ``kappa_px2`` the shift of a blurred curved edge towards its centre of curvature
    (about sigma²/(2 rho)). Returns (T_cam_tgt, bias_px, kappa_px2, rms_px).
    """
    rvec0, tvec0 = pose_to_rvec_tvec(T0)

    def resid(p: np.ndarray) -> np.ndarray:
        T = rvec_tvec_to_pose(p[:3], p[3:6])
        xy = _plane_points(m, T)
        r = np.hypot(xy[:, 0] - centers_mm[:, 0], xy[:, 1] - centers_mm[:, 1])
        return scale_px_per_mm * (r - radii_mm) - polarity * p[6] + p[7] * inv_rho_px

    p0 = np.r_[rvec0, tvec0, 0.0, 0.0]
    sol = least_squares(resid, p0, method="lm", x_scale="jac", xtol=1e-14, ftol=1e-14, max_nfev=400)
    # one robust pass: drop residuals beyond 4 sigma, refit
    r = sol.fun
    s = max(1.4826 * np.median(np.abs(r - np.median(r))), 1e-3)
    keep = np.abs(r) < 4 * s
    if keep.sum() < len(r) and keep.sum() > 20:
        m, centers_mm, radii_mm = m[keep], centers_mm[keep], radii_mm[keep]
        polarity, scale_px_per_mm, inv_rho_px = polarity[keep], scale_px_per_mm[keep], inv_rho_px[keep]
        sol = least_squares(resid, sol.x, method="lm", x_scale="jac", xtol=1e-14, ftol=1e-14,
                            max_nfev=400)
    T = rvec_tvec_to_pose(sol.x[:3], sol.x[3:6])
    return T, float(sol.x[6]), float(sol.x[7]), float(np.sqrt(np.mean(sol.fun ** 2)))


def _inverse_curvature(fit: EllipseFit, uv_px: np.ndarray) -> np.ndarray:
    """Curvature (1/px) of the fitted ellipse at the points' parametric angles:
    ``1/rho = a b / (a² sin² t + b² cos² t)^(3/2)``."""
    a, b = fit.axes_px
    ang = math.radians(fit.angle_deg)
    d = np.asarray(uv_px, float) - fit.center_uv_px
    x = (d[:, 0] * math.cos(ang) + d[:, 1] * math.sin(ang)) / a
    y = (-d[:, 0] * math.sin(ang) + d[:, 1] * math.cos(ang)) / b
    t = np.arctan2(y, x)
    return a * b / (a * a * np.sin(t) ** 2 + b * b * np.cos(t) ** 2) ** 1.5


def measure_image(image: np.ndarray, intrinsics: Intrinsics, target: RotaryTarget,
                  method: str = "direct", T_cam_tgt_ref: np.ndarray | None = None,
                  expected_rotation_deg: float = 0.0, min_radius_px: float = 6.0,
                  band_px: float = 3.0) -> RotaryImageResult:
    """Find the target's circle groups in one image and measure them.

    Parameters
    ----------
    image : (H, W) uint8 grey or (H, W, 3) BGR, as taken (not undistorted).
    intrinsics : the camera's K and dist.
    target : the printed layout.
    method : "direct" (ours) or "reference".
    T_cam_tgt_ref, expected_rotation_deg : the pose measured in the run's first image and the
        commanded increment since then (deg). With a symmetric layout they choose which detected
        group is which (the labelling whose rotation about the target normal is nearest); without
        them the best-fitting labelling is taken.
    min_radius_px : smallest circle (semi-minor axis, px) accepted as part of a group.
    band_px : half-width of the band around each rough ellipse where edges are collected.
    """
    if method not in METHODS:
        raise RotaryError(f"method must be one of {METHODS}, got {method!r}")
    gray = _gray(image)
    if gray.shape != (intrinsics.height, intrinsics.width):
        raise RotaryError(f"image is {gray.shape[1]}x{gray.shape[0]} px but the intrinsics are for "
                          f"{intrinsics.width}x{intrinsics.height}; use the calibration of this "
                          "camera at this resolution")
    clusters = _find_clusters(gray, min_radius_px)
    G = len(target.groups)
    assigns = _assignments(clusters, target, intrinsics)
    if not assigns:
        sizes = sorted(len(c.ellipses) for c in clusters)
        return RotaryImageResult(False, f"target not found: need {G} groups of concentric circles "
                                 f"matching the layout, saw {len(clusters)} concentric clusters with "
                                 f"{sizes} circles; check focus, lighting and that the whole target is "
                                 "in the image", method)
    best = assigns[0]
    if best.rms_px > 0.05 * max(intrinsics.width, intrinsics.height):
        return RotaryImageResult(False, f"circle groups found but they do not fit the layout "
                                 f"(reprojection {best.rms_px:.1f} px); check the target JSON "
                                 "matches the printed target", method)
    if T_cam_tgt_ref is not None:
        good = [a for a in assigns if a.rms_px < max(3.0, 4.0 * best.rms_px)]
        best = min(good, key=lambda a: abs(float(_wrap180(_inplane_deg(T_cam_tgt_ref, a.T_cam_tgt)
                                                          - expected_rotation_deg))))
    fits_by_group: list[list[EllipseFit]] = []
    inliers_by_group: list[list[np.ndarray]] = []
    for j in best.cluster_of_group:
        fits, inl = [], []
        for pts in _edge_points(gray, clusters[j], method, band_px):
            if method == "direct":
                res = fit_ellipse_robust(pts)
                if res is None:
                    return RotaryImageResult(False, f"ellipse fit failed on a circle with "
                                             f"{len(pts)} edge points; image too blurred or too dark?",
                                             method)
                fits.append(res[0])
                inl.append(pts[res[1]])
            else:
                if len(pts) < 6:
                    return RotaryImageResult(False, f"only {len(pts)} Canny edge points on a circle",
                                             method)
                (cx, cy), (w, h), ang = cv2.fitEllipse(pts.astype(np.float32))
                fits.append(EllipseFit((cx, cy), (max(w, h) / 2, min(w, h) / 2), ang, (), float("nan"),
                                       len(pts)))
                inl.append(pts)
        fits_by_group.append(fits)
        inliers_by_group.append(inl)
    ell_centers = np.array([np.mean([f.center_uv_px for f in fits], axis=0) for fits in fits_by_group])
    all_edges = np.concatenate([p for inl in inliers_by_group for p in inl])
    if method == "reference":
        groups = tuple(GroupMeasurement(g, tuple(map(float, ell_centers[g])),
                                        tuple(map(float, ell_centers[g])), tuple(fits_by_group[g]))
                       for g in range(G))
        return RotaryImageResult(True, "", method, groups, best.T_cam_tgt, float("nan"),
                                 len(all_edges), 0.0, all_edges)
    # direct: pose of the plane from all inlier edge points at once
    m_list, c_list, r_list, p_list, s_list, k_list = [], [], [], [], [], []
    for g, inl in enumerate(inliers_by_group):
        radii = target.groups[g].circle_radii_mm
        zg = (best.T_cam_tgt @ np.r_[target.groups[g].center_mm, 0, 1])[2]
        scale = intrinsics.K_array[0, 0] / max(zg, 1e-6)
        for k, pts in enumerate(inl):
            m_list.append(undistort_normalized(pts, intrinsics.K_array, intrinsics.dist_array))
            c_list.append(np.tile(target.groups[g].center_mm, (len(pts), 1)))
            r_list.append(np.full(len(pts), radii[k]))
            p_list.append(np.full(len(pts), 1.0 if k % 2 == 0 else -1.0))
            s_list.append(np.full(len(pts), scale))
            k_list.append(_inverse_curvature(fits_by_group[g][k], pts))
    T, bias, _, rms = _fit_pose(np.concatenate(m_list), np.concatenate(c_list), np.concatenate(r_list),
                                np.concatenate(p_list), np.concatenate(s_list), np.concatenate(k_list),
                                best.T_cam_tgt)
    proj = _project(intrinsics, T, target.centers_mm)
    groups = tuple(GroupMeasurement(g, tuple(map(float, proj[g])), tuple(map(float, ell_centers[g])),
                                    tuple(fits_by_group[g])) for g in range(G))
    return RotaryImageResult(True, "", method, groups, T, rms, len(all_edges), bias, all_edges)


# --------------------------------------------------------------------------- per run

@dataclass(frozen=True)
class RotaryRunResult:
    """Measured angles of a series (see module docstring for E's sign).

    angles_deg : commanded angles, deg. measured_deg : ``angles_deg[0] + measured increment``
    (deg). error_arcsec : commanded increment - measured increment (arc-seconds), first = 0.
    axis_cam : unit rotary-axis direction in the camera frame (direct method), else None.
    """

    ok: bool
    reason: str
    method: str
    angles_deg: tuple[float, ...]
    measured_deg: tuple[float, ...] = ()
    error_arcsec: tuple[float, ...] = ()
    images: tuple[RotaryImageResult, ...] = field(default=(), repr=False)
    axis_cam: tuple[float, float, float] | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "reason": self.reason, "method": self.method,
                "angles_deg": list(self.angles_deg), "measured_deg": list(self.measured_deg),
                "error_arcsec": list(self.error_arcsec),
                "axis_cam": None if self.axis_cam is None else list(self.axis_cam),
                "images": [r.to_dict() for r in self.images]}


def _wrap180(a: np.ndarray | float) -> np.ndarray:
    return (np.asarray(a, dtype=float) + 180.0) % 360.0 - 180.0


def _inplane_deg(T0: np.ndarray, T: np.ndarray) -> float:
    """Rough rotation (deg) of the target from pose T0 to pose T about the target's normal."""
    R = T0[:3, :3].T @ T[:3, :3]
    return math.degrees(math.atan2(R[1, 0], R[0, 0]))


def _twist_deg(R: np.ndarray, axis: np.ndarray) -> float:
    """Signed angle (deg) of the twist of rotation R about the unit ``axis`` (swing-twist)."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return math.degrees(2.0 * math.atan2(np.dot([x, y, z], axis), w))


def _reference_angles(results: list[RotaryImageResult], intr: Intrinsics,
                      want_deg: np.ndarray) -> np.ndarray:
    """Mean change of direction (deg) of all lines joining group centres, image plane.

    Each line's change is taken on the turn nearest to the commanded increment ``want_deg``.
    """
    first = None
    out = []
    for r, w in zip(results, want_deg):
        c = np.array([g.center_uv_px for g in r.groups])
        cu = cv2.undistortPoints(c.reshape(-1, 1, 2), intr.K_array, intr.dist_array,
                                 P=intr.K_array).reshape(-1, 2)
        pairs = list(itertools.combinations(range(len(cu)), 2))
        ang = np.array([math.atan2(-(cu[j, 1] - cu[i, 1]), cu[j, 0] - cu[i, 0]) for i, j in pairs])
        if first is None:
            first = ang
        d = np.degrees(ang - first)
        d = w + _wrap180(d - w)
        out.append(float(np.mean(d)))
    return np.array(out)


def measure_run(images: Sequence[np.ndarray], angles_deg: Sequence[float], intrinsics: Intrinsics,
                target: RotaryTarget, method: str = "direct") -> RotaryRunResult:
    """Measure a series of images taken at the commanded axis angles (deg).

    The commanded angles only resolve the labelling of a symmetric layout (errors must stay below
    half the layout's symmetry angle) and the sign of the axis; the measured increments come from
    the images alone.
    """
    angles = np.asarray(angles_deg, dtype=float).reshape(-1)
    if len(images) != len(angles):
        raise RotaryError(f"{len(images)} images but {len(angles)} commanded angles; give one angle "
                          "per image, in the same order")
    if len(images) < 2:
        raise RotaryError("need at least 2 images (the first one is the zero of the run)")
    first = measure_image(images[0], intrinsics, target, method)
    results = [first]
    for img, a in zip(images[1:], angles[1:]):
        results.append(measure_image(img, intrinsics, target, method,
                                     T_cam_tgt_ref=first.T_cam_tgt if first.ok else None,
                                     expected_rotation_deg=float(a - angles[0])))
    bad = [(i, r.reason) for i, r in enumerate(results) if not r.ok]
    if bad:
        msg = "; ".join(f"image {i}: {why}" for i, why in bad[:3])
        return RotaryRunResult(False, f"{len(bad)} of {len(results)} images failed: {msg}", method,
                               tuple(angles.tolist()), images=tuple(results))
    want = angles - angles[0]
    if method == "reference":
        meas = _reference_angles(results, intrinsics, want)
        if np.dot(np.sin(np.radians(meas)), np.sin(np.radians(want))) < 0:
            meas = -_reference_angles(results, intrinsics, -want)
        axis = None
    else:
        R0 = results[0].T_cam_tgt[:3, :3]
        rv = np.array([Rotation.from_matrix(r.T_cam_tgt[:3, :3] @ R0.T).as_rotvec() for r in results])
        n0 = R0[:, 2]
        signs = np.sign(rv @ n0)
        signs[signs == 0] = 1
        # magnitude-weighted mean direction; the target normal is a weak prior (worth a 0.5 deg
        # rotation) that takes over when the run hardly turns (repeats at one position)
        axis = (rv * signs[:, None]).sum(axis=0) + math.radians(0.5) * n0
        axis = axis / np.linalg.norm(axis)
        meas = np.array([_twist_deg(r.T_cam_tgt[:3, :3] @ R0.T, axis) for r in results])
        if np.dot(np.sin(np.radians(meas)), np.sin(np.radians(want))) < 0:
            meas, axis = -meas, -axis
        axis = tuple(float(x) for x in axis)
    meas = want + _wrap180(meas - want)  # unwrap to the turn of the commanded increment
    err = (want - meas) * 3600.0
    return RotaryRunResult(True, "", method, tuple(angles.tolist()),
                           tuple((angles[0] + meas).tolist()), tuple(err.tolist()),
                           tuple(results), axis)


def draw_rotary(image: np.ndarray, result: RotaryImageResult) -> np.ndarray:
    """BGR picture: edge points (green), fitted ellipses (blue), ellipse centres (red dots),
    measured centres (yellow crosses) with the group index."""
    img = image.copy()
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if not result.ok:
        cv2.putText(img, result.reason[:90], (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 255), 2)
        return img
    if result.edges_uv_px is not None:
        e = np.round(result.edges_uv_px).astype(int)
        e = e[(e[:, 0] >= 0) & (e[:, 0] < img.shape[1]) & (e[:, 1] >= 0) & (e[:, 1] < img.shape[0])]
        img[e[:, 1], e[:, 0]] = (0, 200, 0)
    for g in result.groups:
        for f in g.ellipses:
            cv2.ellipse(img, (tuple(map(float, f.center_uv_px)), (2 * f.axes_px[0], 2 * f.axes_px[1]),
                              f.angle_deg), (255, 0, 0), 1, cv2.LINE_AA)
        ec = tuple(int(round(x)) for x in g.ellipse_center_uv_px)
        cv2.circle(img, ec, 2, (0, 0, 255), -1)
        c = tuple(int(round(x)) for x in g.center_uv_px)
        cv2.drawMarker(img, c, (0, 220, 255), cv2.MARKER_CROSS, 14, 1)
        cv2.putText(img, str(g.group_index), (c[0] + 8, c[1] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                    (0, 220, 255), 2)
    return img
