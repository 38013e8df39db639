"""Stages 1 and 2: where might the part be? Starts for the fine fit.

Every image edge pixel is cast onto the horizontal planes at the heights of the model's horizontal
edges (exact for any perspective); on such a plane the model's edges form a rigid template whose
oriented chamfer correlation with the plane's edge support is computed for every (x, y, theta) in
the frequency domain (in the spirit of the generalised Hough transform: Ballard 1981, "Generalizing
the Hough transform to detect arbitrary shapes", Pattern Recognition 13(2)); the best cells are
re-scored in the image with exact perspective and aligned in the table plane (:mod:`.planar_fit`).
Units: mm and rad in the table frame; pixels in the image.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import fft as sfft
from scipy import ndimage
from scipy.spatial.transform import Rotation

from app.geometry.model_edges import PreparedModel, project_points_px, visible_edge_samples
from app.geometry.transforms import check_pose, inv, make_pose, transform_points
from app.vision.object_pose.edge_image import EdgeImage, nearest_edge_maps
from app.vision.object_pose.planar_fit import planar_fit, sample_subset
from app.vision.object_pose.search_kernels import conj_product_sum, planar_scores


@dataclass
class Hyp:
    state: int
    T_table_obj: np.ndarray
    votes: float = 0.0
    score: float = 0.0
    height_mm: float = 0.0
    refined: dict | None = None
    source: str = "plane"           # "plane": the plane search; "clamped": between located jaws


#: edge-direction channels of the coarse correlation (pi / 4 wide each, an edge counted in the two
#: nearest)
COARSE_CHANNELS = 4


@dataclass(frozen=True, eq=False)
class EdgeRays:
    """Subsampled edge pixels of one image as rays in the table frame (``r0``; ``r1`` through the
    point one px along the edge; ``idx`` into the edge image's pixels), and what does not depend on
    the horizontal plane they are cast on.

    Cast onto the plane z, an edge runs along ``lam1 r1 - lam0 r0`` with ``lam = (z - C_z) / r_z``,
    that is ``(z - C_z) (r1 / r1_z - r0 / r0_z)``: the same direction on every plane (mod pi), so it
    is computed once per image (``phi``, rad mod pi), and so are its channels (``channel_bits``: bit k
    set when it lies within one channel width of channel k's centre, (k + 0.5) pi / COARSE_CHANNELS),
    not once per plane searched."""

    idx: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    phi: np.ndarray
    channel_bits: np.ndarray


def _channel_bits(phi: np.ndarray, n_channels: int = COARSE_CHANNELS) -> np.ndarray:
    """:attr:`EdgeRays.channel_bits` of directions ``phi`` (rad, mod pi)."""
    ch_w = np.pi / n_channels
    bits = np.zeros(len(phi), np.uint32)
    for k in range(n_channels):
        dphi = np.abs(np.mod(phi - (k + 0.5) * ch_w + np.pi / 2, np.pi) - np.pi / 2)
        bits |= (dphi <= ch_w).astype(np.uint32) << np.uint32(k)
    return bits


def _edge_rays_table(eimg: EdgeImage, K, dist, T_table_cam, max_edges: int, rng) -> EdgeRays | None:
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
    r0, r1 = rays[: len(idx)], rays[len(idx):]
    with np.errstate(divide="ignore", invalid="ignore"):   # rays along the plane: no direction on it
        d = r1[:, :2] / r1[:, 2:3] - r0[:, :2] / r0[:, 2:3]
    phi = np.mod(np.arctan2(d[:, 1], d[:, 0]), np.pi)
    return EdgeRays(idx, r0, r1, phi, _channel_bits(phi))


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


def _plane_edges(rays: EdgeRays, C, z: float, extent_xy, b: float):
    """Image edge pixels cast onto the horizontal plane z (table frame) on a grid of b mm: grid size
    (nx, ny), cell indices (ix, iy) and channel bits (:attr:`EdgeRays.channel_bits`) of the edges
    that fall inside the grid."""
    x0, x1, y0, y1 = extent_xy
    nx = int(np.ceil((x1 - x0) / b)) + 1
    ny = int(np.ceil((y1 - y0) / b)) + 1
    lam0 = (z - C[2]) / rays.r0[:, 2]
    lam1 = (z - C[2]) / rays.r1[:, 2]
    ok = (lam0 > 0) & (lam1 > 0)
    p0 = C[:2] + lam0[ok, None] * rays.r0[ok, :2]
    ix = np.floor((p0[:, 0] - x0) / b + 0.5).astype(np.int64)
    iy = np.floor((p0[:, 1] - y0) / b + 0.5).astype(np.int64)
    inside = (ix >= 0) & (ix < nx) & (iy >= 0) & (iy < ny)
    return nx, ny, ix[inside], iy[inside], rays.channel_bits[ok][inside]


def _support_maps(rays: EdgeRays, C, z: float, extent_xy, b: float, tau_bins: float):
    """Edge support on the plane z: (COARSE_CHANNELS, ny, nx) in [0, 1], 1 on an edge of that
    direction."""
    nx, ny, ix, iy, bits = _plane_edges(rays, C, z, extent_xy, b)
    sup = np.zeros((COARSE_CHANNELS, ny, nx), np.float32)
    for k in range(COARSE_CHANNELS):
        m = (bits & np.uint32(1 << k)) != 0   # channel k holds edges within one channel width
        img = np.full((ny, nx), 255, np.uint8)
        img[iy[m], ix[m]] = 0
        dt = cv2.distanceTransform(img, cv2.DIST_L2, 3)
        sup[k] = np.clip(1.0 - dt / tau_bins, 0.0, 1.0)
    return sup


#: threads of the plane search by default, each searching one resting state's planes: one, as the
#: engine keeps to one core unless its caller gives it more (the service gives each job its share of
#: the cores, SETUPCAM_SEARCH_THREADS; the CLI all of them). The compiled scorer, the FFTs and
#: OpenCV's transforms let go of Python's lock: on two idle cores
#: two threads take the plane search's wall clock down by a fifth to a third (devset setup_010 and 034:
#: 6.0 -> 4.3 s and 17 -> 13.5 s per image); on cores that are busy anyway they cost about 10 % more
#: CPU (all 40 devset scenes two at a time). Every result is the same.
SEARCH_THREADS = 1

#: the plane search's coarsest cell (mm): parts above 288 mm are searched on this grid (fixtures finer)
COARSE_STEP_MAX_MM = 16.0


def coarse_cell_mm(diameter_mm: float, max_mm: float = COARSE_STEP_MAX_MM) -> float:
    """The plane search's coarse cell (mm): the part's size / 18, at least 1.5 mm, at most ``max_mm``
    (the wide and mid scorers reach as far as this cell is coarse)."""
    return float(np.clip(diameter_mm / 18.0, 1.5, max(1.5, max_mm)))


def local_maxima_per_turn(width_mm: float, depth_mm: float, diameter_mm: float) -> int:
    """How many local maxima of each turn of the coarse correlation are re-scored in the image: one
    per 8 part-sized places of the searched plane (width x depth mm), 4 to 16. A small part on a
    big table competes in every turn with many more peaks of clutter (slot edges, shadows): the
    devset's angle block (55 mm across, 130 places on the table) ranked 3rd to 9th among the maxima
    of its turn, beyond the 4 that were taken, while the image scorer puts it near the top."""
    n_places = width_mm * depth_mm / max(diameter_mm, 1e-6) ** 2
    return int(np.clip(np.ceil(n_places / 8.0), 4, 16))


def _spread_picks(crease: np.ndarray, max_n: int) -> np.ndarray:
    """At most ``max_n`` indices spread evenly over the samples, sorted, with at most a quarter of
    them on smooth edges when there are creases enough: a bore or a fillet is a dense bundle of
    smooth edges of which one or two show (as silhouettes), and evenly spaced samples would spend
    most of a template on them."""
    if len(crease) <= max_n:
        return np.arange(len(crease))
    n_crease_all = int(crease.sum())
    n_smooth = min(len(crease) - n_crease_all, max_n // 4) if n_crease_all >= max_n // 2 else \
        max_n - min(n_crease_all, max_n)
    pick = []
    for mask, n in ((crease, max_n - n_smooth), (~crease, n_smooth)):
        idx = np.nonzero(mask)[0]
        if n > 0 and len(idx):
            pick.append(idx[np.linspace(0, len(idx) - 1, min(n, len(idx))).astype(np.int64)])
    return np.sort(np.concatenate(pick))


def edge_faces_of(model: PreparedModel, T_rest_obj: np.ndarray, sel: np.ndarray):
    """What the image scorer needs to tell which template samples can show: the normals (resting
    frame) of the faces either side of each sample's edge (a boundary edge repeats its one face),
    and which edges are smooth (a bore's or a fillet's facets: they show only as silhouettes)."""
    N = model.face_normals @ T_rest_obj[:3, :3].T
    ef_s = model.edge_faces[model.sample_edge[sel]]
    return (N[ef_s[:, 0]], N[np.where(ef_s[:, 1] >= 0, ef_s[:, 1], ef_s[:, 0])],
            ~model.edge_feature[model.sample_edge[sel]])


#: the self-occlusion masks' bins of the direction the camera is seen from, in the resting frame (deg)
VIEW_BIN_DEG = 15.0
#: the self-occlusion masks are rendered this many px across the model (a z-buffer per bin used)
VIEW_RENDER_PX = 300


def _view_bins(model: PreparedModel, T_rest_obj: np.ndarray, C, hx, hy, ht, height_mm: float):
    """The bin of the direction from each planar pose's model centre to the camera centre ``C``
    (table frame, mm), in the resting frame: ``1000 * azimuth + 500 + elevation``, each in steps of
    :data:`VIEW_BIN_DEG` (a camera below the part's centre has a negative elevation); and the median
    distance (mm)."""
    c = transform_points(T_rest_obj, model.center_obj[None, :])[0]
    co, si = np.cos(ht), np.sin(ht)
    vx = C[0] - (hx + co * c[0] - si * c[1])
    vy = C[1] - (hy + si * c[0] + co * c[1])
    vz = np.full_like(vx, C[2] - (height_mm + c[2]))
    rx, ry = co * vx + si * vy, -si * vx + co * vy          # turned back into the resting frame
    n_az = int(round(360.0 / VIEW_BIN_DEG))
    az = np.mod(np.rint(np.degrees(np.arctan2(ry, rx)) / VIEW_BIN_DEG), n_az).astype(np.int64)
    el = np.rint(np.degrees(np.arctan2(vz, np.hypot(rx, ry))) / VIEW_BIN_DEG).astype(np.int64)
    return az * 1000 + el + 500, float(np.median(np.sqrt(vx ** 2 + vy ** 2 + vz ** 2)))


def _self_hidden(model: PreparedModel, T_rest_obj: np.ndarray, view_bin: int, distance_mm: float,
                 sel: np.ndarray) -> np.ndarray:
    """Which samples ``sel`` the model hides behind itself, seen from the middle of ``view_bin``
    (:func:`_view_bins`) at ``distance_mm``: (len(sel),) bool. A sample that turns away from that
    view is left to the scorer's own facing test (it depends on the exact pose)."""
    az, el = np.radians(VIEW_BIN_DEG * (view_bin // 1000)), np.radians(VIEW_BIN_DEG * (view_bin % 1000 - 500))
    to_cam = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    c = transform_points(T_rest_obj, model.center_obj[None, :])[0]
    z = -to_cam
    x = np.cross(z, [0.0, 0.0, 1.0]) if abs(to_cam[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])                     # rows: the camera's axes in the resting frame
    d = max(distance_mm, model.diameter_mm)
    T_cam_rest = make_pose(R, -R @ (c + d * to_cam))
    f = VIEW_RENDER_PX * d / max(model.diameter_mm, 1e-6)
    n = int(1.2 * VIEW_RENDER_PX)
    K = np.array([[f, 0.0, n / 2], [0.0, f, n / 2], [0.0, 0.0, 1.0]])
    T = T_cam_rest @ T_rest_obj
    kw = {"subset": sel, "margin_px": 0.0, "max_buffer_px": n}
    front = visible_edge_samples(model, T, K, np.zeros(5), n, n, occlusion_test=False, **kw).index
    shown = visible_edge_samples(model, T, K, np.zeros(5), n, n, occlusion_test=True, **kw).index
    return np.isin(sel, np.setdiff1d(front, shown))


def _unhidden_scores(score, model: PreparedModel, T_rest_obj, C, hx, hy, ht, P, D, w, sel, height_mm: float,
                     normals, masks: dict):
    """``score(hx, hy, ht, P, D, w, normals=normals)`` with, per pose, the samples the model hides
    behind itself from where the camera sees it (:func:`_self_hidden`, one mask per view bin, kept in
    ``masks``) weighted zero: seen from above, a vise's base and the lower steps of its ways lie under
    its body, and counting them as misses ranked its true place below clutter."""
    bins, dist = _view_bins(model, T_rest_obj, C, hx, hy, ht, height_mm)
    out = np.empty(len(hx))
    for vb in np.unique(bins):
        key = (vb, sel.tobytes())
        if key not in masks:
            masks[key] = _self_hidden(model, T_rest_obj, int(vb), dist, sel)
        i = np.nonzero(bins == vb)[0]
        out[i] = score(hx[i], hy[i], ht[i], P, D, np.where(masks[key], 0.0, w), normals=normals)
    return out


def _plane_search(model: PreparedModel, state: int, height_mm: float, rays, C, extent_xy,
                  n_peaks: int, *, px_mm: float, image_score, max_template: int = 400, n_coarse: int = 40,
                  cache: dict | None = None, image_score_wide=None, image_score_mid=None,
                  coarse_step_max_mm: float = COARSE_STEP_MAX_MM, keep_spectra: bool = True,
                  turn_maxima: int = 0, self_occlusion: bool = False) -> list[Hyp]:
    """Exhaustive oriented chamfer matching of the model's horizontal edges on the table planes.

    The image's edge pixels are cast onto each horizontal plane that carries model edges (height
    levels of the resting state); on such a plane the model's edges form a rigid template, so the
    score of (x, y, theta) is a correlation of the template with the plane's edge support (truncated
    distance transform, one map per edge direction). Coarse: every (x, y, theta) on a grid of about
    diameter/18, at most ``coarse_step_max_mm`` (correlations summed in the frequency domain, one
    inverse FFT per theta); fine: the
    best ``n_coarse`` cells re-scored twice on half-step grids in the image itself (``image_score``:
    exact perspective, full-resolution edges and their directions). ``px_mm`` is the plane footprint
    of one image pixel. Returns the best distinct (x, y, theta) as starts. ``keep_spectra``: keep the
    rotated template's spectra in ``cache`` for a next plane on the same grid (the caller knows
    whether one follows: a plane's spectra take up to ~140 MB). ``turn_maxima``: at least this many
    local maxima of every turn are re-scored in the image. ``self_occlusion``: the image scores
    leave out the samples the model hides behind itself from where the camera sees each pose
    (:func:`_unhidden_scores`; the masks are kept in ``cache`` too).
    """
    cache = {} if cache is None else cache
    masks = cache.setdefault(("self_hidden", state), {})     # per view bin and template
    rs = model.resting_states[state]
    P = transform_points(rs.T_rest_obj, model.samples_obj)
    D = model.sample_dir_obj @ rs.T_rest_obj[:3, :3].T
    N = model.face_normals @ rs.T_rest_obj[:3, :3].T
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

    def template(spacing_mm, max_n, only=None):
        step = max(1, int(round(spacing_mm / model.sample_step_mm)))
        keep = np.ones(len(cand), bool) if only is None else only
        sel = cand[keep][::step]
        w = wts_all[keep][::step]
        if len(sel) > max_n:
            k = _spread_picks(crease[keep][::step], max_n)
            sel, w = sel[k], w[k]
        return P[sel, :2], np.arctan2(D[sel, 1], D[sel, 0]), P[sel, 2] + height_mm, w, sel

    # ---- coarse: correlation per theta
    b = coarse_cell_mm(diam, coarse_step_max_mm)
    b = max(b, max(x1 - x0, y1 - y0) / 250.0)
    nx = int(np.ceil((x1 - x0) / b)) + 1
    ny = int(np.ceil((y1 - y0) / b)) + 1
    dth = min(np.radians(9.0), 1.5 * b / max(0.5 * diam, 1e-6))
    nt = 1 if round_part else int(np.ceil(2 * np.pi / dth))
    dth = 2 * np.pi / nt
    nch = COARSE_CHANNELS
    ch_w = np.pi / nch
    m_xy, m_phi, m_z, wts, _ = template(b / 2, max_template, only=coarse_from)
    levels = _levels(m_z, wts, max_levels=6, gap_mm=0.5 * b)
    support = [_support_maps(rays, C, z_l, extent_xy, b, 1.5) for z_l, _ in levels]
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
    # the rotated templates' spectra depend on the template and the grid only, not on the plane's
    # height: planes searched one after the other on the same grid (the risers) share them
    kernels = _kernel_cache(cache, (m_xy.tobytes(), m_phi.tobytes(), wts.tobytes(), lvl_of.tobytes(),
                                    nt, dth, b, Rk, nch, nlc, Py, Px)) if keep_spectra else []
    spectra_room = KERNEL_CACHE_BYTES if keep_spectra else 0
    FS_of: dict = {}
    for it in range(nt):
        if it < len(kernels):
            used, FK = kernels[it]
        else:
            th = it * dth
            c, s = np.cos(th), np.sin(th)
            kx = np.rint((c * m_xy[:, 0] - s * m_xy[:, 1]) / b + Rk).astype(np.int64)
            ky = np.rint((s * m_xy[:, 0] + c * m_xy[:, 1]) / b + Rk).astype(np.int64)
            chn = np.clip((np.mod(m_phi + th, np.pi) / ch_w).astype(np.int64), 0, nch - 1)
            ker = np.zeros((nlc, ks, ks), np.float32)
            np.add.at(ker, (lvl_of * nch + chn, ky, kx), wts.astype(np.float32))
            used = np.nonzero(ker.reshape(nlc, -1).any(axis=1))[0]
            FK = _padded_rfft2(ker[used], Py, Px)
            if it == len(kernels) and sum(f.nbytes for _, f in kernels) < spectra_room:
                kernels.append((used, FK))
        FSc_used = FS_of.get(used.tobytes())
        if FSc_used is None:             # the turns use few distinct sets of channels
            FSc_used = FS_of[used.tobytes()] = np.conj(FS[used])
        # sum_k FS_k conj(FK_k) as conj(sum_k conj(FS_k) FK_k): the support's spectra conjugated once
        # per plane instead of every turn's template spectra, a pass less over the largest arrays;
        # the same numbers (IEEE products and sums are symmetric under the sign flips)
        corr = sfft.irfft2(conj_product_sum(FSc_used, FK), s=(Py, Px), workers=-1)
        _rolled_crop_into(score[it], corr, Rk)
    flat = score.ravel()
    top = _top_k(flat, min(len(flat), 20 * n_coarse))
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
        k_t = max(local_maxima_per_turn(x1 - x0, y1 - y0, diam), turn_maxima)
        # a turn's 3 x 3 maxima (OpenCV's dilation: the same maximum as scipy's with the border
        # repeated, ten times faster)
        peak = np.stack([cv2.dilate(sl, np.ones((3, 3), np.uint8)) for sl in score])
        loc = (score == peak) & (score > 0)
        it2, cell = _best_per_row(loc.reshape(nt, -1), score.reshape(nt, -1), k_t)
        iy2, ix2 = np.divmod(cell, nx)
        ax = np.concatenate([cx, x0 + ix2 * b])
        ay = np.concatenate([cy, y0 + iy2 * b])
        at = np.concatenate([cth, it2 * dth])
        _, _, _, w_w, w_sel = template(max(3.0 * px_mm, diam / 60.0), 80)
        w_args = (P[w_sel] + np.array([0.0, 0.0, height_mm]), D[w_sel], w_w)
        if self_occlusion:
            wide = _unhidden_scores(image_score_wide, model, rs.T_rest_obj, C, ax, ay, at, *w_args, w_sel,
                                    height_mm, edge_faces_of(model, rs.T_rest_obj, w_sel), masks)
        else:
            wide = image_score_wide(ax, ay, at, *w_args, normals=edge_faces_of(model, rs.T_rest_obj, w_sel))
        order = np.argsort(-wide, kind="stable")
        keep = _nms(ax[order], ay[order], at[order], 1.5 * b, 1.5 * dth, n_coarse)
        cx, cy, cth = ax[order][keep], ay[order][keep], at[order][keep]

    # ---- fine: re-score the coarse cells' neighbourhoods in the image (exact perspective)
    _, _, _, f_w, f_sel = template(max(2.0 * px_mm, diam / 100.0), 120)
    f_P = P[f_sel] + np.array([0.0, 0.0, height_mm])
    f_D = D[f_sel]
    f_N = edge_faces_of(model, rs.T_rest_obj, f_sel)
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
        fscore = _unhidden_scores(image_score, model, rs.T_rest_obj, C, hx, hy, ht, f_P, f_D, f_w, f_sel, height_mm,
                                  f_N, masks) if self_occlusion else \
            image_score(hx, hy, ht, f_P, f_D, f_w, normals=f_N)
        best_of_cell = np.arange(len(hx) // nb) * nb + np.argmax(fscore.reshape(-1, nb), axis=1)
        order = best_of_cell[np.argsort(-fscore[best_of_cell])]
        hx, hy, ht, fscore = hx[order], hy[order], ht[order], fscore[order]
    keep = _nms(hx, hy, ht, max(0.2 * diam, 2.5 * b), np.radians(15.0), n_peaks)
    out: list[Hyp] = []
    for i in keep:
        c1, s1 = np.cos(ht[i]), np.sin(ht[i])
        T = make_pose(np.array([[c1, -s1, 0], [s1, c1, 0], [0, 0, 1.0]]), [hx[i], hy[i], height_mm]) @ rs.T_rest_obj
        out.append(Hyp(state=state, T_table_obj=T, votes=float(fscore[i]), height_mm=height_mm))
    return out


def _shown_weight_floor(w: np.ndarray, smooth: np.ndarray) -> float:
    """The least weight a pose's score is a share of: half the creases' (half the whole template's
    where it has none), so that a pose hiding most of the part does not score on its few edges left."""
    return 0.5 * float(w[~smooth].sum()) if (~smooth).any() else 0.5 * float(w.sum())


def _image_scorer(eimg: EdgeImage, K, dist, T_cam_table, tau_px: float = 2.0, max_angle_deg: float = 20.0,
                  compiled: bool = True):
    """Score function for many planar poses at once: each pose (x, y, theta) moves template points
    ``P`` (M, 3, resting frame) with directions ``D``; the score is the weighted share of projected
    points within ``tau_px`` of an image edge of compatible direction (soft: 1 - d / tau). With
    ``normals`` (from :func:`edge_faces_of`) only the samples that can show at that pose count, by
    the rule of :func:`app.geometry.model_edges.visible_edge_samples` without its z-buffer.

    ``compiled``: the numba loop of :mod:`.search_kernels`, about 7x faster with the same numbers
    (bit for bit on all 40 devset scenes; BLAS may sum a product in another order, so the tests allow
    1e-12). The numpy code below is its reference, and serves a tilted sensor (14 coefficients with
    tau_x, tau_y), which the loop does not model."""
    R = T_cam_table[:3, :3]
    t = T_cam_table[:3, 3]
    cos_tol = np.cos(np.radians(max_angle_deg))

    C = -R.T @ t                                  # camera centre, table frame

    W, H = eimg.width, eimg.height
    dd = np.zeros(0) if dist is None else np.asarray(dist, dtype=float).ravel()
    if compiled and not (len(dd) == 14 and np.any(dd[12:] != 0)):
        d12 = np.zeros(12)
        d12[: min(len(dd), 12)] = dd[:12]
        flags = (bool(np.any(d12 != 0)), bool(np.any(d12[5:8] != 0)), bool(np.any(d12[8:12] != 0)))
        Kf = np.ascontiguousarray(K, dtype=float)
        Rc, tc = np.ascontiguousarray(R, dtype=float), np.ascontiguousarray(t, dtype=float)
        no_n, no_s = np.zeros((1, 3)), np.zeros(1, bool)

        def score_compiled(hx, hy, ht, P, D, w, normals=None):
            d_map, cos_map, sin_map = nearest_edge_maps(eimg)
            f64 = [np.ascontiguousarray(a, dtype=float) for a in (hx, hy, ht, P, D, w)]
            if normals is None:
                N0, N1, smooth, w_floor = no_n, no_n, no_s, 0.0
            else:
                N0, N1, smooth = (np.ascontiguousarray(a) for a in normals)
                N0, N1 = N0.astype(float, copy=False), N1.astype(float, copy=False)
                w_floor = _shown_weight_floor(f64[5], smooth)
            return planar_scores(*f64, N0, N1, smooth.astype(bool, copy=False), normals is not None, w_floor,
                                 Rc, tc, C, Kf, d12, *flags, d_map, cos_map, sin_map, W, H, float(tau_px),
                                 float(cos_tol))

        return score_compiled

    def score(hx, hy, ht, P, D, w, normals=None):
        # the same arithmetic as written out per pose, on contiguous arrays and with one lookup of
        # the edge maps (nearest_edge_maps) instead of two: the scores are bit for bit the same
        n, M = len(hx), len(P)
        c, s = np.cos(ht)[:, None], np.sin(ht)[:, None]
        X = np.empty((n, M, 3))
        X[..., 0] = hx[:, None] + c * P[None, :, 0] - s * P[None, :, 1]
        X[..., 1] = hy[:, None] + s * P[None, :, 0] + c * P[None, :, 1]
        X[..., 2] = P[None, :, 2]
        vis = None
        if normals is not None:
            # a crease shows only if one of its faces turns towards the camera (back edges of the
            # part never do; counting them drowns the true pose among clutter that fits by chance);
            # a smooth edge (a bore's or a fillet's facets) only where one face turns away: a silhouette
            N0, N1, smooth = normals
            V0, V1, V2 = C[0] - X[..., 0], C[1] - X[..., 1], C[2] - P[None, :, 2]   # towards the camera
            facing = []
            for Nk in (N0, N1):
                nx = c * Nk[None, :, 0] - s * Nk[None, :, 1]
                ny = s * Nk[None, :, 0] + c * Nk[None, :, 1]
                nx *= V0
                ny *= V1
                nx += ny
                nx += Nk[None, :, 2] * V2
                facing.append(nx > 0)
            vis = np.where(smooth[None, :], facing[0] ^ facing[1], facing[0] | facing[1])
            w_floor = _shown_weight_floor(w, smooth)
        Dt = np.empty((n, M, 3))
        Dt[..., 0] = c * D[None, :, 0] - s * D[None, :, 1]
        Dt[..., 1] = s * D[None, :, 0] + c * D[None, :, 1]
        Dt[..., 2] = D[None, :, 2]
        Xc = X.reshape(-1, 3) @ R.T + t
        X2 = Dt.reshape(-1, 3) @ R.T
        X2 *= 0.5
        X2 += Xc                                  # half a mm along the edge
        uv = project_points_px(Xc, K, dist)
        tv = project_points_px(X2, K, dist)
        tv -= uv
        u, v = uv[:, 0], uv[:, 1]
        ok = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (v >= 0) & (u <= W - 1) & (v <= H - 1)
        iu = np.clip(np.nan_to_num(u).astype(np.int64), 0, W - 1)
        iv = np.clip(np.nan_to_num(v).astype(np.int64), 0, H - 1)
        d_map, cos_map, sin_map = nearest_edge_maps(eimg)
        px = iv * W + iu
        d = d_map[px]
        tn = np.linalg.norm(tv, axis=1) + 1e-12
        # the image gradient is perpendicular to the edge: |sin(angle between gradient and edge)|
        compat = np.abs(cos_map[px] * tv[:, 1] - sin_map[px] * tv[:, 0]) / tn >= cos_tol
        val = (np.clip(1.0 - d / tau_px, 0.0, 1.0) * compat * ok).reshape(n, M)
        if vis is None:
            return val @ w / max(float(w.sum()), 1e-9)
        # share of the visible weight, but never of less than half the creases' weight (a pose that
        # hides most of the part would otherwise score on its few edges left)
        return (val * vis) @ w / np.maximum(vis @ w, w_floor + 1e-9)

    return score


def _padded_rfft2(ker: np.ndarray, Py: int, Px: int) -> np.ndarray:
    """``rfft2(ker, s=(Py, Px))`` of small kernels (n, k, k) zero-padded to (Py, Px): the rows'
    transforms of the k rows that are not zero, then the columns' (the zero rows transform to zeros
    either way, as rfft2 would take them: the same numbers, a fraction of the work)."""
    if ker.shape[-2] > Py or ker.shape[-1] > Px:       # rfft2 would crop: leave it to it
        return sfft.rfft2(ker, s=(Py, Px), workers=-1)
    rows = sfft.rfft(ker, n=Px, axis=-1, workers=-1)
    out = np.zeros(ker.shape[:-2] + (Py, rows.shape[-1]), rows.dtype)
    out[..., : ker.shape[-2], :] = rows
    return sfft.fft(out, axis=-2, workers=-1, overwrite_x=True)


def _rolled_crop_into(out: np.ndarray, a: np.ndarray, r: int) -> None:
    """``out[:] = np.roll(a, (r, r), axis=(0, 1))[:ny, :nx]`` (``(ny, nx) = out.shape``, ``0 <= r``
    less than ``a``'s sides) by copying the (up to) four blocks it takes, not the whole rolled array."""
    def parts(n_out: int, n_a: int) -> list[tuple[slice, slice]]:
        first = min(r, n_out)        # out's first r rows come from a's last r, the rest from its start
        return [(slice(0, first), slice(n_a - r, n_a - r + first))] + \
            ([(slice(r, n_out), slice(0, n_out - r))] if n_out > r else [])

    for o_y, a_y in parts(out.shape[0], a.shape[0]):
        for o_x, a_x in parts(out.shape[1], a.shape[1]):
            out[o_y, o_x] = a[a_y, a_x]


#: at most this much memory (bytes) holds a template's spectra for the next plane (measured: up to
#: 136 MB for a workpiece on the devset's table); the turns beyond it are transformed per plane
KERNEL_CACHE_BYTES = 256 * 2 ** 20


def _kernel_cache(cache: dict, key: tuple) -> list:
    """The list of (used channels, spectrum) per turn of the coarse template described by
    ``key``, kept in ``cache`` (the resting state's, :func:`find_starts`) for the next plane searched
    with the same template and grid; empty for a new one (the caller fills it, up to
    :data:`KERNEL_CACHE_BYTES`). Only the last template is kept: a template's spectra take tens of MB."""
    held = cache.get("coarse_kernels")
    if held is None or held[0] != key:
        held = (key, [])
        cache["coarse_kernels"] = held
    return held[1]


def _top_k(flat: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` largest of ``flat``, largest first, equal values in the order of their
    index: one answer, whatever the partition does with ties (a symmetric part's turns score exactly
    alike). Taken from the few values above a threshold that about k / 4 of every 16th value exceed
    (the coarse scores: ~2 million, k = 800; 21 -> 1.3 ms measured on a loaded machine), from all
    where that lets too few through."""
    cand = np.arange(len(flat))
    if len(flat) > 8 * k:
        sample = flat[::16]
        thr = np.partition(sample, len(sample) - 1 - k // 4)[len(sample) - 1 - k // 4]
        above = np.flatnonzero(flat >= thr)
        if len(above) > k:
            cand = above
    v = flat[cand]
    if len(cand) > k:
        kth = np.partition(v, len(v) - k)[len(v) - k]          # the k-th largest value
        over = np.flatnonzero(v > kth)
        tied = np.flatnonzero(v == kth)[: k - len(over)]        # the first by index
        keep = np.sort(np.concatenate([over, tied]))
        cand, v = cand[keep], v[keep]
    return cand[np.lexsort((cand, -v))]


def _best_per_row(mask: np.ndarray, values: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) of at most ``k`` entries per row where ``mask`` holds, the largest ``values``
    first and equal ones in the order of their column; rows in order."""
    rows, cols = np.nonzero(mask)
    v = values[rows, cols]
    order = np.lexsort((cols, -v, rows))
    rows, cols = rows[order], cols[order]
    rank = np.arange(len(rows)) - np.searchsorted(rows, rows)     # place within its row
    return rows[rank < k], cols[rank < k]


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


def _intersect(a, b):
    """Overlap of two table-plane extents (x0, x1, y0, y1), or None where they do not overlap."""
    e = (max(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), min(a[3], b[3]))
    return e if e[1] > e[0] and e[3] > e[2] else None


def searched_states(model: PreparedModel, resting_states=None, min_state_probability: float = 0.1) -> list[int]:
    """The resting states searched: ``resting_states`` if given, else the distinct ones that are the
    first, at least ``min_state_probability`` likely, or stand the part on its CAD z axis."""
    if resting_states is not None:
        return list(resting_states)
    return [i for i, s in enumerate(model.resting_states)
            if s.same_as < 0 and (i == 0 or s.probability >= min_state_probability or s.cad_axis)]


def search_planes(height_offsets_mm) -> list[tuple[float, tuple | None]]:
    """``LocateOptions.height_offsets_mm`` as (height mm, table-plane extent (x0, x1, y0, y1) to search
    there, or None: the whole table): an entry is a height or such a pair."""
    return [(float(h[0]), h[1]) if isinstance(h, tuple) else (float(h), None) for h in height_offsets_mm]


def centre_extent(table_extent_xy, diameter_mm: float):
    """Where a part's centre is searched (x0, x1, y0, y1 mm, table frame): the table top
    ``table_extent_xy`` grown by half the part's size (it may overhang); None: unbounded."""
    if table_extent_xy is None:
        return None
    half = 0.5 * float(diameter_mm)
    x0, x1, y0, y1 = map(float, table_extent_xy)
    return (x0 - half, x1 + half, y0 - half, y1 + half)


def find_starts(eimg: EdgeImage, K, dist, T_cam_table, model: PreparedModel, *, height_offsets_mm=(0.0,),
            resting_states=None, min_state_probability: float = 0.1, n_starts: int = 6, n_planar: int = 10,
            max_edges: int = 60000, rng=None, timings: dict | None = None, table_extent_xy=None,
            n_coarse: int = 40, coarse_step_max_mm: float = COARSE_STEP_MAX_MM, turn_maxima: int = 0,
            self_occlusion: bool = False, threads: int = SEARCH_THREADS):
    """Stages 1 and 2: starts from the plane search, aligned in the table plane, best first.
    ``table_extent_xy`` (x0, x1, y0, y1 mm): where the part's centre can be (the table and a margin);
    the floor and the machine's walls in the background are not searched. ``threads``: resting
    states searched at the same time (:data:`SEARCH_THREADS`); the starts do not depend on it.
    Returns (hypotheses, px_per_mm) or the reason (str) why there are none."""
    timings = {} if timings is None else timings
    memo = ("search", id(model), T_cam_table.tobytes(), tuple(height_offsets_mm),
            None if resting_states is None else tuple(resting_states), min_state_probability, n_starts, n_planar,
            n_coarse, coarse_step_max_mm, turn_maxima, self_occlusion,
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
    r0, r1 = rays.r0, rays.r1
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
    states = searched_states(model, resting_states, min_state_probability)
    hyps: list[Hyp] = []
    scorer = _image_scorer(eimg, K, dist, T_cam_table)
    b_px = coarse_cell_mm(model.diameter_mm, coarse_step_max_mm) / max(px_mm, 1e-9)
    scorer_wide = _image_scorer(eimg, K, dist, T_cam_table, tau_px=float(np.clip(1.2 * b_px, 3.0, 20.0)))
    scorer_mid = _image_scorer(eimg, K, dist, T_cam_table, tau_px=float(np.clip(0.6 * b_px, 2.5, 10.0)))
    planes = []
    for h, ext in search_planes(height_offsets_mm):
        ext = extent if ext is None else _intersect(ext, extent)
        if ext is not None:
            planes.append((float(h), ext))
    # one plane per resting state (recognition at the table's height): no spectra kept for a next
    # plane that does not come; kept, every state's were fresh memory, given back to the system and
    # faulted in again by the next (measured: 218 000 page faults per image with 20 models, 58 000 without)
    keep_spectra = len(planes) > 1
    nearest_edge_maps(eimg)             # made once, before the states' threads look it up

    def state_hyps(st: int) -> list[Hyp]:
        # a state's planes share its template's spectra, kept here: states searched at the same time
        # do not take each other's (and a state's are given back when it is done)
        spectra: dict = {}
        return [hyp for h, ext in planes
                for hyp in _plane_search(model, st, h, rays, C, ext, n_starts, px_mm=px_mm, n_coarse=n_coarse,
                                         image_score=scorer, cache=spectra, image_score_wide=scorer_wide,
                                         image_score_mid=scorer_mid, coarse_step_max_mm=coarse_step_max_mm,
                                         keep_spectra=keep_spectra, turn_maxima=turn_maxima,
                                         self_occlusion=self_occlusion)]

    if threads > 1 and len(states) > 1:
        with ThreadPoolExecutor(min(threads, len(states))) as pool:
            for got in pool.map(state_hyps, states):      # in the states' order: the same starts
                hyps += got
    else:
        for st in states:
            hyps += state_hyps(st)
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
    sub_coarse = sample_subset(model, px_per_mm, 4.0, 400)
    for h in hyps:
        planar_fit(eimg, model, h, T_cam_table, K, dist, sub_coarse)
    hyps.sort(key=lambda h: -h.score)
    timings["planar_fit"] = (time.perf_counter() - t) * 1e3
    eimg.cache[memo] = (hyps, px_per_mm)
    return hyps, px_per_mm



def turned_over(model: PreparedModel, T_table_obj: np.ndarray) -> list[np.ndarray]:
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


def _start_template(model: PreparedModel, state: int, T0: np.ndarray):
    """The start as a turn about the table normal and a shift (M, theta0) and a template of at most
    150 model edge samples in the resting frame at the start's height (P, D, weights, and what tells
    which of them show: :func:`edge_faces_of`); whether the part is round about the table normal."""
    rs = model.resting_states[state]
    M = T0 @ inv(rs.T_rest_obj)
    th0 = float(np.arctan2(M[1, 0], M[0, 0]))
    P = transform_points(rs.T_rest_obj, model.samples_obj) + np.array([0.0, 0.0, M[2, 3]])
    D = model.sample_dir_obj @ rs.T_rest_obj[:3, :3].T
    sel = _spread_picks(model.edge_feature[model.sample_edge], 150)
    round_part = (model.continuous_axis_obj is not None and
                  abs((rs.T_rest_obj[:3, :3] @ model.continuous_axis_obj)[2]) > 0.999)
    return M, th0, P[sel], D[sel], np.ones(len(sel)), edge_faces_of(model, rs.T_rest_obj, sel), round_part


def _grid_scores(scorer, x0: float, y0: float, th0: float, capture_mm: float, step_mm: float,
                 capture_rad: float, step_rad: float, P, D, w, faces, round_part: bool):
    """Scores of every (x, y, theta) on a grid about (x0, y0, th0): arrays hx, hy, ht, score."""
    g = np.arange(-capture_mm, capture_mm + 1e-9, step_mm)
    gt = np.array([0.0]) if round_part else np.arange(-capture_rad, capture_rad + 1e-9, step_rad)
    DX, DY, DT = np.meshgrid(g, g, gt, indexing="ij")
    hx, hy, ht = x0 + DX.ravel(), y0 + DY.ravel(), th0 + DT.ravel()
    sc = np.concatenate([scorer(hx[i:i + 2000], hy[i:i + 2000], ht[i:i + 2000], P, D, w, normals=faces)
                         for i in range(0, len(hx), 2000)])
    return hx, hy, ht, sc


def _planar_pose(state_T_rest: np.ndarray, x: float, y: float, th: float, z: float) -> np.ndarray:
    c1, s1 = np.cos(th), np.sin(th)
    return make_pose(np.array([[c1, -s1, 0], [s1, c1, 0], [0, 0, 1.0]]), [x, y, z]) @ state_T_rest


def _state_of(model: PreparedModel, T0: np.ndarray) -> int:
    """The resting state whose table normal the pose matches best."""
    ups = [float((T0[:3, :3] @ (inv(r.T_rest_obj)[:3, :3] @ np.array([0.0, 0.0, 1.0])))[2])
           for r in model.resting_states]
    return int(np.argmax(ups))


def starts_from_poses(model: PreparedModel, start_poses, T_cam_table, K, dist, eimg: EdgeImage,
                      capture_mm: float = 30.0, capture_deg: float = 8.0, n_peaks: int = 3):
    """Starts given by someone who knows roughly where the part is ("refine from here").

    Each start is taken in the resting state whose table normal it matches best, then searched
    locally in the table plane (x, y within ``capture_mm``, rotation within ``capture_deg``, scored
    in the image as in the fine stage of the plane search) and aligned: an operator's drag or nudge
    rarely lands within the few pixels the least-squares fit converges from. The start itself stays
    a candidate, so a start that is already right cannot be talked out of it.
    Returns (hypotheses best first, px_per_mm) or the reason (str) why there are none."""
    starts = [(_state_of(model, T0), T0) for T0 in (check_pose(T, "start pose T_table_obj") for T in start_poses)]
    if not starts:
        return "no start pose given"
    z = float(transform_points(T_cam_table, starts[0][1][:3, 3][None])[0, 2])
    px_per_mm = K[0, 0] / max(z, 1.0)
    scorer = _image_scorer(eimg, K, dist, T_cam_table, tau_px=3.0)
    sub_coarse = sample_subset(model, px_per_mm, 4.0, 400)
    hyps: list[Hyp] = []
    for state, T0 in starts:
        M, th0, P, D, w, faces, round_part = _start_template(model, state, T0)
        step = 2.5 / px_per_mm                 # within the scorer's reach of 3 px
        dth = np.radians(min(2.0, np.degrees(2.5 / (px_per_mm * max(0.5 * model.diameter_mm, 1.0)))))
        hx, hy, ht, sc = _grid_scores(scorer, M[0, 3], M[1, 3], th0, capture_mm, max(step, capture_mm / 25),
                                      np.radians(capture_deg), dth, P, D, w, faces, round_part)
        order = np.argsort(-sc)
        keep = _nms(hx[order], hy[order], ht[order], max(0.2 * model.diameter_mm, 3 * step),
                    np.radians(15.0), n_peaks)
        for i in order[keep]:
            T = _planar_pose(model.resting_states[state].T_rest_obj, hx[i], hy[i], ht[i], M[2, 3])
            hyps.append(planar_fit(eimg, model, Hyp(state=state, T_table_obj=T, votes=float(sc[i])),
                                   T_cam_table, K, dist, sub_coarse))
        hyps.append(planar_fit(eimg, model, Hyp(state=state, T_table_obj=T0, votes=0.0),
                               T_cam_table, K, dist, sub_coarse))
    hyps.sort(key=lambda h: -h.score)
    return hyps, px_per_mm


def settle_start(model: PreparedModel, h: Hyp, T_cam_table, K, dist, eimg: EdgeImage, *,
                 capture_mm: float, capture_deg: float, n_steps: int = 6) -> Hyp:
    """A start searched once more around itself, coarse to fine, and aligned in the table plane;
    the better aligned of it and the start (by the planar fit's score).

    Pass 1 scores a grid of ``2 n_steps + 1`` values per axis over ``capture_mm`` and ``capture_deg``
    with a scorer as wide as its step; pass 2 a grid as fine as the 3 px scorer reaches over one step
    of pass 1 around its best. About 2 x 13^3 poses, whatever the part's size in the image."""
    state, T0 = h.state, h.T_table_obj
    z = float(transform_points(T_cam_table, T0[:3, 3][None])[0, 2])
    px_per_mm = K[0, 0] / max(z, 1.0)
    M, th0, P, D, w, faces, round_part = _start_template(model, state, T0)
    fine = 2.5 / px_per_mm
    dth_fine = np.radians(min(2.0, np.degrees(2.5 / (px_per_mm * max(0.5 * model.diameter_mm, 1.0)))))
    x, y, th = M[0, 3], M[1, 3], th0
    cap, cap_t = capture_mm, np.radians(capture_deg)
    for _ in range(2):
        step, dth = max(fine, cap / n_steps), max(dth_fine, cap_t / n_steps)
        scorer = _image_scorer(eimg, K, dist, T_cam_table, tau_px=float(np.clip(step * px_per_mm, 3.0, 12.0)))
        hx, hy, ht, sc = _grid_scores(scorer, x, y, th, cap, step, cap_t, dth, P, D, w, faces, round_part)
        i = int(np.argmax(sc))
        x, y, th = hx[i], hy[i], ht[i]
        cap, cap_t = step, dth
    sub_coarse = sample_subset(model, px_per_mm, 4.0, 400)
    T = _planar_pose(model.resting_states[state].T_rest_obj, x, y, th, M[2, 3])
    settled = planar_fit(eimg, model, Hyp(state=state, T_table_obj=T, votes=h.votes, height_mm=h.height_mm),
                         T_cam_table, K, dist, sub_coarse)
    return settled if settled.score > h.score else h
