"""Sheet-metal detection on a slatted cutting bed: four corners, rotation and the work origin.

Method (:func:`find_sheet`)
---------------------------
1. **Seed.** On a reduced image, the sheet is the largest *untextured* region: the gradient energy
   (Sobel magnitude, box-filtered) is low on the sheet and high on slats, teeth and slag. The seed is
   the maximum of the distance transform of the low-energy mask, i.e. the centre of the largest
   inscribed disc; scrap parts and the gaps between slats are smaller than the sheet.
2. **Rays.** From the seed, 720 rays sample the lightly smoothed image; each stops at the first
   *step* (a jump against the mean of the preceding 2 to 6 px larger than the threshold), so slats,
   shadows and scrap beyond the sheet's edge never matter. Soft shadow edges change too slowly to
   count as a step.
3. **Quadrilateral.** The ray ends, undistorted to ideal pinhole pixels (a straight 3-D edge is a
   straight line there), are split into four lines by sequential RANSAC; consecutive lines (sorted by
   direction from the seed) intersect in the coarse corners.
4. **Subpixel edges.** Along each side, every ~2 px, an intensity profile across the edge is sampled
   from the raw image (bilinear, positions mapped through the distortion model). The edge is the 50 %
   crossing between the sheet level just inside and the level on the outside shoulder of the first
   step, linearly interpolated. A RANSAC line (MSAC cost, Torr & Zisserman 2000) followed by total
   least squares on the inliers gives the side; two passes with a narrowing search band.
5. **Corners, bed frame.** Adjacent side lines intersect (homogeneous cross product); the corners go
   to the bed plane ``z = thickness_mm`` through the homography of :class:`~app.vision.bed_scale.BedPlane`
   and back through the distortion model to raw pixels.

Conventions: raw pixels ``uv_px`` are OpenCV (u right, v down, pixel centres at integers); "ideal"
pixels are undistorted pinhole pixels with the same ``K``. Bed frame: origin at a front-left corner of
the slat field, x along the long side, z up, slat tips at z = 0; the sheet's top is z = thickness.
Corners are ordered nearest to the bed origin first, then counter-clockwise seen from above (+z);
``angle_deg`` is the direction of the edge corner 0 -> corner 1 against bed x. The work origin is
corner 0 moved by ``margin_mm`` along both sheet edges; its X axis runs along the edge 0 -> 1.

:func:`baseline_corners` is the reference's corner finder (global threshold, row-by-row scan for the
first and last transition), kept for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from app.vision.bed_scale import BedPlane
from app.vision.intrinsics import distort_px, undistort_px

MAX_MARGIN_MM = 20.0
# a step's outside shoulder ends where the profile moves by less than this fraction of its steepest
# increment: separates the top edge from the side face that follows it on the sides facing the camera
SHOULDER_FRACTION = 0.05


# ---------------------------------------------------------------------------------------------------
# result types


@dataclass(frozen=True)
class BedOffset:
    """A sheet's work origin in the bed frame: origin (x_mm, y_mm) and rotation c_deg about bed z (the
    machine's offset, :class:`app.machine.WorkOffset`, is made from it by
    :func:`app.geometry.work_offset.sheet_work_offset`)."""

    x_mm: float
    y_mm: float
    c_deg: float

    def as_dict(self) -> dict:
        return {"x_mm": round(self.x_mm, 4), "y_mm": round(self.y_mm, 4), "c_deg": round(self.c_deg, 5)}


@dataclass(frozen=True)
class SheetResult:
    """A found sheet.

    Attributes
    ----------
    corners_px : ndarray (4, 2)
        Raw image pixels of the top-face corners, nearest to the bed origin first, then CCW from above.
    corners_bed_mm : ndarray (4, 2)
        The same corners in the bed frame (x, y) mm, on the plane z = thickness_mm.
    angle_deg : float
        Direction of the edge corner 0 -> corner 1 against bed x, in (-180, 180].
    origin_bed_mm : ndarray (2,)
        Work origin: corner 0 moved by margin_mm along both edges.
    offset : BedOffset
        (origin x, origin y, angle) to send as the work offset (bed frame).
    side_lengths_mm : ndarray (4,)
        Edges 0-1, 1-2, 2-3, 3-0 on the bed plane.
    lines_ideal : ndarray (4, 3)
        Side k (corner k -> k+1) as a line a u + b v + c = 0 in ideal px, a^2 + b^2 = 1.
    edge_points_px : tuple of 4 ndarrays (n_k, 2)
        Subpixel edge points (raw px) found along each side; ``inliers`` marks those the line kept.
    rms_px : ndarray (4,)
        RMS distance of the inliers to their line (ideal px).
    """

    corners_px: np.ndarray
    corners_bed_mm: np.ndarray
    angle_deg: float
    origin_bed_mm: np.ndarray
    offset: BedOffset
    margin_mm: float
    thickness_mm: float
    side_lengths_mm: np.ndarray
    lines_ideal: np.ndarray
    edge_points_px: tuple = field(repr=False)
    inliers: tuple = field(repr=False)
    rms_px: np.ndarray = field(default_factory=lambda: np.zeros(4))
    seed_px: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def __bool__(self) -> bool:
        return True

    def as_dict(self) -> dict:
        """The CLI/REST answer (mm, degrees, px)."""
        return {
            "corners_px": np.round(self.corners_px, 3).tolist(),
            "corners_bed_mm": np.round(self.corners_bed_mm, 3).tolist(),
            "angle_deg": round(self.angle_deg, 5),
            "origin_bed_mm": np.round(self.origin_bed_mm, 3).tolist(),
            "margin_mm": self.margin_mm,
            "thickness_mm": self.thickness_mm,
            "offset": self.offset.as_dict(),
            "side_lengths_mm": np.round(self.side_lengths_mm, 3).tolist(),
            "edge_rms_px": np.round(self.rms_px, 4).tolist(),
            "edge_points": [int(m.sum()) for m in self.inliers],
        }


@dataclass(frozen=True)
class SheetFailure:
    """No sheet: falsy, with the reason and the stage that failed ("seed", "quad", "edges")."""

    reason: str
    stage: str
    seed_px: np.ndarray | None = None
    boundary_px: np.ndarray | None = None

    def __bool__(self) -> bool:
        return False

    def as_dict(self) -> dict:
        return {"error": self.reason, "stage": self.stage}


# ---------------------------------------------------------------------------------------------------
# small maths


def to_gray(image: np.ndarray) -> np.ndarray:
    """uint8/float image (H, W) or (H, W, 3) BGR -> float32 grey (H, W)."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.shape[2] == 3 else img[..., 0]
    return img.astype(np.float32, copy=False)


def fit_line_ransac(
    pts: np.ndarray, thr_px: float, n_hyp: int = 256, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Robust line through points (N, 2): RANSAC hypotheses scored by MSAC, then total least squares.

    Returns ``(line (3,) with a^2 + b^2 = 1, inlier mask (N,), rms of inliers)`` or ``None`` for fewer
    than 3 points or fewer than 3 inliers. Deterministic (seeded).
    """
    pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    n = len(pts)
    if n < 3:
        return None
    rng = np.random.default_rng(seed)
    i = rng.integers(0, n, n_hyp)
    j = (i + rng.integers(1, n, n_hyp)) % n
    d = pts[j] - pts[i]
    nrm = np.stack([-d[:, 1], d[:, 0]], axis=1)
    ln = np.linalg.norm(nrm, axis=1)
    ok = ln > 1e-9
    nrm = nrm[ok] / ln[ok, None]
    c = -np.sum(nrm * pts[i[ok]], axis=1)
    r = np.abs(pts @ nrm.T + c)  # (N, H)
    cost = np.minimum(r, thr_px) ** 2
    best = int(np.argmin(cost.sum(axis=0)))
    line = np.array([nrm[best, 0], nrm[best, 1], c[best]])
    inl = np.zeros(n, dtype=bool)
    for _ in range(3):
        inl = np.abs(pts @ line[:2] + line[2]) < thr_px
        if inl.sum() < 3:
            return None
        q = pts[inl]
        m = q.mean(axis=0)
        _, _, vt = np.linalg.svd(q - m, full_matrices=False)
        nv = vt[1]
        line = np.array([nv[0], nv[1], -nv @ m])
    res = pts[inl] @ line[:2] + line[2]
    rms = float(np.sqrt(np.mean(res**2)))
    tight = max(3.0 * rms, 0.25)  # drop the inliers' own tail (points biased by a slat right beside the edge)
    if tight < thr_px:
        keep = np.abs(pts @ line[:2] + line[2]) < tight
        if keep.sum() >= max(3, 0.5 * inl.sum()):
            q = pts[keep]
            m = q.mean(axis=0)
            _, _, vt = np.linalg.svd(q - m, full_matrices=False)
            line = np.array([vt[1, 0], vt[1, 1], -vt[1] @ m])
            inl = keep
            res = q @ line[:2] + line[2]
            rms = float(np.sqrt(np.mean(res**2)))
    return line, inl, rms


def _intersect(l1: np.ndarray, l2: np.ndarray) -> np.ndarray:
    p = np.cross(l1, l2)
    if abs(p[2]) < 1e-12:
        return np.array([np.nan, np.nan])
    return p[:2] / p[2]


def _sample(gray: np.ndarray, uv_px: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``gray`` at raw pixel positions (..., 2); NaN outside the image."""
    shp = uv_px.shape[:-1]
    flat = uv_px.reshape(-1, 2).astype(np.float32)
    n = len(flat)
    cols = min(max(n, 1), 4096)
    rows = -(-n // cols)
    maps = np.full((rows * cols, 2), -10.0, dtype=np.float32)
    maps[:n] = flat
    out = cv2.remap(gray, maps[:, 0].reshape(rows, cols), maps[:, 1].reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    h, w = gray.shape
    bad = (flat[:, 0] < 0) | (flat[:, 1] < 0) | (flat[:, 0] > w - 1) | (flat[:, 1] > h - 1)
    out = out.reshape(-1)[:n].copy()
    out[bad] = np.nan
    return out.reshape(shp)


def _noise_sigma(gray: np.ndarray, centre_px: np.ndarray, half: int = 24) -> float:
    """Grey-level noise near ``centre_px`` (inside the sheet): MAD of the Laplacian-like residual."""
    u, v = np.round(centre_px).astype(int)
    h, w = gray.shape
    win = gray[max(0, v - half): min(h, v + half), max(0, u - half): min(w, u + half)]
    if win.size < 25:
        return 2.0
    res = win[1:-1, 1:-1] - 0.25 * (win[:-2, 1:-1] + win[2:, 1:-1] + win[1:-1, :-2] + win[1:-1, 2:])
    return float(1.4826 * np.median(np.abs(res - np.median(res))) / np.sqrt(1.25))


def first_step_crossings(prof: np.ndarray, step_px: float, thr: float) -> np.ndarray:
    """Subpixel position (in px from the profile start) of the first step of each profile; NaN if none.

    Profiles (N, L) run from inside the sheet outwards with ``step_px`` between samples. The first
    step is the first sample that differs from the mean of the samples 1 to 3 px before it by more
    than ``thr`` grey levels. Its position is the 50 % crossing between the inside level (median of
    the samples 1.5 to 4 px before the step) and the outside shoulder (where the profile stops moving
    away, at most 3 px after the step), linearly interpolated between samples.
    """
    N, L = prof.shape
    near = max(1, int(round(1.0 / step_px)))
    far = max(near + 1, int(round(3.0 / step_px)))
    in_lo = int(round(4.0 / step_px))
    in_hi = max(1, int(round(1.5 / step_px)))
    after = max(2, int(round(3.0 / step_px)))
    out = np.full(N, np.nan)
    if L < far + after + 2:
        return out
    finite = np.isfinite(prof)
    cs = np.concatenate([np.zeros((N, 1)), np.cumsum(np.where(finite, prof, 0.0), axis=1)], axis=1)
    idx = np.arange(L)
    lo = np.clip(idx - far, 0, None)
    hi = np.clip(idx - near + 1, 1, None)
    ref = (cs[:, hi] - cs[:, lo]) / np.maximum(hi - lo, 1)
    dev = prof - ref
    dev[:, :far] = 0.0
    trig = np.abs(dev) > thr
    trig &= finite
    has = trig.any(axis=1)
    d = np.argmax(trig, axis=1)
    rows = np.flatnonzero(has & (d >= in_lo) & (d + after + 1 < L))
    if len(rows) == 0:
        return out
    d = d[rows]
    P = prof[rows]
    sgn = np.sign(dev[rows, d])
    win_in = d[:, None] + np.arange(-in_lo, -in_hi + 1)[None, :]
    level_in = np.median(P[np.arange(len(rows))[:, None], win_in], axis=1)  # NaN rows fail below
    # outside shoulder: follow the step while it keeps moving in its direction
    k = np.arange(len(rows))
    pos = d.copy()
    moving = np.ones(len(rows), dtype=bool)
    peak = np.zeros(len(rows))
    for _ in range(after):
        nxt = np.minimum(pos + 1, L - 1)
        inc = sgn * (P[k, nxt] - P[k, pos])
        peak = np.maximum(peak, np.where(moving, inc, 0.0))
        go = moving & (inc > np.maximum(0.08 * thr, SHOULDER_FRACTION * peak))
        pos = np.where(go, nxt, pos)
        moving = go
    level_out = P[k, pos]
    contrast = sgn * (level_out - level_in)
    mid = 0.5 * (level_in + level_out)
    # last sample before the shoulder that is still on the inside of the 50 % level
    s_idx = np.arange(-in_hi - near, after + 1)
    cand = np.clip(d[:, None] + s_idx[None, :], 0, L - 2)
    a = sgn[:, None] * (P[k[:, None], cand] - mid[:, None])
    b = sgn[:, None] * (P[k[:, None], cand + 1] - mid[:, None])
    cross = (a < 0) & (b >= 0) & (cand + 1 <= pos[:, None])
    ok = cross.any(axis=1) & (contrast > thr) & np.isfinite(level_in) & np.isfinite(level_out)
    j = cand[k, np.argmax(cross, axis=1)]
    p0 = P[k, j]
    p1 = P[k, j + 1]
    frac = (mid - p0) / np.where(np.abs(p1 - p0) < 1e-9, 1e-9, p1 - p0)
    pos_px = (j + np.clip(frac, 0.0, 1.0)) * step_px
    out[rows[ok]] = pos_px[ok]
    return out


# ---------------------------------------------------------------------------------------------------
# stages


def _seed(gray: np.ndarray, min_inscribed_px: float) -> tuple[np.ndarray, float] | SheetFailure:
    """Centre (raw px) and radius (px) of the largest inscribed disc of the untextured region."""
    h, w = gray.shape
    scale = max(1.0, max(h, w) / 480.0)
    small = cv2.resize(gray, (int(round(w / scale)), int(round(h / scale))), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), 1.0)
    gx = cv2.Sobel(small, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(small, cv2.CV_32F, 0, 1, ksize=3)
    energy = cv2.boxFilter(np.hypot(gx, gy), -1, (5, 5))
    low_ref = float(np.percentile(energy, 5))
    thr = max(4.0 * low_ref, low_ref + 6.0)
    mask = (energy < thr).astype(np.uint8)
    mask[0, :] = mask[-1, :] = 0
    mask[:, 0] = mask[:, -1] = 0
    dt = cv2.distanceTransform(mask, cv2.DIST_L2, 5)
    _, r, _, loc = cv2.minMaxLoc(dt)
    r_px = r * scale
    if r_px < min_inscribed_px:
        return SheetFailure(
            f"sheet not found: no untextured region larger than {2 * min_inscribed_px:.0f} px across "
            f"(largest {2 * r_px:.0f} px); check that the sheet is in view and lit, or lower min_side_mm",
            "seed",
        )
    seed = (np.array(loc, dtype=float) + 0.5) * scale - 0.5
    return seed, r_px


def _cast_rays(gray_s: np.ndarray, seed: np.ndarray, thr: float, n_rays: int = 720) -> np.ndarray:
    """End points (M, 2) raw px of rays from ``seed`` at their first step."""
    h, w = gray_s.shape
    ang = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    dirs = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    L = int(np.hypot(h, w))
    s = np.arange(L, dtype=np.float64)
    pts = seed[None, None, :] + s[None, :, None] * dirs[:, None, :]
    prof = _sample(gray_s, pts)
    pos = first_step_crossings(prof, 1.0, thr)
    ok = np.isfinite(pos)
    return seed[None, :] + pos[ok, None] * dirs[ok]


def _quad_from_points(pts_ideal: np.ndarray, seed_ideal: np.ndarray, min_area_px: float) -> np.ndarray | SheetFailure:
    """Four lines (4, 3), in order around the seed, from boundary points by sequential RANSAC."""
    remaining = pts_ideal.copy()
    lines = []
    for k in range(4):
        if len(remaining) < 6:
            break
        fit = fit_line_ransac(remaining, 2.0, n_hyp=400, seed=k)
        if fit is None:
            break
        line, inl, _ = fit
        if inl.sum() < max(6, 0.04 * len(pts_ideal)):
            break
        lines.append(line)
        remaining = remaining[~inl]
    if len(lines) < 4:
        return SheetFailure(
            f"sheet not found: no four-sided contour larger than {min_area_px:.0f} px² "
            f"(found {len(lines)} straight side(s) around the untextured region)", "quad")
    lines = np.array(lines)
    # orient normals away from the seed, sort by the normal's direction
    sgn = np.sign(lines[:, :2] @ seed_ideal + lines[:, 2])
    lines = lines * -np.where(sgn == 0, 1.0, sgn)[:, None]
    order = np.argsort(np.arctan2(lines[:, 1], lines[:, 0]))
    lines = lines[order]
    corners = np.array([_intersect(lines[k - 1], lines[k]) for k in range(4)])
    if not np.all(np.isfinite(corners)):
        return SheetFailure("sheet not found: two sides of the contour are parallel (no four-sided contour)", "quad")
    area = 0.5 * abs(np.cross(corners[2] - corners[0], corners[3] - corners[1]))
    turn = [np.cross(corners[(k + 1) % 4] - corners[k], corners[(k + 2) % 4] - corners[(k + 1) % 4]) for k in range(4)]
    if not (all(t > 0 for t in turn) or all(t < 0 for t in turn)) or area < min_area_px:
        return SheetFailure(
            f"sheet not found: no four-sided contour larger than {min_area_px:.0f} px² "
            f"(best quadrilateral: {area:.0f} px², {'convex' if all(t > 0 for t in turn) or all(t < 0 for t in turn) else 'not convex'})",
            "quad")
    return lines


def _refine_side(
    gray: np.ndarray, K: np.ndarray, dist: np.ndarray, p0: np.ndarray, p1: np.ndarray, inside_pt: np.ndarray,
    band_px: float, thr: float, spacing_px: float = 2.0, end_skip_px: float = 6.0, step_px: float = 0.5,
    max_points: int = 400, n_hyp: int = 256, origin_px: tuple[float, float] = (0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float] | None:
    """Subpixel edge points and fitted line for the side p0 -> p1 (ideal px).

    ``gray`` may be a crop of the raw image whose pixel (0, 0) is the raw pixel ``origin_px``.

    Returns ``(line (3,), edge points ideal (n, 2), inlier mask, rms)`` or ``None``.
    """
    e = p1 - p0
    length = float(np.linalg.norm(e))
    if length < 2 * end_skip_px + 4:
        return None
    e /= length
    n_out = np.array([e[1], -e[0]])
    if n_out @ (inside_pt - p0) > 0:
        n_out = -n_out
    skip = end_skip_px + 0.02 * length
    m = int(min(max_points, max(8, (length - 2 * skip) / spacing_px)))
    t = np.linspace(skip, length - skip, m)
    base = p0 + t[:, None] * e
    s = np.arange(-band_px, band_px + 1e-9, step_px)
    ideal = base[:, None, :] + s[None, :, None] * n_out
    raw = distort_px(ideal.reshape(-1, 2), K, dist).reshape(ideal.shape)
    prof = _sample(gray, raw - np.asarray(origin_px, dtype=np.float64))
    pos = first_step_crossings(prof, step_px, thr)
    ok = np.isfinite(pos)
    if ok.sum() < 5:
        return None
    pts = base[ok] + (pos[ok, None] - band_px) * n_out
    fit = fit_line_ransac(pts, 0.75, n_hyp=n_hyp)
    if fit is None:
        return None
    line, inl, rms = fit
    if inl.sum() < max(5, 0.2 * m):
        return None
    return line, pts, inl, rms


def _order_from_origin(corners_bed: np.ndarray) -> np.ndarray:
    """Index order (4,): counter-clockwise seen from +z, the corner nearest the bed origin first."""
    c = corners_bed
    area2 = np.sum(c[:, 0] * np.roll(c[:, 1], -1) - np.roll(c[:, 0], -1) * c[:, 1])
    idx = np.arange(4) if area2 > 0 else np.arange(4)[::-1]
    k = int(np.argmin(np.linalg.norm(c[idx], axis=1)))
    return np.roll(idx, -k)


def work_origin(corners_bed_mm: np.ndarray, margin_mm: float) -> tuple[np.ndarray, BedOffset]:
    """Work origin and offset from ordered corners (4, 2) bed mm.

    X runs along the edge corner 0 -> 1, Y perpendicular to it (counter-clockwise, towards the
    sheet); the origin is corner 0 + margin_mm * (X + Y). ``margin_mm`` must be within 0..20 mm.
    """
    if not 0.0 <= margin_mm <= MAX_MARGIN_MM:
        raise ValueError(f"origin margin {margin_mm} mm is outside 0..{MAX_MARGIN_MM:.0f} mm")
    c = np.asarray(corners_bed_mm, dtype=float)
    ex = (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
    ey = np.array([-ex[1], ex[0]])
    o = c[0] + margin_mm * (ex + ey)
    return o, BedOffset(float(o[0]), float(o[1]), float(np.degrees(np.arctan2(ex[1], ex[0]))))


def _finish(
    corners_ideal: np.ndarray, lines: np.ndarray, plane: BedPlane, margin_mm: float,
    edge_pts: list, inliers: list, rms: list, seed: np.ndarray,
) -> SheetResult:
    bed = plane.ideal_to_bed(corners_ideal)
    order = _order_from_origin(bed)
    # side k joins corner k and k+1; after reordering, recover the sides in the new order
    side_of = {frozenset((k, (k + 1) % 4)): k for k in range(4)}
    sides = [side_of[frozenset((int(order[k]), int(order[(k + 1) % 4])))] for k in range(4)]
    bed = bed[order]
    px = distort_px(corners_ideal[order], plane.K, plane.dist)
    origin, offset = work_origin(bed, margin_mm)
    return SheetResult(
        corners_px=px,
        corners_bed_mm=bed,
        angle_deg=offset.c_deg,
        origin_bed_mm=origin,
        offset=offset,
        margin_mm=float(margin_mm),
        thickness_mm=plane.height_mm,
        side_lengths_mm=np.linalg.norm(np.roll(bed, -1, axis=0) - bed, axis=1),
        lines_ideal=lines[sides],
        edge_points_px=tuple(distort_px(edge_pts[k], plane.K, plane.dist) for k in sides),
        inliers=tuple(inliers[k] for k in sides),
        rms_px=np.array([rms[k] for k in sides]),
        seed_px=seed,
    )


def find_sheet(
    image: np.ndarray,
    plane: BedPlane,
    margin_mm: float = 0.0,
    min_side_mm: float = 50.0,
    min_contrast: float = 10.0,
) -> SheetResult | SheetFailure:
    """Find the sheet's four top corners with subpixel accuracy.

    Parameters
    ----------
    image : ndarray (H, W) or (H, W, 3) BGR
        Camera image (raw, distorted).
    plane : BedPlane
        Intrinsics, ``T_cam_bed`` and ``height_mm`` = the sheet thickness (the top face's plane).
    margin_mm : float
        Work origin offset from corner 0 along both edges, 0..20 mm.
    min_side_mm : float
        Smallest sheet side accepted (mm on the bed plane).
    min_contrast : float
        Smallest grey-level step accepted as an edge.

    Returns
    -------
    SheetResult, or a falsy SheetFailure whose ``reason`` says what was not found.
    """
    if not 0.0 <= margin_mm <= MAX_MARGIN_MM:
        raise ValueError(f"origin margin {margin_mm} mm is outside 0..{MAX_MARGIN_MM:.0f} mm")
    gray = to_gray(image)
    K, dist = plane.K, plane.dist
    h, w = gray.shape
    scale_mm = float(plane.mm_per_px(np.array([[w / 2.0, h / 2.0]]))[0])
    min_side_px = min_side_mm / scale_mm
    seed = _seed(gray, 0.5 * min_side_px)
    if isinstance(seed, SheetFailure):
        return seed
    seed_px, _ = seed
    thr = max(min_contrast, 6.0 * _noise_sigma(gray, seed_px))
    gray_s = cv2.GaussianBlur(gray, (0, 0), 1.0)
    boundary = _cast_rays(gray_s, seed_px, thr)
    if len(boundary) < 24:
        return SheetFailure(f"sheet not found: only {len(boundary)} of 720 rays from the sheet's centre met an edge",
                            "quad", seed_px, boundary)
    b_ideal = undistort_px(boundary, K, dist)
    s_ideal = undistort_px(seed_px[None], K, dist)[0]
    lines = _quad_from_points(b_ideal, s_ideal, min_side_px**2)
    if isinstance(lines, SheetFailure):
        return SheetFailure(lines.reason, lines.stage, seed_px, boundary)
    corners = np.array([_intersect(lines[k - 1], lines[k]) for k in range(4)])  # corner k: sides k-1, k
    edge_pts: list = [None] * 4
    inl: list = [None] * 4
    rms: list = [0.0] * 4
    for band in (10.0, 6.0):
        centre = corners.mean(axis=0)
        new_lines = lines.copy()
        for k in range(4):
            fit = _refine_side(gray, K, dist, corners[k], corners[(k + 1) % 4], centre, band, thr)
            if fit is None:
                return SheetFailure(
                    f"sheet not found: side {k} (between coarse corners {np.round(distort_px(corners[[k, (k + 1) % 4]], K, dist), 1).tolist()} px) "
                    f"has too few edge points with a contrast above {thr:.0f} grey levels; check lighting and focus",
                    "edges", seed_px, boundary)
            new_lines[k], edge_pts[k], inl[k], rms[k] = fit
        # side k runs from corner k to corner k+1; corner k lies on sides k-1 and k
        lines = new_lines
        corners = np.array([_intersect(lines[k - 1], lines[k]) for k in range(4)])
        if not np.all(np.isfinite(corners)):
            return SheetFailure("sheet not found: fitted sides do not form a quadrilateral", "edges", seed_px, boundary)
    result = _finish(corners, lines, plane, margin_mm, edge_pts, inl, rms, seed_px)
    short = result.side_lengths_mm.min()
    if short < min_side_mm:
        return SheetFailure(f"sheet not found: no four-sided contour larger than {min_side_mm:.0f} mm a side "
                            f"(shortest side {short:.1f} mm)", "edges", seed_px, boundary)
    return result


# ---------------------------------------------------------------------------------------------------
# corner re-finding in a region of interest (drift monitoring)


def refine_corner(
    gray: np.ndarray, plane: BedPlane, corner_ideal: np.ndarray, dir_a: np.ndarray, dir_b: np.ndarray,
    roi_px: int = 100, band_px: float = 12.0, thr: float = 10.0, origin_px: tuple[float, float] = (0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Re-find one sheet corner near ``corner_ideal`` (ideal px) from its two edges.

    ``gray`` is the grey image, or a crop of it whose pixel (0, 0) is the raw pixel ``origin_px``
    (the monitor converts only the regions around the corners).

    ``dir_a`` and ``dir_b`` are unit directions (ideal px) from the corner along its two sheet edges.
    Each edge is searched only inside the ``roi_px`` square around the corner, within ``band_px`` of
    the previous edge. Returns ``(corner ideal (2,), new dir_a, new dir_b)`` or ``None``.
    """
    half = roi_px / 2.0
    reach = half - 2.0
    c = np.asarray(corner_ideal, dtype=np.float64)
    dirs = [np.asarray(dir_a, dtype=np.float64), np.asarray(dir_b, dtype=np.float64)]
    for band in (band_px, min(band_px, 5.0)):  # a wide search, then a narrow one around the new edges
        lines = []
        for j in range(2):
            d, other = dirs[j], dirs[1 - j]
            p1 = c + d * (reach / max(abs(d[0]), abs(d[1]), 1e-9))
            length = float(np.linalg.norm(p1 - c))
            fit = _refine_side(
                gray, plane.K, plane.dist, c, p1, c + 20.0 * other + 20.0 * d,
                band, thr, spacing_px=1.0, end_skip_px=min(6.0, 0.2 * length), max_points=60, n_hyp=64,
                origin_px=origin_px,
            )
            if fit is None:
                return None
            lines.append(fit[0])
        new_dirs = []
        for j, line in enumerate(lines):
            t = np.array([-line[1], line[0]])
            new_dirs.append(t if t @ dirs[j] > 0 else -t)
        c_new = _intersect(lines[0], lines[1])
        if not np.all(np.isfinite(c_new)) or np.any(np.abs(c_new - corner_ideal) > half):
            return None
        c, dirs = c_new, new_dirs
    return c, dirs[0], dirs[1]


# ---------------------------------------------------------------------------------------------------
# baseline: the reference's corner finder


@dataclass(frozen=True)
class BaselineResult:
    """Corners by the reference method (integer pixels), ordered like :class:`SheetResult`."""

    corners_px: np.ndarray
    corners_bed_mm: np.ndarray
    angle_deg: float
    threshold: float


def baseline_corners(image: np.ndarray, plane: BedPlane) -> BaselineResult | SheetFailure:
    """The reference's corner finder: a global (Otsu) threshold, then per image row the first and the
    last pixel above it; the four corners are the extreme scan points along the diagonals
    (min u+v, max u-v, max u+v, max v-u). No subpixel step, no distortion-aware line fit.
    """
    gray = to_gray(image).astype(np.uint8)
    thr, binary = cv2.threshold(gray, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    fg = binary > 0
    rows = np.flatnonzero(fg.any(axis=1))
    if len(rows) < 2:
        return SheetFailure("sheet not found: no pixel above the global threshold", "baseline")
    first = np.argmax(fg[rows], axis=1)
    last = fg.shape[1] - 1 - np.argmax(fg[rows, ::-1], axis=1)
    pts = np.concatenate([np.stack([first, rows], 1), np.stack([last, rows], 1)]).astype(float)
    u, v = pts[:, 0], pts[:, 1]
    quad = pts[[np.argmin(u + v), np.argmax(u - v), np.argmax(u + v), np.argmax(v - u)]]
    bed = plane.px_to_bed(quad)
    order = _order_from_origin(bed)
    bed = bed[order]
    e = bed[1] - bed[0]
    return BaselineResult(quad[order], bed, float(np.degrees(np.arctan2(e[1], e[0]))), float(thr))


# ---------------------------------------------------------------------------------------------------
# picture


def draw_sheet(image: np.ndarray, result: SheetResult | SheetFailure | BaselineResult) -> np.ndarray:
    """BGR picture: edge points (green inliers, red outliers), fitted outline, numbered corners, the
    work origin with its X (red) and Y (green) axes; for a failure the seed, ray ends and reason."""
    img = np.asarray(image)
    out = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.copy()
    if out.dtype != np.uint8:
        out = np.clip(out, 0, 255).astype(np.uint8)
    sc = max(1, int(round(max(out.shape[:2]) / 800)))
    if isinstance(result, SheetFailure):
        if result.boundary_px is not None:
            for p in result.boundary_px:
                cv2.circle(out, tuple(np.round(p).astype(int)), sc, (0, 165, 255), -1)
        if result.seed_px is not None:
            cv2.drawMarker(out, tuple(np.round(result.seed_px).astype(int)), (255, 0, 255), cv2.MARKER_CROSS, 20 * sc, 2 * sc)
        cv2.putText(out, result.reason[:110], (10, 30 * sc), cv2.FONT_HERSHEY_SIMPLEX, 0.6 * sc, (0, 0, 255), 2 * sc)
        return out
    if isinstance(result, SheetResult):
        for pts, inl in zip(result.edge_points_px, result.inliers):
            for p, ok in zip(pts, inl):
                cv2.circle(out, tuple(np.round(p).astype(int)), sc, (0, 200, 0) if ok else (0, 0, 255), -1)
    poly = np.round(result.corners_px * 16).astype(np.int32).reshape(-1, 1, 2)
    cv2.polylines(out, [poly], True, (255, 200, 0), sc, cv2.LINE_AA, shift=4)
    for k, p in enumerate(result.corners_px):
        q = tuple(np.round(p).astype(int))
        cv2.circle(out, q, 6 * sc, (0, 255, 255), sc, cv2.LINE_AA)
        cv2.putText(out, str(k), (q[0] + 8 * sc, q[1] - 8 * sc), cv2.FONT_HERSHEY_SIMPLEX, 0.7 * sc, (0, 255, 255), 2 * sc)
    if isinstance(result, SheetResult):
        scale = 0.15 * float(np.linalg.norm(result.corners_bed_mm[1] - result.corners_bed_mm[0]))
        a = np.radians(result.angle_deg)
        ex, ey = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
        o = result.origin_bed_mm
        # axes drawn through the corners' homography (distortion ignored: a picture, not a measurement)
        src = result.corners_bed_mm.astype(np.float32)
        dst = result.corners_px.astype(np.float32)
        Hm = cv2.getPerspectiveTransform(src, dst)
        pts = cv2.perspectiveTransform(np.array([[o, o + scale * ex, o + scale * ey]], dtype=np.float32), Hm)[0]
        o_px, x_px, y_px = (tuple(np.round(p).astype(int)) for p in pts)
        cv2.arrowedLine(out, o_px, x_px, (0, 0, 255), 2 * sc, cv2.LINE_AA, tipLength=0.1)
        cv2.arrowedLine(out, o_px, y_px, (0, 200, 0), 2 * sc, cv2.LINE_AA, tipLength=0.1)
        text = f"angle {result.angle_deg:.3f} deg  origin ({o[0]:.2f}, {o[1]:.2f}) mm  margin {result.margin_mm:g} mm"
    else:
        text = f"baseline: angle {result.angle_deg:.3f} deg  threshold {result.threshold:.0f}"
    cv2.putText(out, text, (10, 30 * sc), cv2.FONT_HERSHEY_SIMPLEX, 0.6 * sc, (255, 255, 255), 2 * sc)
    return out


__all__ = [
    "BaselineResult", "BedOffset", "SheetFailure", "SheetResult", "baseline_corners", "draw_sheet",
    "find_sheet", "first_step_crossings", "fit_line_ransac", "refine_corner", "to_gray", "work_origin",
]
