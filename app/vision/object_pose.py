"""Pose of a CAD part on the machine table from one image, without markers on the part.

Given the table's pose ``T_cam_table`` (from its fiducials), the intrinsics and a prepared model
(:func:`app.geometry.model_edges.prepare_model`), :func:`locate_object` finds ``T_cam_obj`` and
``T_table_obj = inv(T_cam_table) @ T_cam_obj`` in four stages:

1. **search** (wide, several starts): the part lies on the table, so a pose is a resting state, a
   position (x, y) and a rotation theta about the table normal. Every image edge pixel is cast onto
   the horizontal planes at the heights of the model's horizontal edges (exact for any perspective),
   and a generalised Hough transform (Ballard 1981, "Generalizing the Hough transform to detect
   arbitrary shapes", Pattern Recognition 13(2)) lets each pair (image edge, model edge sample) with
   matching direction vote for (x, y, theta). The strongest distinct peaks are the starts.
2. **planar fit**: each start is aligned in (x, y, theta) by iterated point-to-line matching against
   the nearest image edge pixel of compatible direction (oriented chamfer ICP), and scored by the
   share of the model's visible edges with an image edge nearby.
3. **refinement** of the best starts in full 6 DoF (``scipy.optimize.least_squares``, soft-L1 loss
   against occlusion and shadow edges): each visible model edge sample (hidden lines removed with a
   z-buffer of the part and the known occluders) looks along its image normal for the image edge and
   takes its position at the 50 % intensity crossing of the gamma-decoded profile.
4. **verification**: share of the visible model edges supported by image edges, margin to the best
   different pose, the part's symmetries (equivalent poses; a datum chosen by features only when the
   features decide it), uncertainty from the least-squares covariance ``(J^T J)^-1 s^2``.

A fit that is not good enough, or not clearly better than a different pose, is returned as an
:class:`ObjectFailure` with the reason; it is never returned as a pose.

Conventions: DESIGN.md (``T_a_b``, mm, degrees at the boundary); pixels are OpenCV's (u right, v down,
centres at integers); ``image`` is 8-bit grey (a colour image is converted).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import fft as sfft
from scipy import ndimage
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from app.geometry.model_edges import PreparedModel, project_points_px, render_depth, visible_edge_samples
from app.geometry.transforms import check_pose, inv, make_pose, transform_points
from app.vision.blas_threads import one_blas_thread

__all__ = [
    "EdgeImage",
    "ObjectPose",
    "ObjectFailure",
    "Recognition",
    "prepare_image",
    "mask_known_edges",
    "locate_object",
    "search_poses",
    "recognise",
    "draw_object",
]


# --------------------------------------------------------------------------------------------------
# results
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class ObjectPose:
    """A located part. Poses 4x4 (mm); ``sigma`` is 1-sigma of ``T_table_obj``: keys ``x_mm, y_mm,
    z_mm`` (the obj frame's origin, table axes) and ``rx_deg, ry_deg, rz_deg`` (small rotations about
    the table axes); NaN for a rotation that the part's round symmetry leaves undetermined.

    score : verification score in [0, 1] (share of visible model edge samples supported by an image
        edge within ``support_px`` after the fit)
    inlier_edge_fraction : same share counted with the fit's robust inliers (|residual| < 3 scale)
    residual_px : RMS of the inlier residuals along the edge normals
    visible_fraction : share of the model's edges in view that the given occluders do not hide
    supported_edge_px : length (px) of the model's visible edges supported by image edges
    unexplained_fraction : share of the image edge pixels inside the part's outline (3 px in) that no
        visible model edge explains (a smaller model fitted into a bigger part leaves many)
    margin : score minus the score of the best different (non-equivalent) pose found, or NaN if none
    distinctiveness : least drop of the score when the pose is moved by 4 px (x, y) or turned
    tilt_deg : angle between the part's resting normal and the table normal after the 6-DoF fit;
        ``tilt_sigma_deg`` its 1-sigma; flag "tilt" when it exceeds both ``max_tilt_deg`` and 3 sigma.
        ``T_table_obj`` is the flat fit; the free fit is ``T_table_obj_6dof``
    equivalent_poses : ``T_table_obj @ S`` for every symmetry S of the part (same look, other datum)
    datum_note : how the datum (which of the equivalent poses) was chosen, or why it could not be
    uncertainty_ok : every sigma within the tolerances given to :func:`locate_object`
    flags : warnings ("tilt", "datum_ambiguous", "uncertainty", "few_edges")
    """

    model_name: str
    T_cam_obj: np.ndarray
    T_table_obj: np.ndarray
    resting_state: int
    score: float
    inlier_edge_fraction: float
    residual_px: float
    visible_fraction: float
    supported_edge_px: float
    unexplained_fraction: float
    n_edge_samples: int
    sigma: dict
    uncertainty_ok: bool
    T_table_obj_6dof: np.ndarray
    tilt_deg: float
    tilt_sigma_deg: float
    height_offset_mm: float
    margin: float
    runner_up_score: float
    distinctiveness: float
    equivalent_poses: tuple
    datum_ambiguous: bool
    datum_note: str
    flags: tuple
    timings_ms: dict
    chain: tuple = ()          # what it rests on, nearest first, down to the table (set by the caller)
    covariance: np.ndarray | None = None   # 6x6 of (origin x, y, z mm, rotation vector rad), table axes

    def __bool__(self) -> bool:
        return True

    def to_dict(self) -> dict:
        return {
            "ok": True,
            "model": self.model_name,
            "T_cam_obj": self.T_cam_obj.tolist(),
            "T_table_obj": self.T_table_obj.tolist(),
            "resting_state": self.resting_state,
            "score": self.score,
            "inlier_edge_fraction": self.inlier_edge_fraction,
            "residual_px": self.residual_px,
            "visible_fraction": self.visible_fraction,
            "supported_edge_px": self.supported_edge_px,
            "unexplained_fraction": self.unexplained_fraction,
            "n_edge_samples": self.n_edge_samples,
            "sigma": {k: (None if not np.isfinite(v) else float(v)) for k, v in self.sigma.items()},
            "uncertainty_ok": self.uncertainty_ok,
            "T_table_obj_6dof": self.T_table_obj_6dof.tolist(),
            "tilt_deg": self.tilt_deg,
            "tilt_sigma_deg": None if not np.isfinite(self.tilt_sigma_deg) else self.tilt_sigma_deg,
            "height_offset_mm": self.height_offset_mm,
            "chain": list(self.chain),
            "cov6": None if self.covariance is None else np.where(np.isfinite(self.covariance), self.covariance, 0.0).tolist(),
            "margin": None if not np.isfinite(self.margin) else self.margin,
            "runner_up_score": None if not np.isfinite(self.runner_up_score) else self.runner_up_score,
            "distinctiveness": self.distinctiveness,
            "equivalent_poses": [T.tolist() for T in self.equivalent_poses],
            "datum_ambiguous": self.datum_ambiguous,
            "datum_note": self.datum_note,
            "flags": list(self.flags),
            "timings_ms": dict(self.timings_ms),
        }


@dataclass(frozen=True, eq=False)
class ObjectFailure:
    """A part that was not located; ``reason`` is the sentence for the operator.

    kind : "not_found" | "ambiguous" | "bad_input"
    candidates : best hypotheses seen, each ``{"T_table_obj": 4x4 list, "score": float}``
    """

    model_name: str
    kind: str
    reason: str
    best_score: float
    candidates: tuple
    timings_ms: dict

    def __bool__(self) -> bool:
        return False

    def to_dict(self) -> dict:
        return {"ok": False, "model": self.model_name, "kind": self.kind, "reason": self.reason,
                "best_score": self.best_score, "candidates": list(self.candidates),
                "timings_ms": dict(self.timings_ms)}


@dataclass(frozen=True, eq=False)
class Recognition:
    """Outcome of :func:`recognise`.

    accepted : located parts that passed (score >= min_score, margin >= min_margin), best first
    ranked : every candidate as ``{"model", "score", "ok", "reason"}``, best first
    reason : "" when something was accepted, else why nothing was ("not recognised: ...")
    """

    accepted: tuple
    ranked: tuple
    reason: str
    timings_ms: dict

    @property
    def best(self) -> ObjectPose | None:
        return self.accepted[0] if self.accepted else None

    def __bool__(self) -> bool:
        return bool(self.accepted)

    def to_dict(self) -> dict:
        return {"ok": bool(self.accepted), "accepted": [a.to_dict() for a in self.accepted],
                "ranked": list(self.ranked), "reason": self.reason, "timings_ms": dict(self.timings_ms)}


# --------------------------------------------------------------------------------------------------
# image preparation
# --------------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class EdgeImage:
    """An image prepared once for all candidate models.

    linear : (H, W) float32 intensity with the camera's gamma undone (0..1)
    edges : (H, W) uint8 Canny edge map
    dist_px : (H, W) float32 distance to the nearest edge pixel
    nearest : (H, W) int32 index into ``edge_uv`` of that pixel
    edge_uv : (E, 2) float edge pixel positions (u, v); ``edge_angle`` (E,) gradient direction, rad
    """

    width: int
    height: int
    linear: np.ndarray
    edges: np.ndarray
    dist_px: np.ndarray
    nearest: np.ndarray
    edge_uv: np.ndarray
    edge_angle: np.ndarray
    edge_mag: np.ndarray
    noise_linear: float
    cache: dict = field(default_factory=dict)   # per-image intermediate results shared by models


def prepare_image(image: np.ndarray, *, gamma: float = 2.2, canny_low: float | None = None,
                  canny_high: float | None = None, smooth_sigma_px: float = 1.0) -> EdgeImage:
    """Gamma-decode the image and extract its edges (Canny), their directions and distance map.

    ``canny_low``/``canny_high`` default to 2.5x / 6x the noise of the Sobel magnitude, estimated
    from the image (median absolute deviation), with floors of 8 and 20 grey levels.
    """
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        raise ValueError(f"image must be 8-bit grey or BGR, got dtype {img.dtype}")
    H, W = img.shape
    lin = ((img.astype(np.float32) / 255.0) ** float(gamma)).astype(np.float32)
    sm = cv2.GaussianBlur(img, (0, 0), smooth_sigma_px) if smooth_sigma_px > 0 else img
    smf = sm.astype(np.float32)
    gx = cv2.Sobel(smf, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smf, cv2.CV_32F, 0, 1, ksize=3)
    mag = np.hypot(gx, gy)
    # noise: MAD of the difference between the image and its blur (flat areas dominate)
    resid = img.astype(np.float32) - smf
    noise = float(1.4826 * np.median(np.abs(resid - np.median(resid)))) + 1e-3
    sob_noise = noise * 2.0
    lo = canny_low if canny_low is not None else max(8.0, 2.5 * sob_noise)
    hi = canny_high if canny_high is not None else max(20.0, 6.0 * sob_noise)
    gx16 = np.clip(np.round(gx), -32767, 32767).astype(np.int16)
    gy16 = np.clip(np.round(gy), -32767, 32767).astype(np.int16)
    edges = cv2.Canny(gx16, gy16, lo, hi, L2gradient=True)
    noise_lin = float(noise / 255.0 * gamma * 0.5 ** (gamma - 1))  # slope of the decode at mid-grey
    return _edge_image(lin, edges, np.arctan2(gy, gx), mag, noise_lin)


def _edge_image(lin, edges, angle, mag, noise_lin) -> EdgeImage:
    H, W = edges.shape
    dist_px, labels = cv2.distanceTransformWithLabels(
        np.where(edges > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, 5,
        labelType=cv2.DIST_LABEL_PIXEL)
    vv, uu = np.nonzero(edges)
    edge_uv = np.stack([uu, vv], axis=1).astype(float)
    nearest = (labels.astype(np.int32) - 1) if len(uu) else np.zeros_like(labels, dtype=np.int32)
    full_angle = angle if angle.shape == edges.shape else None
    return EdgeImage(width=W, height=H, linear=lin, edges=edges, dist_px=dist_px.astype(np.float32),
                     nearest=nearest, edge_uv=edge_uv,
                     edge_angle=full_angle[vv, uu] if full_angle is not None else angle,
                     edge_mag=mag[vv, uu] if mag.shape == edges.shape else mag, noise_linear=noise_lin,
                     cache={"angle_full": angle, "mag_full": mag})


def mask_known_edges(eimg: EdgeImage, known: list[tuple[PreparedModel, np.ndarray]], K, dist,
                     width_px: float = 1.5) -> EdgeImage:
    """A copy of ``eimg`` without the edge pixels that known geometry explains.

    ``known`` holds pairs (prepared model, ``T_cam_model``), typically the table itself (its border,
    T-slots and marker-free structure) at ``T_cam_table``: corners and steps of the table otherwise
    look like small workpieces to the search. Edge pixels within ``width_px`` of a visible edge of a
    known model are removed; the grey image used for the subpixel fit is unchanged.
    """
    K = np.asarray(K, float)
    dist = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    mask = np.zeros(eimg.edges.shape, np.uint8)
    for model, T_cam_model in known:
        es = visible_edge_samples(model, np.asarray(T_cam_model, float), K, dist, eimg.width, eimg.height,
                                  max_buffer_px=1200)
        step = max(1, int(np.ceil(len(es.uv_px) / 400000)))
        for u, v in np.rint(es.uv_px[::step] * 4).astype(np.int64):
            cv2.circle(mask, (int(u), int(v)), int(round(width_px * 4)), 255, -1, shift=2)
    edges = np.where(mask > 0, 0, eimg.edges).astype(np.uint8)
    return _edge_image(eimg.linear, edges, eimg.cache.get("angle_full"), eimg.cache.get("mag_full"),
                       eimg.noise_linear)


def mask_table_regions(eimg: EdgeImage, regions_table: list, T_cam_table: np.ndarray, K, dist,
                       dilate_px: float = 2.0) -> EdgeImage:
    """A copy of ``eimg`` without the edge pixels inside regions of the table (each a polygon (N, 3)
    in the table frame, mm), typically the printed fiducial labels: their black and white cells are
    exactly the small squares a small part looks like. A part's own edges crossing such a region
    are lost there too (a part rarely stands on a marker; it would hide it from the table pose)."""
    K = np.asarray(K, float)
    dist = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    mask = np.zeros(eimg.edges.shape, np.uint8)
    for poly in regions_table:
        P = transform_points(np.asarray(T_cam_table, float), np.asarray(poly, float).reshape(-1, 3))
        if np.any(P[:, 2] <= 1.0):
            continue
        uv = project_points_px(P, K, dist)
        cv2.fillPoly(mask, [np.rint(uv * 4).astype(np.int32)], 255, lineType=cv2.LINE_8, shift=2)
    if not mask.any():
        return eimg
    r = max(1, int(np.ceil(dilate_px)))
    mask = cv2.dilate(mask, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    edges = np.where(mask > 0, 0, eimg.edges).astype(np.uint8)
    return _edge_image(eimg.linear, edges, eimg.cache.get("angle_full"), eimg.cache.get("mag_full"),
                       eimg.noise_linear)


# --------------------------------------------------------------------------------------------------
# pose parametrisation
# --------------------------------------------------------------------------------------------------


def _perturb(T_table_obj: np.ndarray, c_table: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``T_table_obj`` moved by p = (dx, dy, dz mm, rotation vector rad) about the point c_table."""
    R = Rotation.from_rotvec(p[3:6]).as_matrix()
    T = make_pose(R, c_table + p[:3] - R @ c_table)
    return T @ T_table_obj


def _perturb3(T_table_obj: np.ndarray, c_table: np.ndarray, q: np.ndarray) -> np.ndarray:
    return _perturb(T_table_obj, c_table, np.array([q[0], q[1], 0.0, 0.0, 0.0, q[2]]))


# --------------------------------------------------------------------------------------------------
# stage 1: generalised Hough transform on the table planes
# --------------------------------------------------------------------------------------------------


@dataclass
class _Hyp:
    state: int
    T_table_obj: np.ndarray
    votes: float = 0.0
    score: float = 0.0
    height_mm: float = 0.0
    refined: dict | None = None


def _edge_rays_table(eimg: EdgeImage, K, dist, T_table_cam, max_edges: int, rng):
    """Subsampled edge pixels as rays in the table frame, plus rays one px along the edge."""
    n = len(eimg.edge_uv)
    if n == 0:
        return None
    idx = np.arange(n) if n <= max_edges else np.sort(rng.choice(n, max_edges, replace=False))
    uv = eimg.edge_uv[idx]
    ang = eimg.edge_angle[idx]
    tang = np.stack([-np.sin(ang), np.cos(ang)], axis=1)
    both = np.vstack([uv, uv + 2.0 * tang]).reshape(-1, 1, 2)
    xy = cv2.undistortPoints(both, K, np.asarray(dist, float)).reshape(-1, 2)
    rays = np.column_stack([xy, np.ones(len(xy))]) @ T_table_cam[:3, :3].T
    return idx, rays[: len(idx)], rays[len(idx):]


def _levels(m_z: np.ndarray, w: np.ndarray | None = None, max_levels: int = 4,
            gap_mm: float = 0.5) -> list[tuple[float, np.ndarray]]:
    """Template points grouped by height: (height mm, indices) of at most ``max_levels`` planes.

    Points closer than ``gap_mm`` in height form one group (chains of them too). When there are more
    groups than planes, the heaviest groups (by weight ``w``) become the planes and the other points
    join the nearest plane within ``gap_mm`` or are left out: merging two real heights (a vise's base
    at 0 and its ways at 14 mm) would put both on a plane where neither is."""
    w = np.ones(len(m_z)) if w is None else np.asarray(w, float)
    order = np.argsort(m_z)
    groups, start = [], 0
    for k in range(1, len(order) + 1):
        if k == len(order) or m_z[order[k]] - m_z[order[k - 1]] > gap_mm:
            groups.append(order[start:k])
            start = k
    if len(groups) <= max_levels:
        return [(float(np.average(m_z[g], weights=w[g] + 1e-12)), g) for g in groups]
    groups.sort(key=lambda g: -float(w[g].sum()))
    heights = np.array([float(np.average(m_z[g], weights=w[g] + 1e-12)) for g in groups[:max_levels]])
    near = np.argmin(np.abs(m_z[:, None] - heights[None, :]), axis=1)
    close = np.abs(m_z - heights[near]) <= gap_mm
    return [(float(h), np.nonzero(close & (near == i))[0]) for i, h in enumerate(heights)]


def _plane_edges(rays, C, z: float, extent_xy, b: float):
    """Image edge pixels cast onto the horizontal plane z (table frame) on a grid of b mm: grid size
    (nx, ny), cell indices (ix, iy), edge direction on the plane (rad, mod pi), inside-grid mask."""
    _, r0, r1 = rays
    x0, x1, y0, y1 = extent_xy
    nx = int(np.ceil((x1 - x0) / b)) + 1
    ny = int(np.ceil((y1 - y0) / b)) + 1
    lam0 = (z - C[2]) / r0[:, 2]
    lam1 = (z - C[2]) / r1[:, 2]
    ok = (lam0 > 0) & (lam1 > 0)
    p0 = C[:2] + lam0[ok, None] * r0[ok, :2]
    p1 = C[:2] + lam1[ok, None] * r1[ok, :2]
    dd = p1 - p0
    e_phi = np.mod(np.arctan2(dd[:, 1], dd[:, 0]), np.pi)
    ix = np.floor((p0[:, 0] - x0) / b + 0.5).astype(np.int64)
    iy = np.floor((p0[:, 1] - y0) / b + 0.5).astype(np.int64)
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    return nx, ny, ix, iy, e_phi, inside


def _support_maps(rays, C, z: float, extent_xy, b: float, n_channels: int, tau_bins: float):
    """Edge support on the plane z: (n_channels, ny, nx) in [0, 1], 1 on an edge of that direction."""
    nx, ny, ix, iy, e_phi, inside = _plane_edges(rays, C, z, extent_xy, b)
    ch_w = np.pi / n_channels
    sup = np.zeros((n_channels, ny, nx), np.float32)
    for k in range(n_channels):
        dphi = np.abs(np.mod(e_phi - (k + 0.5) * ch_w + np.pi / 2, np.pi) - np.pi / 2)
        m = inside & (dphi <= ch_w)          # channel k holds edges within one channel width
        img = np.full((ny, nx), 255, np.uint8)
        img[iy[m], ix[m]] = 0
        dt = cv2.distanceTransform(img, cv2.DIST_L2, 3)
        sup[k] = np.clip(1.0 - dt / tau_bins, 0.0, 1.0)
    return sup


# The least-squares sigma (cluster-robust over model edges, contact prior) still misses what is
# shared between edges (blur, shading, the table pose). Fitted on the independent devset's first half
# only (setup_000-019, 13 located scenes, 78 error components of x, y, z, rx, ry, rz): the 68th
# percentile of |error| / sigma was 1.38 at the former scale 1.3 (fitted on our own generator), so
# 1.3 x 1.38 = 1.8. Applied to the image's share of the covariance only (the contact prior is
# physical), the first half then has 67 % of the components within 1 sigma and 99 % within 3; the
# second half (setup_020-039) checks it. Command:
# .venv/bin/python benchmarks/devset_pose.py --methods engine --scenes setup_000,...,setup_019
SIGMA_SCALE = 1.8

# Contact prior of the final fit (see locate_object): the lowest point of a part on a known surface
# is on it within CONTACT_SIGMA_MM (a burr, the surface's own pose) and the part tilts within
# CONTACT_SIGMA_DEG (a chip under one edge, a strap pressing one side: the devset's first half has
# tilts up to 0.5 deg, its parts always touching with their lowest point; 0.15 mm against 0.5 mm on
# its six located table scenes: position error mean 0.34 vs 0.48 mm, largest 0.86 vs 1.69 mm, median
# 0.26 vs 0.24 mm, every axis still within 2 sigma); above a riser of unknown height the height is
# nearly free.
CONTACT_SIGMA_MM = 0.15
CONTACT_SIGMA_DEG = 0.3
RISER_SIGMA_MM = 15.0
# A freely fitted height within this of a known surface is taken as resting on it.
SNAP_MM = 3.0
# A 6-DoF fit further than this many prior sigmas from its resting contact is not believed.
MAX_PRIOR_SIGMAS = 4.0


def _plane_search(model: PreparedModel, state: int, height_mm: float, rays, C, extent_xy,
                  n_peaks: int, *, px_mm: float, image_score, max_template: int = 400, n_coarse: int = 40,
                  cache: dict | None = None, image_score_wide=None, image_score_mid=None) -> list[_Hyp]:
    """Exhaustive oriented chamfer matching of the model's horizontal edges on the table planes.

    The image's edge pixels are cast onto each horizontal plane that carries model edges (height
    levels of the resting state); on such a plane the model's edges form a rigid template, so the
    score of (x, y, theta) is a correlation of the template with the plane's edge support (truncated
    distance transform, one map per edge direction). Coarse: every (x, y, theta) on a grid of about
    diameter/18 (correlations summed in the frequency domain, one inverse FFT per theta); fine: the
    best ``n_coarse`` cells re-scored twice on half-step grids in the image itself (``image_score``:
    exact perspective, full-resolution edges and their directions). ``px_mm`` is the plane footprint
    of one image pixel. Returns the best distinct (x, y, theta) as starts.
    """
    cache = {} if cache is None else cache
    rs = model.resting_states[state]
    P = transform_points(rs.T_rest_obj, model.samples_obj)
    D = model.sample_dir_obj @ rs.T_rest_obj[:3, :3].T
    N = model.mesh.face_normals @ rs.T_rest_obj[:3, :3].T
    horizontal = np.abs(D[:, 2]) < 0.3
    cand = np.nonzero(horizontal)[0]
    if len(cand) == 0:
        return []
    # edges of curved surfaces show only as silhouettes, and where depends on the view: in the coarse
    # template (one plane per height band) a vise's screw and round handles would bury its outline
    crease = model.edge_feature[model.sample_edge[cand]]
    coarse_from = crease if crease.sum() >= 50 else np.ones(len(cand), bool)
    # edges of upward faces show from any side and count fully; others (bottom outline, edges
    # between side faces) half: which of those show depends on the unknown rotation
    ef = model.edge_faces[model.sample_edge[cand]]
    up = (N[ef[:, 0], 2] > 0.3) | ((ef[:, 1] >= 0) & (N[np.maximum(ef[:, 1], 0), 2] > 0.3))
    wts_all = np.where(up, 1.0, 0.5)
    diam = model.diameter_mm
    x0, x1, y0, y1 = extent_xy
    round_part = (model.continuous_axis_obj is not None and
                  abs((rs.T_rest_obj[:3, :3] @ model.continuous_axis_obj)[2]) > 0.999)

    def face_normals(sel):
        """Normals (resting frame) of the faces either side of the samples' edges; a boundary edge
        repeats its one face."""
        ef_s = model.edge_faces[model.sample_edge[sel]]
        return N[ef_s[:, 0]], N[np.where(ef_s[:, 1] >= 0, ef_s[:, 1], ef_s[:, 0])]

    def template(spacing_mm, max_n, only=None):
        step = max(1, int(round(spacing_mm / model.sample_step_mm)))
        keep = np.ones(len(cand), bool) if only is None else only
        sel = cand[keep][::step]
        w = wts_all[keep][::step]
        if len(sel) > max_n:
            k = np.linspace(0, len(sel) - 1, max_n).astype(np.int64)
            sel, w = sel[k], w[k]
        return P[sel, :2], np.arctan2(D[sel, 1], D[sel, 0]), P[sel, 2] + height_mm, w, sel

    # ---- coarse: correlation per theta
    b = float(np.clip(diam / 18.0, 1.5, 16.0))
    b = max(b, max(x1 - x0, y1 - y0) / 250.0)
    nx = int(np.ceil((x1 - x0) / b)) + 1
    ny = int(np.ceil((y1 - y0) / b)) + 1
    dth = min(np.radians(9.0), 1.5 * b / max(0.5 * diam, 1e-6))
    nt = 1 if round_part else int(np.ceil(2 * np.pi / dth))
    dth = 2 * np.pi / nt
    nch = 4
    ch_w = np.pi / nch
    m_xy, m_phi, m_z, wts, _ = template(b / 2, max_template, only=coarse_from)
    levels = _levels(m_z, wts, max_levels=6, gap_mm=0.5 * b)
    support = [_support_maps(rays, C, z_l, extent_xy, b, nch, 1.5) for z_l, _ in levels]
    # support relative to its surroundings (about half the part's size): textured or busy areas,
    # where every direction has edges everywhere, no longer outscore the part's own outline
    hp = int(np.clip(2 * round(0.25 * diam / b) + 1, 3, 15))
    support = [sp - ndimage.uniform_filter(sp, size=(1, hp, hp), mode="nearest") for sp in support]
    Rk = int(np.ceil(np.max(np.linalg.norm(m_xy, axis=1)) / b)) + 2
    ks = 2 * Rk + 1
    # correlation of every (level, channel) support map with the rotated template, summed in the
    # frequency domain (one inverse FFT per theta)
    nlc = len(levels) * nch
    Py = cv2.getOptimalDFTSize(ny + Rk + 1)
    Px = cv2.getOptimalDFTSize(nx + Rk + 1)
    FS = sfft.rfft2(np.concatenate(support, axis=0).astype(np.float32), s=(Py, Px), workers=-1)
    lvl_of = np.full(len(m_xy), -1, np.int64)        # -1: on none of the planes, left out
    for li, (_, lv) in enumerate(levels):
        lvl_of[lv] = li
    on_plane = lvl_of >= 0
    m_xy, m_phi, wts, lvl_of = m_xy[on_plane], m_phi[on_plane], wts[on_plane], lvl_of[on_plane]
    score = np.zeros((nt, ny, nx), np.float32)
    for it in range(nt):
        th = it * dth
        c, s = np.cos(th), np.sin(th)
        kx = np.rint((c * m_xy[:, 0] - s * m_xy[:, 1]) / b + Rk).astype(np.int64)
        ky = np.rint((s * m_xy[:, 0] + c * m_xy[:, 1]) / b + Rk).astype(np.int64)
        chn = np.clip((np.mod(m_phi + th, np.pi) / ch_w).astype(np.int64), 0, nch - 1)
        ker = np.zeros((nlc, ks, ks), np.float32)
        np.add.at(ker, (lvl_of * nch + chn, ky, kx), wts.astype(np.float32))
        used = np.nonzero(ker.reshape(nlc, -1).any(axis=1))[0]
        FK = sfft.rfft2(ker[used], s=(Py, Px), workers=-1)
        corr = sfft.irfft2(np.einsum("kij,kij->ij", FS[used], np.conj(FK)), s=(Py, Px), workers=-1)
        score[it] = np.roll(corr, (Rk, Rk), axis=(0, 1))[:ny, :nx]
    flat = score.ravel()
    k = min(len(flat), 20 * n_coarse)
    top = np.argpartition(-flat, k - 1)[:k]
    top = top[np.argsort(-flat[top])]
    it_, rem = np.divmod(top, ny * nx)
    iy_, ix_ = np.divmod(rem, nx)
    cx, cy, cth = x0 + ix_ * b, y0 + iy_ * b, it_ * dth
    keep = _nms(cx, cy, cth, 1.5 * b, 1.5 * dth, n_coarse)
    cx, cy, cth = cx[keep], cy[keep], cth[keep]
    # long straight image edges (slots, shadows, texture) give ridges of high correlation at the
    # turns that align the template's edges with them and crowd the part's own peak out of the
    # global ranking: also take the best local maxima of every turn and let the image decide
    # (wide soft chamfer score with exact perspective), keeping the best n_coarse of both
    if image_score_wide is not None and nt > 1:
        k_t = 4
        loc = (score == ndimage.maximum_filter(score, size=(1, 3, 3), mode="nearest")) & (score > 0)
        flat_t = np.where(loc, score, -np.inf).reshape(nt, -1)
        top_t = np.argpartition(-flat_t, k_t - 1, axis=1)[:, :k_t]
        it2 = np.repeat(np.arange(nt), k_t)
        cell = top_t.ravel()
        good = np.isfinite(flat_t[it2, cell])
        iy2, ix2 = np.divmod(cell[good], nx)
        ax = np.concatenate([cx, x0 + ix2 * b])
        ay = np.concatenate([cy, y0 + iy2 * b])
        at = np.concatenate([cth, it2[good] * dth])
        _, _, _, w_w, w_sel = template(max(3.0 * px_mm, diam / 60.0), 80)
        wide = image_score_wide(ax, ay, at, P[w_sel] + np.array([0.0, 0.0, height_mm]), D[w_sel], w_w,
                                normals=face_normals(w_sel))
        order = np.argsort(-wide)
        keep = _nms(ax[order], ay[order], at[order], 1.5 * b, 1.5 * dth, n_coarse)
        cx, cy, cth = ax[order][keep], ay[order][keep], at[order][keep]

    # ---- fine: re-score the coarse cells' neighbourhoods in the image (exact perspective)
    _, _, _, f_w, f_sel = template(max(2.0 * px_mm, diam / 100.0), 120)
    f_P = P[f_sel] + np.array([0.0, 0.0, height_mm])
    f_D = D[f_sel]
    f_N = face_normals(f_sel)
    hx, hy, ht = cx, cy, cth
    # each step's scorer reaches about as far as the step is coarse (a 2 px scorer cannot see a part
    # half a coarse cell away); every coarse cell keeps its best refinement, so a big part whose
    # neighbourhood is full of good-looking cells does not crowd the other cells out
    for (step_xy, step_th), image_score in zip(((b / 2, dth / 2), (b / 4, dth / 4)),
                                               (image_score_wide or image_score, image_score_mid or image_score)):
        g = np.array([-step_xy, 0.0, step_xy])
        gt = np.array([0.0]) if round_part else np.array([-step_th, 0.0, step_th])
        DX, DY, DT = np.meshgrid(g, g, gt, indexing="ij")
        nb = DX.size
        hx = (hx[:, None] + DX.ravel()[None, :]).ravel()
        hy = (hy[:, None] + DY.ravel()[None, :]).ravel()
        ht = (ht[:, None] + DT.ravel()[None, :]).ravel()
        fscore = image_score(hx, hy, ht, f_P, f_D, f_w, normals=f_N)
        best_of_cell = np.arange(len(hx) // nb) * nb + np.argmax(fscore.reshape(-1, nb), axis=1)
        order = best_of_cell[np.argsort(-fscore[best_of_cell])]
        hx, hy, ht, fscore = hx[order], hy[order], ht[order], fscore[order]
    keep = _nms(hx, hy, ht, max(0.2 * diam, 2.5 * b), np.radians(15.0), n_peaks)
    out: list[_Hyp] = []
    for i in keep:
        c1, s1 = np.cos(ht[i]), np.sin(ht[i])
        T = make_pose(np.array([[c1, -s1, 0], [s1, c1, 0], [0, 0, 1.0]]), [hx[i], hy[i], height_mm]) @ rs.T_rest_obj
        out.append(_Hyp(state=state, T_table_obj=T, votes=float(fscore[i]), height_mm=height_mm))
    return out


def _image_scorer(eimg: EdgeImage, K, dist, T_cam_table, tau_px: float = 2.0, max_angle_deg: float = 20.0):
    """Score function for many planar poses at once: each pose (x, y, theta) moves template points
    ``P`` (M, 3, resting frame) with directions ``D``; the score is the weighted share of projected
    points within ``tau_px`` of an image edge of compatible direction (soft: 1 - d / tau)."""
    R = T_cam_table[:3, :3]
    t = T_cam_table[:3, 3]
    cos_tol = np.cos(np.radians(max_angle_deg))

    C = -R.T @ t                                  # camera centre, table frame

    def score(hx, hy, ht, P, D, w, normals=None):
        c, s = np.cos(ht)[:, None], np.sin(ht)[:, None]
        X = np.stack([hx[:, None] + c * P[None, :, 0] - s * P[None, :, 1],
                      hy[:, None] + s * P[None, :, 0] + c * P[None, :, 1],
                      np.broadcast_to(P[None, :, 2], (len(hx), len(P)))], axis=-1).reshape(-1, 3)
        vis = None
        if normals is not None:
            # an edge shows only if one of its faces turns towards the camera (back edges of the
            # part never do; counting them drowns the true pose among clutter that fits by chance)
            V = (C[None, :] - X).reshape(len(hx), len(P), 3)
            vis = np.zeros((len(hx), len(P)), bool)
            for Nk in normals:
                nx = c * Nk[None, :, 0] - s * Nk[None, :, 1]
                ny = s * Nk[None, :, 0] + c * Nk[None, :, 1]
                vis |= (nx * V[..., 0] + ny * V[..., 1] + Nk[None, :, 2] * V[..., 2]) > 0
        Dt = np.stack([c * D[None, :, 0] - s * D[None, :, 1], s * D[None, :, 0] + c * D[None, :, 1],
                       np.broadcast_to(D[None, :, 2], (len(hx), len(P)))], axis=-1).reshape(-1, 3)
        Xc = X @ R.T + t
        uv = project_points_px(Xc, K, dist)
        uv2 = project_points_px(Xc + 0.5 * (Dt @ R.T), K, dist)
        tv = uv2 - uv
        ok = np.isfinite(uv).all(1) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & \
            (uv[:, 0] <= eimg.width - 1) & (uv[:, 1] <= eimg.height - 1)
        iu = np.clip(np.nan_to_num(uv[:, 0]).astype(np.int64), 0, eimg.width - 1)
        iv = np.clip(np.nan_to_num(uv[:, 1]).astype(np.int64), 0, eimg.height - 1)
        d = eimg.dist_px[iv, iu]
        a = eimg.edge_angle[eimg.nearest[iv, iu]] if len(eimg.edge_angle) else np.zeros(len(iv))
        tn = np.linalg.norm(tv, axis=1) + 1e-12
        # the image gradient is perpendicular to the edge: |sin(angle between gradient and edge)|
        compat = np.abs(np.cos(a) * tv[:, 1] - np.sin(a) * tv[:, 0]) / tn >= cos_tol
        val = (np.clip(1.0 - d / tau_px, 0.0, 1.0) * compat * ok).reshape(len(hx), len(P))
        if vis is None:
            return val @ w / max(float(w.sum()), 1e-9)
        # share of the visible weight, but never of less than half the template (a pose that hides
        # most of the part would otherwise score on its few edges left)
        return (val * vis) @ w / np.maximum(vis @ w, 0.5 * float(w.sum()) + 1e-9)

    return score


def _nms(x, y, th, r_xy, r_th, n_max) -> list[int]:
    """Greedy non-maximum suppression of (x, y, theta) sorted best first; indices kept."""
    alive = np.ones(len(x), bool)
    keep = []
    for i in range(len(x)):
        if not alive[i]:
            continue
        keep.append(i)
        if len(keep) >= n_max:
            break
        dang = np.abs(np.mod(th - th[i] + np.pi, 2 * np.pi) - np.pi)
        alive &= ~((np.hypot(x - x[i], y - y[i]) < r_xy) & (dang < r_th))
    return keep


# --------------------------------------------------------------------------------------------------
# stage 2: planar oriented-chamfer fit
# --------------------------------------------------------------------------------------------------


def _sample_subset(model: PreparedModel, px_per_mm: float, spacing_px: float, max_n: int) -> np.ndarray:
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


def _planar_fit(eimg, model, hyp: _Hyp, T_cam_table, K, dist, subset, radii=(14.0, 8.0, 4.0, 2.5)):
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
            for k, h in enumerate((0.5, 0.5, 0.002)):
                q = np.zeros(3)
                q[k] = h
                uvk = project_points_px(transform_points(T_cam_table @ _perturb3(T, c_table, q), X), K, dist)
                J[:, k] = np.einsum("ij,ij->i", n, (uvk - base) / h)
            w = np.minimum(1.0, (0.5 * r) / np.maximum(np.abs(e), 1e-9))   # Huber weights
            A = J.T @ (J * w[:, None]) + np.diag([1e-6, 1e-6, 1e-2])
            dq = -np.linalg.solve(A, J.T @ (w * e))
            dq[:2] = np.clip(dq[:2], -r * 3, r * 3)
            T = _perturb3(T, c_table, dq)
    T_cam_obj = T_cam_table @ T
    es = visible_edge_samples(model, T_cam_obj, K, dist, W, H, occlusion_test=False, subset=subset)
    ok, _, _ = _chamfer_support(eimg, es.uv_px, es.normal_uv, 2.0)
    hyp.T_table_obj = T
    hyp.score = float(ok.mean()) if len(ok) else 0.0
    return hyp


# --------------------------------------------------------------------------------------------------
# stage 3: subpixel edges and 6-DoF least squares
# --------------------------------------------------------------------------------------------------


def _edges_along_normals(lin: np.ndarray, uv: np.ndarray, normal: np.ndarray, search_px: float,
                         plateau_px: float = 2.5, step_px: float = 0.25):
    """Find the image edge near each point along its normal; position at the 50 % crossing.

    For each sample a profile of the gamma-decoded image is read along the normal (bilinear, every
    ``step_px``); the edge is the gradient peak within ``search_px`` that is strongest after a
    Gaussian preference for small offsets; its position is where the profile crosses the mean of the
    two plateaus ``plateau_px`` before and after the peak (linear interpolation).

    Returns offset (N,) px along the normal, contrast (N,) (plateau difference, linear units).
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
    return off, np.abs(hi - lo)


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


FREE_6DOF = (0, 1, 2, 3, 4, 5)
FREE_REST = (0, 1, 2, 5)      # x, y, z, rotation about the table normal: part lying flat


def _refine(eimg: EdgeImage, model: PreparedModel, T_table_obj: np.ndarray, T_cam_table, K, dist,
            occluders_cam, subset, *, free=FREE_6DOF, radii=(5.0, 3.0, 2.0, 2.0), min_contrast: float,
            round_axis_table: np.ndarray | None = None, f_scale_px: float = 0.5,
            prior: tuple[np.ndarray, float, float, np.ndarray] | None = None):
    """Iterated least-squares fit of the free pose parameters to subpixel image edges.

    Parameters p = (dx, dy, dz mm, rotation vector rad) move the part about its centre of mass in
    the table frame; ``free`` selects which are fitted (``FREE_REST`` keeps the part flat). Each
    round re-computes the visible edges (z-buffer with the occluders) and looks for the image edge
    along each edge normal within the round's radius. Returns (T_table_obj, info).

    ``prior = (T_rest, sigma_z_mm, sigma_tilt_rad, hull_obj)``: the part rests on a surface, so its height and
    tilt are known beforehand to within the contact's sigmas (a chip under an edge, an unknown riser)
    about ``T_rest``: they enter as Gaussian prior residuals (in units of :data:`PRIOR_PX` pixels of
    edge noise) and as prior information in :func:`_covariance` (a maximum a-posteriori fit).
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
        off, contrast = _edges_along_normals(eimg.linear, es.uv_px, es.normal_uv, r)
        seen = np.isfinite(off) & (contrast >= min_contrast)
        good = seen & _clear_of_other_edges(model, es, r + 3.0)
        if good.sum() < 10:
            # a small part (a few dozen pixels) has every sample near another edge: look closer in
            good = seen & _clear_of_other_edges(model, es, min(r, 2.0) + 1.0)
        if good.sum() < 10:
            return T, {"n_visible": len(es.index), "failed": "too few image edges along the model's edges"}
        X = es.points_obj[good]
        n = es.normal_uv[good]
        target = es.uv_px[good] + off[good, None] * n
        c_table = transform_points(T, model.center_obj[None])[0]
        T0 = T
        # the samples along one model edge share its errors: the data carry about as much information
        # as that many edges, not samples; the prior is weighed against them accordingly
        n_cl = len(np.unique(model.sample_edge[es.index[good]]))
        w_prior = PRIOR_PX * np.sqrt(max(good.sum() / max(n_cl, 1), 1.0))
        pin = None
        if round_axis_table is not None and len(free) == 6:
            pin = round_axis_table

        def full(q, free=free):
            p = np.zeros(6)
            p[free] = q
            return p

        def fun(q, X=X, n=n, target=target, T0=T0, c_table=c_table, pin=pin, w_prior=w_prior):
            p = full(q)
            T1 = _perturb(T0, c_table, p)
            uv = project_points_px(transform_points(T_cam_table @ T1, X), K, dist)
            res = np.einsum("ij,ij->i", n, uv - target)
            if pin is not None:   # round part: pin the unobservable spin
                res = np.append(res, 1e4 * float(p[3:6] @ pin))
            if prior is not None:
                res = np.append(res, w_prior * _prior_offsets(T1, prior))
            return res

        xs = np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3])[free]
        sol = least_squares(fun, np.zeros(len(free)), loss="soft_l1", f_scale=f_scale_px, method="trf",
                            x_scale=xs, max_nfev=60)
        T = _perturb(T0, c_table, full(sol.x))
        info = {"sol": sol, "X": X, "n": n, "target": target, "T0": T0, "c_table": c_table,
                "n_visible": len(es.index), "n_used": int(good.sum()), "free": free, "pin": pin, "prior": prior,
                "edge": model.sample_edge[es.index[good]]}
    return T, info


def _verify(eimg, model, T_table_obj, T_cam_table, K, dist, occluders_cam, subset, *, min_contrast,
            support_px: float = 1.5, search_px: float = 3.0):
    """Share of the visible model samples with an image edge within ``support_px`` (subpixel)."""
    W, H = eimg.width, eimg.height
    es = visible_edge_samples(model, T_cam_table @ T_table_obj, K, dist, W, H, occluders=occluders_cam,
                              occlusion_test=True, subset=subset)
    if len(es.index) == 0:
        return 0.0, es, np.zeros(0, bool)
    off, contrast = _edges_along_normals(eimg.linear, es.uv_px, es.normal_uv, search_px)
    sup = np.isfinite(off) & (np.abs(np.nan_to_num(off, nan=99.0)) <= support_px) & (contrast >= min_contrast)
    return float(sup.mean()), es, sup


# Edge noise (px) in whose units the contact prior's residuals are expressed: one prior residual
# weighs as much as one edge sample of that noise (the sigma calibration absorbs the rest).
PRIOR_PX = 0.5


def _prior_offsets(T: np.ndarray, prior) -> np.ndarray:
    """(dz / sigma_z, tilt_x / sigma_t, tilt_y / sigma_t) of ``T`` against the prior's resting pose.

    ``dz`` is the height of the part's lowest point (over ``hull_obj``, its convex hull's vertices,
    obj frame) above the lowest point at rest: a part tilted by a chip under one edge still touches
    its support with the other, so its lowest point stays on the surface while its centre rises."""
    T_rest, sz, st, hull_obj = prior
    dz = float(transform_points(T, hull_obj)[:, 2].min() - transform_points(T_rest, hull_obj)[:, 2].min())
    rv = Rotation.from_matrix(T[:3, :3] @ T_rest[:3, :3].T).as_rotvec()
    return np.array([dz / sz, rv[0] / st, rv[1] / st])


def _hull_points(model: PreparedModel, max_n: int = 400) -> np.ndarray:
    """Vertices of the model's convex hull (obj frame, mm), at most ``max_n``: where it can touch."""
    try:
        v = np.asarray(model.mesh.convex_hull.vertices, dtype=np.float64)
    except Exception:  # noqa: BLE001 - a degenerate (flat) mesh has no hull; its vertices will do
        v = np.asarray(model.mesh.vertices, dtype=np.float64)
    if len(v) > max_n:
        v = v[np.linspace(0, len(v) - 1, max_n).astype(np.int64)]
    return v


def _covariance(info: dict, K, dist, T_cam_table, data_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, float]:
    """6x6 covariance of p = (t mm at the part's centre, rotation vector rad) from the last solve
    over the robust inliers (zero rows/columns for parameters held fixed): the classical
    ``(J^T J)^-1 s^2`` plus the cluster-robust term for errors shared along each model edge."""
    sol, free, pin = info["sol"], info["free"], info["pin"]
    X, n, target, T0, c_table = info["X"], info["n"], info["target"], info["T0"], info["c_table"]
    p = np.zeros(6)
    p[free] = sol.x

    def raw(pp):
        uv = project_points_px(transform_points(T_cam_table @ _perturb(T0, c_table, pp), X), K, dist)
        return np.einsum("ij,ij->i", n, uv - target)

    r = raw(p)
    scale = 1.4826 * float(np.median(np.abs(r))) + 1e-9
    inl = np.abs(r) < max(3.0 * scale, 0.3)
    J = np.zeros((len(r), 6))
    for k in free:
        h = 1e-3 if k < 3 else 1e-6
        dp = np.zeros(6)
        dp[k] = h
        J[:, k] = (raw(p + dp) - raw(p - dp)) / (2 * h)
    Ji, ri = J[inl][:, free], r[inl]
    m = len(ri)
    s2 = float(ri @ ri) / max(m - len(free), 1)
    A = Ji.T @ Ji
    if pin is not None:
        a = np.concatenate([np.zeros(3), pin])[free]
        A = A + 1e8 * np.outer(a, a)
    Ainv = np.linalg.pinv(A)
    cov_iid = Ainv * s2
    # samples along one model edge share its errors (blur, shading, tessellation): cluster-robust
    # "sandwich" covariance with the edges as clusters (Liang & Zeger 1986, Biometrika 73(1), eq. 2.4)
    edges = info["edge"][inl]
    G = np.zeros((len(free), len(free)))
    for e in np.unique(edges):
        g = Ji[edges == e].T @ ri[edges == e]
        G += np.outer(g, g)
    n_cl = len(np.unique(edges))
    G *= n_cl / max(n_cl - len(free), 1)          # small-sample correction
    cov_cl = Ainv @ G @ Ainv
    cov_f = (cov_cl + cov_iid) * data_scale ** 2   # the image's share, calibrated; the prior is physical
    prior = info.get("prior")
    if prior is not None:         # prior information on height and tilt (MAP): add it, invert back
        Jp = np.zeros((3, 6))
        for k in free:
            h = 1e-3 if k < 3 else 1e-6
            dp = np.zeros(6)
            dp[k] = h
            Jp[:, k] = (_prior_offsets(_perturb(T0, c_table, p + dp), prior)
                        - _prior_offsets(_perturb(T0, c_table, p - dp), prior)) / (2 * h)
        P = (Jp.T @ Jp)[np.ix_(free, free)]
        cov_f = np.linalg.pinv(np.linalg.pinv(cov_f) + P)
    cov = np.zeros((6, 6))
    cov[np.ix_(free, free)] = cov_f
    return cov, inl, float(np.sqrt(np.mean(ri ** 2))) if m else float("nan")


# --------------------------------------------------------------------------------------------------
# main entry
# --------------------------------------------------------------------------------------------------


def _pose_distance(T1, T2, c_obj):
    p1 = transform_points(T1, c_obj[None])[0]
    p2 = transform_points(T2, c_obj[None])[0]
    R = T1[:3, :3].T @ T2[:3, :3]
    ang = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(p1 - p2)), float(ang)


def _same_up_to_symmetry(model: PreparedModel, T1, T2, pos_tol, ang_tol, exact_only: bool = False) -> bool:
    """T1 ~ T2 @ S for a symmetry S (``exact_only``: exact symmetries and near ones that turn about
    the table normal; near-symmetric flips onto another face then count as different poses)."""
    Ss = [np.eye(4)] + [s.S for s in model.symmetries
                        if s.exact or not exact_only or abs(float((T2[:3, :3] @ s.axis_obj)[2])) > 0.99]
    for S in Ss:
        d, a = _pose_distance(T1, T2 @ S, model.center_obj)
        if d < pos_tol and (a < ang_tol or model.continuous_axis_obj is not None and
                            abs(float((T1[:3, :3] @ model.continuous_axis_obj) @ (T2[:3, :3] @ model.continuous_axis_obj))) > np.cos(np.radians(ang_tol))):
            return True
    return False


def _intersect(a, b):
    """Overlap of two table-plane extents (x0, x1, y0, y1), or None where they do not overlap."""
    e = (max(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), min(a[3], b[3]))
    return e if e[1] > e[0] and e[3] > e[2] else None


def _search(eimg: EdgeImage, K, dist, T_cam_table, model: PreparedModel, *, height_offsets_mm=(0.0,),
            resting_states=None, min_state_probability: float = 0.1, n_starts: int = 6, n_planar: int = 10, max_edges: int = 60000, rng=None,
            timings: dict | None = None, table_extent_xy=None):
    """Stages 1 and 2: starts from the plane search, aligned in the table plane, best first.
    ``table_extent_xy`` (x0, x1, y0, y1 mm): where the part's centre can be (the table and a margin);
    the floor and the machine's walls in the background are not searched.
    Returns (hypotheses, px_per_mm) or the reason (str) why there are none."""
    timings = {} if timings is None else timings
    memo = ("search", id(model), T_cam_table.tobytes(), tuple(height_offsets_mm),
            None if resting_states is None else tuple(resting_states), min_state_probability, n_starts, n_planar,
            None if table_extent_xy is None else tuple(table_extent_xy))
    if memo in eimg.cache:              # same image, model and table pose: reuse (recognition)
        timings.setdefault("search", 0.0)
        timings.setdefault("planar_fit", 0.0)
        return eimg.cache[memo]
    rng = np.random.default_rng(0) if rng is None else rng
    t = time.perf_counter()
    T_table_cam = inv(T_cam_table)
    C = T_table_cam[:3, 3]
    key = ("rays", max_edges, T_cam_table.tobytes())
    if key not in eimg.cache:
        eimg.cache[key] = _edge_rays_table(eimg, K, dist, T_table_cam, max_edges, rng)
    rays = eimg.cache[key]
    if rays is None:
        return "the image has no edges"
    _, r0, r1 = rays
    lam = -C[2] / r0[:, 2]
    lam1 = -C[2] / r1[:, 2]
    okp = (lam > 0) & (lam1 > 0)
    pts = C[:2] + lam[okp, None] * r0[okp, :2]
    if len(pts) < 20:
        return "no image edges fall on the table plane"
    px_mm = 0.5 * float(np.median(np.linalg.norm((C[:2] + lam1[okp, None] * r1[okp, :2]) - pts, axis=1)))
    lo_xy = np.maximum(np.percentile(pts, 1, axis=0), C[:2] - 3000.0) - 150.0
    hi_xy = np.minimum(np.percentile(pts, 99, axis=0), C[:2] + 3000.0) + 150.0
    extent = (float(lo_xy[0]), float(hi_xy[0]), float(lo_xy[1]), float(hi_xy[1]))
    extent = _intersect(extent, extent if table_extent_xy is None else table_extent_xy)   # None if empty
    if extent is None:
        return "the image's edges meet the table plane only more than 3 m from the camera"
    if resting_states is None:
        states = [i for i, s in enumerate(model.resting_states)
                  if s.same_as < 0 and (i == 0 or s.probability >= min_state_probability or s.cad_axis)]
    else:
        states = list(resting_states)
    hyps: list[_Hyp] = []
    scorer = _image_scorer(eimg, K, dist, T_cam_table)
    b_px = float(np.clip(model.diameter_mm / 18.0, 1.5, 16.0)) / max(px_mm, 1e-9)
    scorer_wide = _image_scorer(eimg, K, dist, T_cam_table, tau_px=float(np.clip(1.2 * b_px, 3.0, 20.0)))
    scorer_mid = _image_scorer(eimg, K, dist, T_cam_table, tau_px=float(np.clip(0.6 * b_px, 2.5, 10.0)))
    planes = []
    for h in height_offsets_mm:            # a height, or (height, table-plane extent to search there)
        h, ext = (h if isinstance(h, tuple) else (h, None))
        ext = extent if ext is None else _intersect(ext, extent)
        if ext is not None:
            planes.append((float(h), ext))
    for st in states:
        for h, ext in planes:
            hyps += _plane_search(model, st, h, rays, C, ext, n_starts, px_mm=px_mm,
                                  image_score=scorer, cache=eimg.cache, image_score_wide=scorer_wide,
                                  image_score_mid=scorer_mid)
    timings["search"] = (time.perf_counter() - t) * 1e3
    if not hyps:
        return "the search produced no pose on the table"
    t = time.perf_counter()
    hyps.sort(key=lambda h: -h.votes)
    # votes are not comparable between resting states (a part on its side shows other edges):
    # keep the best few of every state besides the best overall
    # nor between heights (a riser plane full of the table's edges outvotes the part's own): the
    # best two of every (state, height) as well
    groups: dict = {}
    for h in hyps:
        groups.setdefault((h.state, round(h.height_mm, 1)), []).append(h)
    extra = [h for st in states for h in [g for g in hyps if g.state == st][:3]]
    extra += [h for g in groups.values() for h in g[:2]]
    hyps = list({id(h): h for h in hyps[:n_planar] + extra}.values())     # in order, each once
    z_typ = float(np.median(transform_points(T_cam_table, np.array([[*h.T_table_obj[:2, 3], 0.0] for h in hyps]))[:, 2]))
    px_per_mm = K[0, 0] / max(z_typ, 1.0)
    sub_coarse = _sample_subset(model, px_per_mm, 4.0, 400)
    for h in hyps:
        _planar_fit(eimg, model, h, T_cam_table, K, dist, sub_coarse)
    hyps.sort(key=lambda h: -h.score)
    timings["planar_fit"] = (time.perf_counter() - t) * 1e3
    eimg.cache[memo] = (hyps, px_per_mm)
    return hyps, px_per_mm


def search_poses(image, K, dist, T_cam_table, model: PreparedModel, *, gamma: float = 2.2,
                 edge_image: EdgeImage | None = None, **kw) -> list[tuple[np.ndarray, float]]:
    """The coarse stages alone: candidate ``T_table_obj`` aligned in the table plane with their
    chamfer score (share of visible edges within 2 px of an image edge), best first. For
    diagnostics and as a common start for other refinement methods."""
    eimg = edge_image if edge_image is not None else prepare_image(image, gamma=gamma)
    found = _search(eimg, np.asarray(K, float), np.zeros(5) if dist is None else np.asarray(dist, float).ravel(),
                    check_pose(T_cam_table, "T_cam_table"), model, **kw)
    if isinstance(found, str):
        return []
    return [(h.T_table_obj, h.score) for h in found[0]]


def _unexplained_edges(eimg: EdgeImage, model: PreparedModel, T_cam_obj, K, dist, inset_px: float = 3.0,
                       tol_px: float = 2.0) -> float:
    """Share of the image's edge pixels inside the model's projected outline that lie farther than
    ``tol_px`` from every visible model edge (pinhole coordinates; the outline shrunk by ``inset_px``)."""
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
    return float(np.mean(d > tol_px + 0.5 * model.sample_step_mm * K[0, 0] / float(np.median(V[:, 2]))))


def _turned_over(model: PreparedModel, T_table_obj: np.ndarray) -> list[np.ndarray]:
    """The pose turned 180 deg about each horizontal axis of the part through its centre, put back
    on the plane it stood on (lowest vertex at the same height)."""
    out = []
    R = T_table_obj[:3, :3]
    z0 = float(transform_points(T_table_obj, model.mesh.vertices)[:, 2].min())
    c = transform_points(T_table_obj, model.mesh.bounds.mean(axis=0)[None])[0]     # outline's centre
    for k in range(3):
        a = R[:, k]
        if abs(a[2]) > 0.05:
            continue                      # not a horizontal axis of the part
        F = make_pose(Rotation.from_rotvec(np.pi * a / np.linalg.norm(a)).as_matrix())
        T = make_pose(t=c) @ F @ make_pose(t=-c) @ T_table_obj
        T[2, 3] += z0 - float(transform_points(T, model.mesh.vertices)[:, 2].min())
        out.append(T)
    return out


def _start_hypotheses(model: PreparedModel, start_poses, T_cam_table, K, dist, eimg: EdgeImage,
                      capture_mm: float = 30.0, capture_deg: float = 8.0, n_peaks: int = 3):
    """Starts given by someone who knows roughly where the part is ("refine from here").

    Each start is taken in the resting state whose table normal it matches best, then searched
    locally in the table plane (x, y within ``capture_mm``, rotation within ``capture_deg``, scored
    in the image as in the fine stage of the plane search) and aligned: an operator's drag or nudge
    rarely lands within the few pixels the least-squares fit converges from. The start itself stays
    a candidate, so a start that is already right cannot be talked out of it.
    Returns (hypotheses best first, px_per_mm) or the reason (str) why there are none."""
    starts = []
    for T0 in start_poses:
        T0 = check_pose(T0, "start pose T_table_obj")
        ups = [float((T0[:3, :3] @ (inv(r.T_rest_obj)[:3, :3] @ np.array([0.0, 0.0, 1.0])))[2])
               for r in model.resting_states]
        starts.append((int(np.argmax(ups)), T0))
    if not starts:
        return "no start pose given"
    z = float(transform_points(T_cam_table, starts[0][1][:3, 3][None])[0, 2])
    px_per_mm = K[0, 0] / max(z, 1.0)
    scorer = _image_scorer(eimg, K, dist, T_cam_table, tau_px=3.0)
    sub_coarse = _sample_subset(model, px_per_mm, 4.0, 400)
    hyps: list[_Hyp] = []
    for state, T0 in starts:
        rs = model.resting_states[state]
        M = T0 @ inv(rs.T_rest_obj)            # the start as a turn about the table normal + shift
        th0 = float(np.arctan2(M[1, 0], M[0, 0]))
        P = transform_points(rs.T_rest_obj, model.samples_obj) + np.array([0.0, 0.0, M[2, 3]])
        D = model.sample_dir_obj @ rs.T_rest_obj[:3, :3].T
        sel = np.linspace(0, len(P) - 1, min(len(P), 150)).astype(np.int64)
        P, D, w = P[sel], D[sel], np.ones(len(sel))
        round_part = (model.continuous_axis_obj is not None and
                      abs((rs.T_rest_obj[:3, :3] @ model.continuous_axis_obj)[2]) > 0.999)
        step = 2.5 / px_per_mm                 # within the scorer's reach of 3 px
        g = np.arange(-capture_mm, capture_mm + 1e-9, max(step, capture_mm / 25))
        dth = np.radians(min(2.0, np.degrees(2.5 / (px_per_mm * max(0.5 * model.diameter_mm, 1.0)))))
        gt = np.array([0.0]) if round_part else \
            np.arange(-np.radians(capture_deg), np.radians(capture_deg) + 1e-9, dth)
        DX, DY, DT = np.meshgrid(g, g, gt, indexing="ij")
        hx, hy, ht = M[0, 3] + DX.ravel(), M[1, 3] + DY.ravel(), th0 + DT.ravel()
        sc = np.concatenate([scorer(hx[i:i + 2000], hy[i:i + 2000], ht[i:i + 2000], P, D, w)
                             for i in range(0, len(hx), 2000)])
        order = np.argsort(-sc)
        keep = _nms(hx[order], hy[order], ht[order], max(0.2 * model.diameter_mm, 3 * step),
                    np.radians(15.0), n_peaks)
        for i in order[keep]:
            c1, s1 = np.cos(ht[i]), np.sin(ht[i])
            T = make_pose(np.array([[c1, -s1, 0], [s1, c1, 0], [0, 0, 1.0]]), [hx[i], hy[i], M[2, 3]]) @ rs.T_rest_obj
            hyps.append(_planar_fit(eimg, model, _Hyp(state=state, T_table_obj=T, votes=float(sc[i])),
                                    T_cam_table, K, dist, sub_coarse))
        hyps.append(_planar_fit(eimg, model, _Hyp(state=state, T_table_obj=T0, votes=0.0),
                                T_cam_table, K, dist, sub_coarse))
    hyps.sort(key=lambda h: -h.score)
    return hyps, px_per_mm


@one_blas_thread
def locate_object(image, K, dist, T_cam_table, model: PreparedModel, *, occluder_models=(), known_models=(),
                  known_regions=(),
                  gamma: float = 2.2, height_offsets_mm=(0.0,), free_height: bool = False, resting_states=None,
                  min_score: float = 0.5, min_margin: float = 0.1, min_distinctiveness: float = 0.1,
                  max_tilt_deg: float = 0.5, max_sigma_mm: float = 0.2, max_sigma_deg: float = 0.1,
                  n_starts: int = 6, n_planar: int = 10, n_refine: int = 3, max_edges: int = 60000,
                  edge_image: EdgeImage | None = None, sigma_scale: float = SIGMA_SCALE, seed: int = 0,
                  start_poses=None, known_heights_mm=None, contact_sigma_mm: float = CONTACT_SIGMA_MM,
                  contact_sigma_deg: float = CONTACT_SIGMA_DEG, riser_sigma_mm: float = RISER_SIGMA_MM,
                  table_extent_xy=None):
    """Locate one part on the table. Returns :class:`ObjectPose` or :class:`ObjectFailure`.

    ``start_poses``: optional ``T_table_obj`` starts (e.g. an operator's adjusted pose, "refine from
    here") that replace the search; refinement, verification and uncertainty are as usual.

    Parameters
    ----------
    image : (H, W) uint8 grey (or BGR); ignored when ``edge_image`` (from :func:`prepare_image`) is given
    K : (3, 3), dist : (5,) OpenCV intrinsics of the image
    T_cam_table : (4, 4) pose of the table in the camera frame, mm
    model : prepared part
    occluder_models : pairs ``(PreparedModel or trimesh.Trimesh, T_table_occ)`` of objects with known
        poses (vise, clamps) that may hide parts of the model's edges
    known_models : pairs ``(PreparedModel, T_table_model)`` of geometry whose edges are not the part,
        typically the table itself with the identity pose: its border, slots and steps are removed
        from the edge map before the search (see :func:`mask_known_edges`)
    known_regions : polygons (N, 3) on the table (table frame, mm) whose edges are not the part, e.g.
        the printed fiducial labels (see :func:`mask_table_regions`)
    gamma : the camera's encoding gamma (intensities are decoded as ``(I/255) ** gamma``)
    height_offsets_mm : heights above the table to search (e.g. ``(0, 10, 20)`` for unknown parallels)
    free_height : fit the height above the table too (parts on parallels); by default the part lies
        on the table (or at the searched height offset) and only x, y and the rotation are fitted
    resting_states : indices into ``model.resting_states`` to try (default: the distinct states with a
        probability of at least 0.1, always including the likeliest)
    min_score : least share of visible model edges supported by image edges to accept
    min_margin : least score difference to the best different pose
    min_distinctiveness : least drop of the score when the fitted pose is moved by 4 px along x, y or
        turned so that its edges move as much at their mean distance from the centre (in the better
        of the two directions each); fits onto a single straight
        edge or onto texture do not drop and are refused
    max_tilt_deg : residual tilt above which (and above 3 sigma) the result carries the "tilt" flag
    max_sigma_mm, max_sigma_deg : tolerances on the 1-sigma uncertainty; ``uncertainty_ok`` says
        whether they hold (flag "uncertainty" when not)
    n_starts : search peaks per resting state and height; n_planar : best of those aligned in the
        table plane; n_refine : distinct aligned starts refined and verified
    sigma_scale : factor on the image's share of the covariance (before the contact prior joins it);
        default :data:`SIGMA_SCALE`

    known_heights_mm : heights (table z) of surfaces known to carry parts (the table, located
        fixtures' faces); a start searched at another height (a riser of unknown height) has its
        height fitted (``free_height``) and only a broad prior on it. None: every searched height
        (with ``free_height``: none, the height is always fitted).
    table_extent_xy : (x0, x1, y0, y1) of the table top (mm, table frame): the part's centre is
        searched within it, grown by half the part's size; None: wherever image edges meet the plane
    contact_sigma_mm, contact_sigma_deg : how far a part resting on a known surface may sit above
        it or tilt (a chip, a burr, a strap pressing one side): the prior of the final fit;
        ``riser_sigma_mm`` the prior on the height above an unknown riser.

    The pose is fitted lying flat (x, y, rotation about the table normal; height with ``free_height``
    on unknown risers), then once more in 6 DoF with the contact prior (maximum a-posteriori): that
    is the pose returned, with its posterior sigma for all six axes. Its tilt is reported (flag
    "tilt" when it exceeds ``max_tilt_deg`` and 3 sigma; ``T_table_obj_6dof`` is the same pose).
    """
    t_all = time.perf_counter()
    timings: dict[str, float] = {}
    K = np.asarray(K, dtype=float)
    dist = np.zeros(5) if dist is None else np.asarray(dist, dtype=float).ravel()
    T_cam_table = check_pose(T_cam_table, "T_cam_table")
    T_table_cam = inv(T_cam_table)
    rng = np.random.default_rng(seed)
    t = time.perf_counter()
    eimg = edge_image if edge_image is not None else prepare_image(image, gamma=gamma)
    if known_models:
        eimg = mask_known_edges(eimg, [(m, T_cam_table @ np.asarray(T, float)) for m, T in known_models], K, dist)
    if len(known_regions):
        eimg = mask_table_regions(eimg, known_regions, T_cam_table, K, dist)
    timings["edges"] = (time.perf_counter() - t) * 1e3
    W, H = eimg.width, eimg.height
    name = model.name

    def fail(kind, reason, best=0.0, cands=()):
        timings["total"] = (time.perf_counter() - t_all) * 1e3
        return ObjectFailure(model_name=name, kind=kind, reason=reason, best_score=float(best),
                             candidates=tuple(cands), timings_ms=dict(timings))

    if len(eimg.edge_uv) < 20:
        return fail("not_found", f"{name} not found: the image has almost no edges "
                                 f"({len(eimg.edge_uv)} edge pixels); check exposure and focus")
    occluders_cam = tuple((m, T_cam_table @ np.asarray(T, float)) for m, T in occluder_models)
    C = T_table_cam[:3, 3]
    if C[2] <= 0:
        return fail("bad_input", "the camera is below the table plane according to T_cam_table "
                                 f"(camera height {C[2]:.0f} mm); check the table pose")

    # ---- stages 1 and 2: search and planar fit
    if start_poses is not None:
        found = _start_hypotheses(model, start_poses, T_cam_table, K, dist, eimg)
    else:
        found = _search(eimg, K, dist, T_cam_table, model, height_offsets_mm=height_offsets_mm,
                        resting_states=resting_states, n_starts=n_starts, n_planar=n_planar,
                        max_edges=max_edges, rng=rng, timings=timings,
                        table_extent_xy=None if table_extent_xy is None else
                        (table_extent_xy[0] - 0.5 * model.diameter_mm, table_extent_xy[1] + 0.5 * model.diameter_mm,
                         table_extent_xy[2] - 0.5 * model.diameter_mm, table_extent_xy[3] + 0.5 * model.diameter_mm))
    if isinstance(found, str):
        return fail("not_found", f"{name} not found: {found}")
    hyps, px_per_mm = found

    # ---- stage 3: refine the best distinct starts (flat on the table: x, y, z, rotation)
    t = time.perf_counter()
    pos_tol = max(2.0, 0.04 * model.diameter_mm)
    distinct: list[_Hyp] = []
    for h in hyps:
        if h.score <= 0:
            continue
        # near-symmetric alternatives (e.g. the part upside down) are refined separately and compete
        if any(_same_up_to_symmetry(model, h.T_table_obj, d.T_table_obj, pos_tol, 4.0, exact_only=True)
               for d in distinct):
            continue
        distinct.append(h)
        if len(distinct) >= n_refine:
            break
    if not distinct:
        return fail("not_found", f"{name} not found: no start matched any image edges")
    sub_fine = _sample_subset(model, px_per_mm, 2.5, 1500)
    min_contrast = max(0.01, 6.0 * eimg.noise_linear)

    hull_obj = _hull_points(model)

    def on_known_surface(T) -> bool:
        if known_heights_mm is None:      # every searched height is a known surface, unless told to fit it
            return not free_height
        z0 = float(transform_points(T, model.mesh.vertices)[:, 2].min())
        return any(abs(z0 - h) < 0.5 for h in known_heights_mm)

    def refine_rest(T0, state, radii=(5.0, 3.0, 2.0, 2.0)):
        rs_axis = inv(model.resting_states[state].T_rest_obj)[:3, :3] @ np.array([0.0, 0.0, 1.0])
        free = (0, 1, 2, 5) if free_height and not on_known_surface(T0) else (0, 1, 5)
        if model.continuous_axis_obj is not None and abs(float(rs_axis @ model.continuous_axis_obj)) > 0.999:
            free = free[:-1]          # round part standing on its face: its spin is not observable
        T, info = _refine(eimg, model, T0, T_cam_table, K, dist, occluders_cam, sub_fine, free=free,
                          radii=radii, min_contrast=min_contrast)
        if 2 in free and known_heights_mm is not None:
            # a height fitted freely that ends near a known surface, or under it (impossible), is that
            # surface: the image alone slides the part along the line of sight
            z0 = float(transform_points(T, model.mesh.vertices)[:, 2].min())
            near = [h for h in known_heights_mm if z0 - SNAP_MM < h < z0 + SNAP_MM or (h > z0 and h - z0 < 3 * SNAP_MM)]
            if near:
                h = min(near, key=lambda h: abs(h - z0))
                T = make_pose(None, [0.0, 0.0, h - z0]) @ T
                T, info = _refine(eimg, model, T, T_cam_table, K, dist, occluders_cam, sub_fine,
                                  free=tuple(f for f in free if f != 2), radii=radii[-2:], min_contrast=min_contrast)
        score, es, sup = _verify(eimg, model, T, T_cam_table, K, dist, occluders_cam, sub_fine,
                                 min_contrast=min_contrast)
        spacing = float(np.median(np.linalg.norm(np.diff(es.uv_px, axis=0), axis=1))) if len(es.index) > 2 else 0.0
        support_px = float(np.count_nonzero(sup)) * min(spacing, 10.0)
        # rank: share of the model's edges supported, weighted by how much image evidence that is
        # (a simpler hypothesis, e.g. the part upside down with its pocket hidden, explains less)
        return {"state": state, "T": T, "info": info, "score": score, "es": es, "sup": sup,
                "support_px": support_px, "key": score * np.sqrt(support_px)}

    results = []
    for h in distinct:
        r = refine_rest(h.T_table_obj, h.state)
        r["hyp"] = h
        results.append(r)
    timings["refine"] = (time.perf_counter() - t) * 1e3

    # ---- stage 4: verification, symmetry, tilt, uncertainty
    t = time.perf_counter()
    results.sort(key=lambda r: -r["key"])
    best = results[0]
    # the part turned over about one of its horizontal axes has the same outline when the outline is
    # symmetric (a plate with a pocket on top: upside down it is a plain rectangle that supports a high
    # share of its few edges); the search may offer only one of the two: refine the other as well
    # (the flip moves the part by a few mm when its outline is not centred on its mass: aligned in the
    # plane first). Explaining clearly more of the image (25 % more supported edge length) at an
    # acceptable score wins even at a lower share: the pocket's walls are rarely all supported.
    upright_only = len(model.resting_states) == 1 and model.resting_states[0].cad_axis == "+z"
    if "sol" in best["info"] and not upright_only:      # a fixture never lies upside down
        for T_alt in _turned_over(model, best["T"]):
            found_alt = _start_hypotheses(model, [T_alt], T_cam_table, K, dist, eimg,
                                          capture_mm=max(5.0, 0.06 * model.diameter_mm), capture_deg=2.0, n_peaks=1)
            if isinstance(found_alt, str):
                continue
            h = found_alt[0][0]
            alt = refine_rest(h.T_table_obj, h.state)
            if "sol" in alt["info"]:
                alt["hyp"] = h
                results.append(alt)
                if alt["score"] >= min_score and alt["support_px"] >= 1.25 * best["support_px"]:
                    best = alt
        results.sort(key=lambda r: (r is not best, -r["key"]))
    # near symmetries (outline maps, small features do not): try the turned poses, keep the best
    # (only turns about the table normal: a near-symmetric flip puts the part on another face, which
    # the search covers as its own resting state, at its own height)
    near = [s for s in model.symmetries if not s.exact
            and abs(float((best["T"][:3, :3] @ s.axis_obj)[2])) > 0.99]
    sym_scores = []
    if near and "sol" in best["info"]:
        base = best
        for s in near:
            alt = refine_rest(base["T"] @ s.S, base["state"], radii=(2.0, 2.0))
            alt["hyp"] = base["hyp"]
            sym_scores.append((s, alt["score"]))
            if alt["key"] > best["key"]:
                best = alt
    if "sol" in best["info"]:          # polish the chosen pose with a narrow search
        pol = refine_rest(best["T"], best["state"], radii=(2.0, 1.5, 1.5))
        if "sol" in pol["info"] and pol["key"] >= best["key"] * 0.98:
            pol["hyp"] = best["hyp"]
            results = [pol if r is best else r for r in results]
            best = pol
    cands = [{"T_table_obj": r["T"].tolist(), "score": round(r["score"], 4)} for r in results]
    # the part turned over onto another face by a near symmetry (same outline, e.g. a counterbore
    # underneath) is not a different place: it is a question of the datum, handled below
    flips = [r for r in results if r is not best and
             not _same_up_to_symmetry(model, r["T"], best["T"], pos_tol, 4.0, exact_only=True) and
             _same_up_to_symmetry(model, r["T"], best["T"], pos_tol, 4.0)]
    # a different pose competes only if it explains about as much of the image (a part upside down
    # with its pocket hidden is a plain outline: a high share of fewer edges is not a rival)
    others = [r for r in results if r is not best and all(r is not f for f in flips) and
              not _same_up_to_symmetry(model, r["T"], best["T"], pos_tol, 4.0, exact_only=True)]
    runner = max((r["score"] for r in others), default=float("nan"))
    margin = best["score"] - runner if others else float("nan")
    rivals = [r for r in others if r["support_px"] >= 0.8 * best["support_px"]]
    if rivals and "sol" in best["info"]:
        # nor is a pose that leaves clearly more of the image inside its outline unexplained (the
        # block upside down: same outline, its pocket's edges in the picture belong to nothing)
        u_best = _unexplained_edges(eimg, model, T_cam_table @ best["T"], K, dist)
        rivals = [r for r in rivals
                  if _unexplained_edges(eimg, model, T_cam_table @ r["T"], K, dist) < u_best + 0.1]
    rival_margin = best["score"] - max((r["score"] for r in rivals), default=float("nan"))
    if "sol" not in best["info"]:
        timings["verify"] = (time.perf_counter() - t) * 1e3
        return fail("not_found", f"{name} not found: {best['info'].get('failed', 'the fit did not converge')}",
                    best["score"], cands)
    if best["score"] < min_score:
        timings["verify"] = (time.perf_counter() - t) * 1e3
        return fail("not_found",
                    f"{name} not found: the best fit supports only {best['score']:.0%} of its visible "
                    f"edges (need {min_score:.0%}); the part may be hidden, outside the image or a "
                    f"different model", best["score"], cands)
    # distinctiveness: the support must drop when the pose is moved by a few pixels in every
    # direction of the table plane (a fit along one straight edge or onto texture does not)
    shift_mm = 4.0 / px_per_mm
    c_tab = transform_points(best["T"], model.center_obj[None])[0]
    # turned by as much as moves a typical edge point (mean distance from the centre) by those pixels
    r_mean = float(np.mean(np.linalg.norm(model.samples_obj - model.center_obj, axis=1)))
    dth = shift_mm / max(r_mean, 1.0)
    drops, owed = {}, {}
    es_b, sup_b = best["es"], best["sup"]
    for key, q in (("x", (shift_mm, 0, 0)), ("-x", (-shift_mm, 0, 0)), ("y", (0, shift_mm, 0)),
                   ("-y", (0, -shift_mm, 0)), ("rz", (0, 0, dth)), ("-rz", (0, 0, -dth))):
        if model.continuous_axis_obj is not None and key.endswith("rz"):
            continue
        T_q = _perturb3(best["T"], c_tab, np.array(q, float))
        sc, _, _ = _verify(eimg, model, T_q, T_cam_table, K, dist, occluders_cam, sub_fine, min_contrast=min_contrast)
        drops[key] = best["score"] - sc
        # the drop the part's own geometry owes: supported samples that the move carries off their
        # edge (a round outline turned, a long edge slid along itself, owe nothing)
        if len(es_b.index):
            uv_q = project_points_px(transform_points(T_cam_table @ T_q, es_b.points_obj), K, dist)
            moved = np.abs(np.einsum("ij,ij->i", uv_q - es_b.uv_px, es_b.normal_uv)) > 1.5
            owed[key] = float(np.count_nonzero(moved & sup_b)) / len(es_b.index)
    pairs, pair_ok = [], []
    for a, b in (("x", "-x"), ("y", "-y"), ("rz", "-rz")):
        k = a if drops.get(a, 1.0) >= drops.get(b, 1.0) else b
        d = drops.get(k, 1.0)
        pairs.append(d)
        # distinct: a clear drop, or (where the geometry owes less than twice that) at least half
        # of what it owes: a flange's holes are all that turning it moves
        need = min(min_distinctiveness, 0.5 * owed.get(k, 1.0)) if k.endswith("rz") else min_distinctiveness
        pair_ok.append(d >= max(need, 0.02))
    distinct_drop = float(min(pairs))
    if not all(pair_ok):
        weakest = ("x", "y", "rotation")[pair_ok.index(False)]
        timings["verify"] = (time.perf_counter() - t) * 1e3
        return fail("not_found",
                    f"{name} not found: the best fit ({best['score']:.0%} of its visible edges) is not "
                    f"distinct: moved a few pixels in {weakest} it still fits {best['score'] - distinct_drop:.0%} "
                    f"(need a drop of {min_distinctiveness:.0%}); it lies on straight edges or texture, "
                    f"not on the part", best["score"], cands)
    if rivals and rival_margin < min_margin:
        timings["verify"] = (time.perf_counter() - t) * 1e3
        return fail("ambiguous",
                    f"{name} ambiguous: two different poses fit almost equally well "
                    f"({best['score']:.0%} and {best['score'] - rival_margin:.0%} of the visible edges, margin "
                    f"{rival_margin:.0%} < {min_margin:.0%}); take another view or give the pose roughly",
                    best["score"], cands)
    # turned over: decided by the features only with twice the margin (fewer visible edges are
    # easier to support); otherwise the place is known and the face up is not -> datum question
    flip_runner = max((r["score"] for r in flips), default=float("nan"))
    flips_open = [r for r in flips if best["score"] - r["score"] < 2 * min_margin]

    # residual tilt: free 6-DoF fit from the flat result, with the contact prior
    def fit6(r):
        ra_ = None if model.continuous_axis_obj is None else r["T"][:3, :3] @ model.continuous_axis_obj
        pr = (r["T"], contact_sigma_mm if on_known_surface(r["T"]) else riser_sigma_mm,
              np.radians(contact_sigma_deg), hull_obj)
        T6_, info6_ = _refine(eimg, model, r["T"], T_cam_table, K, dist, occluders_cam, sub_fine,
                              free=FREE_6DOF, radii=(2.0, 2.0), min_contrast=min_contrast, round_axis_table=ra_,
                              prior=pr)
        conflict = "sol" in info6_ and np.max(np.abs(_prior_offsets(T6_, pr))) > MAX_PRIOR_SIGMAS
        return T6_, info6_, pr, conflict

    T6, info6, prior, conflict6 = fit6(best)
    if conflict6:
        # the best flat fit does not rest where it says (e.g. on a vise's seat where the part in fact
        # stands 20 mm higher on parallels and, seen from afar, looks nearly the same): a rival of
        # about the same score that does rest as it says is the better reading
        for r in sorted(results, key=lambda r: -r["key"]):
            if r is best or "sol" not in r["info"] or r["score"] < best["score"] - min_margin:
                continue
            alt = fit6(r)
            if "sol" in alt[1] and not alt[3]:
                best = r
                T6, info6, prior, conflict6 = alt
                break
    st = best["state"]
    n_rest = inv(model.resting_states[st].T_rest_obj)[:3, :3] @ np.array([0.0, 0.0, 1.0])
    up = T6[:3, :3] @ n_rest
    tilt = float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))
    flags = []
    tilt_sigma = float("nan")
    cov6_full = None
    if "sol" in info6:
        cov6_full = _covariance(info6, K, dist, T_cam_table, data_scale=sigma_scale)
        cov6 = cov6_full[0]
        tilt_sigma = float(np.degrees(np.sqrt(max(cov6[3, 3] + cov6[4, 4], 0.0))))
    if "sol" in info6 and tilt > max_tilt_deg and tilt > 3.0 * tilt_sigma:
        flags.append("tilt")          # the free fit says: not lying flat
    # The pose returned is the 6-DoF fit with the contact prior (maximum a-posteriori): where the
    # image cannot tell height and tilt, the contact holds them; where it can (a chip under an edge),
    # the image wins. Its covariance is the posterior, so the stated sigma covers all six axes.
    T_table_obj, info = (T6, info6) if "sol" in info6 else (best["T"], best["info"])
    contact_conflict = False
    if conflict6:
        # the image pulls the part far off the surface it should rest on (or tilts it by degrees):
        # either it does not rest as assumed or the fit is caught on other edges; keep the flat
        # pose and say that its height and tilt are not known
        contact_conflict = True
        flags.append("contact")
        T_table_obj, info = best["T"], best["info"]
    # of the poses that look exactly the same, give the most upright one (the part's CAD z up, as a
    # 3-axis work offset needs it); which of them is meant stays the operator's choice
    S_up = max([np.eye(4)] + [s.S for s in model.symmetries if s.exact],
               key=lambda S: round(float((T_table_obj @ S)[2, 2]), 6))
    T_table_obj, T6 = T_table_obj @ S_up, T6 @ S_up
    # the 6-DoF posterior is already at hand unless the flat fit stands in for it
    cov, inl, rms = cov6_full if info is info6 else _covariance(info, K, dist, T_cam_table, data_scale=sigma_scale)
    # covariance of (origin position, rotation): origin = c + R(dr)(o - c) + dt
    o = T_table_obj[:3, 3]
    c = transform_points(T_table_obj, model.center_obj[None])[0]
    lever = o - c
    A = np.eye(6)
    A[:3, 3:] = -np.array([[0, -lever[2], lever[1]], [lever[2], 0, -lever[0]], [-lever[1], lever[0], 0]])
    cov_o = A @ cov @ A.T
    sd = np.sqrt(np.maximum(np.diag(cov_o), 0))
    sigma = {"x_mm": float(sd[0]), "y_mm": float(sd[1]), "z_mm": float(sd[2]),
             "rx_deg": float(np.degrees(sd[3])), "ry_deg": float(np.degrees(sd[4])),
             "rz_deg": float(np.degrees(sd[5]))}
    if "sol" not in info6 or contact_conflict:     # height and tilt not measured, only assumed
        sigma.update(z_mm=float("nan"), rx_deg=float("nan"), ry_deg=float("nan"))
    # the spin of a round part about its own axis is not seen: undetermined, a datum question
    spin_free = set()
    if model.continuous_axis_obj is not None:
        ax = np.abs(T_table_obj[:3, :3] @ model.continuous_axis_obj)
        spin_free = {key for k, key in enumerate(("rx_deg", "ry_deg", "rz_deg")) if ax[k] > 0.9}
    for key in spin_free:
        sigma[key] = float("nan")
    # symmetry and datum
    exact = [s for s in model.symmetries if s.exact]
    listed = list(exact)
    ambiguous_datum = False
    if model.continuous_axis_obj is not None:
        note = ("the part is round: its rotation about its axis cannot be seen; the datum's angle "
                "about that axis is arbitrary (its sigma is reported as undetermined)")
        ambiguous_datum = True
    elif exact:
        note = (f"the part looks the same after {len(exact)} rotation(s) "
                f"({', '.join(f'{s.angle_deg:.0f} deg' for s in exact)}): {len(exact) + 1} equivalent "
                f"poses, the datum cannot be chosen from the image; confirm which one is meant")
        ambiguous_datum = True
    elif not sym_scores:
        note = "the part has no rotational symmetry: the datum follows from the fit"
    if sym_scores:
        gap = min(best["score"] - sc for _, sc in sym_scores)
        alts = ", ".join(f"{sc:.0%} turned {s.angle_deg:.0f} deg" for s, sc in sym_scores)
        head = "" if not (exact or model.continuous_axis_obj is not None) else note + "; "
        if gap >= 0.5 * min_margin:
            note = (f"{head}the outline is near-symmetric; the datum was chosen by the small features that "
                    f"break the symmetry (score {best['score']:.0%} vs {alts})")
        else:
            note = (f"{head}the outline is near-symmetric and the features that break the symmetry are not "
                    f"clear enough in this image (score {best['score']:.0%} vs {alts}): the datum is not "
                    f"decided; all {len(near) + 1} candidate poses are listed, confirm which one is meant")
            ambiguous_datum = True
            listed += near
    equivalent = tuple(T_table_obj @ s.S for s in listed)
    if flips_open:
        turned = ", ".join(f"{r['score']:.0%}" for r in flips_open)
        head = note + "; " if ambiguous_datum else ""
        note = (f"{head}the part fits almost as well turned over onto another face ({best['score']:.0%} as "
                f"shown, {turned} turned over): the features that tell the faces apart are not clear in "
                f"this view, so which face is up is not decided; the turned-over pose is listed, confirm "
                f"which one is meant")
        ambiguous_datum = True
        equivalent += tuple(r["T"] for r in flips_open)
    elif flips:
        note += (f"; turned over onto another face it fits clearly worse ({flip_runner:.0%} against "
                 f"{best['score']:.0%}): the face up is decided")
    if ambiguous_datum:
        flags.append("datum_ambiguous")
    # an axis whose sigma is unknown fails (NaN compares false); only the spin of a round part about
    # its own axis is exempt: it is a datum question, not an uncertainty
    uncertainty_ok = bool(all(sigma[k] <= max_sigma_mm for k in ("x_mm", "y_mm", "z_mm")) and
                          all(sigma[k] <= max_sigma_deg for k in ("rx_deg", "ry_deg", "rz_deg") if k not in spin_free))
    if not uncertainty_ok:
        flags.append("uncertainty")
    n_vis = len(best["es"].index)
    if n_vis < 60:
        flags.append("few_edges")
    vis_frac = 1.0
    if occluders_cam:
        es_free = visible_edge_samples(model, T_cam_table @ T_table_obj, K, dist, W, H, occlusion_test=True,
                                       subset=sub_fine)
        vis_frac = n_vis / max(len(es_free.index), 1)
    inlier_frac = float(inl.sum()) / max(n_vis, 1)
    supported_px = best["support_px"]
    unexplained = _unexplained_edges(eimg, model, T_cam_table @ T_table_obj, K, dist)
    height = float(transform_points(T_table_obj @ inv(model.resting_states[st].T_rest_obj), np.zeros((1, 3)))[0, 2])
    timings["verify"] = (time.perf_counter() - t) * 1e3
    timings["total"] = (time.perf_counter() - t_all) * 1e3
    return ObjectPose(
        model_name=name, T_cam_obj=T_cam_table @ T_table_obj, T_table_obj=T_table_obj, resting_state=st,
        score=float(best["score"]), inlier_edge_fraction=min(1.0, inlier_frac), residual_px=rms,
        visible_fraction=float(vis_frac), n_edge_samples=int(info["n_used"]), sigma=sigma, tilt_deg=tilt,
        tilt_sigma_deg=tilt_sigma, T_table_obj_6dof=T6, unexplained_fraction=unexplained,
        supported_edge_px=supported_px,
        uncertainty_ok=uncertainty_ok, height_offset_mm=height, margin=float(margin), runner_up_score=float(runner),
        distinctiveness=distinct_drop, covariance=cov_o,
        equivalent_poses=equivalent, datum_ambiguous=ambiguous_datum, datum_note=note, flags=tuple(flags),
        timings_ms=dict(timings))


@one_blas_thread
def recognise(image, K, dist, T_cam_table, candidates: list[PreparedModel], *, min_score: float = 0.6,
              min_margin: float = 0.1, gamma: float = 2.2, n_full: int = 4, **locate_kw) -> Recognition:
    """Which of ``candidates`` are in the image?

    Every candidate goes through the search and the planar fit (stages 1 and 2 of
    :func:`locate_object`); the ``n_full`` best by that coarse score are located completely and
    ranked by their verification score, the others keep their coarse score ("coarse only").
    A candidate is accepted when its score reaches ``min_score`` and no other candidate at the same
    place (centres closer than half the larger diameter) explains clearly more image edges
    (``supported_edge_px`` 25 % higher) or, explaining about as much, scores within ``min_margin``.
    Different objects at different places can all be accepted (a workpiece and its clamps).
    Nothing accepted: ``reason`` starts with "not recognised:" and names the top candidates.
    """
    t0 = time.perf_counter()
    K = np.asarray(K, dtype=float)
    dist = np.zeros(5) if dist is None else np.asarray(dist, dtype=float).ravel()
    T_cam_table = check_pose(T_cam_table, "T_cam_table")
    eimg = prepare_image(image, gamma=gamma)
    known = locate_kw.pop("known_models", ())
    if known:
        eimg = mask_known_edges(eimg, [(m, T_cam_table @ np.asarray(T, float)) for m, T in known], K, dist)
    regions = locate_kw.pop("known_regions", ())
    if len(regions):
        eimg = mask_table_regions(eimg, regions, T_cam_table, K, dist)
    search_kw = {k: locate_kw[k] for k in ("height_offsets_mm", "resting_states", "n_starts", "n_planar")
                 if k in locate_kw}
    coarse = []
    for m in candidates:
        found = _search(eimg, K, dist, T_cam_table, m, **search_kw)
        coarse.append(0.0 if isinstance(found, str) or not found[0] else float(found[0][0].score))
    order = np.argsort(-np.asarray(coarse), kind="stable")
    res = []
    for rank, i in enumerate(order):
        m = candidates[i]
        if rank < n_full:
            r = locate_object(None, K, dist, T_cam_table, m, edge_image=eimg, min_score=0.0, min_margin=0.0,
                              **locate_kw)
        else:
            r = ObjectFailure(model_name=m.name, kind="not_found", reason="coarse only", best_score=coarse[i],
                              candidates=(), timings_ms={})
        res.append((m, r))

    def score(r):
        return r.score if isinstance(r, ObjectPose) else r.best_score

    res.sort(key=lambda mr: -score(mr[1]))
    accepted = []
    ranked = []
    for i, (m, r) in enumerate(res):
        ok = isinstance(r, ObjectPose) and r.score >= min_score
        reason = ""
        if isinstance(r, ObjectPose) and not ok:
            reason = f"score {r.score:.0%} below {min_score:.0%}"
        elif isinstance(r, ObjectPose):
            c_i = transform_points(r.T_table_obj, m.center_obj[None])[0]
            for j, (m2, r2) in enumerate(res):
                if j == i or not isinstance(r2, ObjectPose) or r2.score < min_score:
                    continue
                c_j = transform_points(r2.T_table_obj, m2.center_obj[None])[0]
                if np.linalg.norm(c_i[:2] - c_j[:2]) >= 0.5 * max(m.diameter_mm, m2.diameter_mm):
                    continue            # different places: both may be there (workpiece and clamp)
                if r2.supported_edge_px > 1.25 * r.supported_edge_px:
                    ok = False          # e.g. a small block fitted into a bigger part's edges
                    reason = (f"{m2.name} explains more of the image at the same place "
                              f"({r2.supported_edge_px:.0f} px of edges vs {r.supported_edge_px:.0f} px)")
                    break
                if r.supported_edge_px <= 1.25 * r2.supported_edge_px and r.score - r2.score < min_margin:
                    ok = False
                    reason = (f"{m2.name} fits the same place almost as well "
                              f"({r.score:.0%} vs {r2.score:.0%})")
                    break
        else:
            reason = r.reason
        ranked.append({"model": m.name, "score": round(float(score(r)), 4), "ok": bool(ok), "reason": reason})
        if ok:
            accepted.append(r)
    ranked.sort(key=lambda d: (not d["ok"], -d["score"]))
    reason = ""
    if not accepted:
        top = ", ".join(f"{d['model']} {d['score']:.0%}" for d in ranked[:3])
        reason = f"not recognised: no candidate reached {min_score:.0%} with a margin of {min_margin:.0%} (top: {top})"
    return Recognition(accepted=tuple(accepted), ranked=tuple(ranked), reason=reason,
                       timings_ms={"total": (time.perf_counter() - t0) * 1e3})


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
