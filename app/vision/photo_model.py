"""Objects known from photographs instead of CAD: a 2.5-D edge template in the table plane.

A fixture, clamp or repeat part without a CAD model is taught from the machine's own camera. With
the table located by its markers (``T_cam_table``), every picture is *rectified* onto the plane
``z = height`` of the table frame: the plane's homography ``K [r1 r2 (z r3 + t)]`` composed with the
lens model, so one rectified pixel is a fixed square of that plane in millimetres
(:func:`rectify`; without distortion the same warp is :func:`cv2.warpPerspective`). Seen so, the
object's top face keeps its true shape and size from any camera pose, while its side walls, its
shadow and the table's own edges (all below the plane) do not line up between views.

* :func:`teach` makes a :class:`PhotoModel` from one or more pictures of the object where it lies:
  the edges of its top face (subpixel, mm, with their normals) in an object frame whose origin is the
  outline's centroid on the table (z = 0) and whose axes are the table's at teaching, the outline and
  its holes (for a 2.5-D mesh), its symmetries, and how the teach picture maps to the table. Further
  pictures (the object moved or turned, the camera anywhere) keep only the edges most of them show;
  of the edges the template keeps those that border the top face (its outline, hole rims).
* :func:`measure_height` finds the top face's height from two pictures taken from different camera
  poses: the plane where the rectified edges of both coincide (a plane sweep).
* :func:`locate` finds a taught object in a later picture: an oriented chamfer search over x, y and
  the turn about table z on a coarse rectification (distance transforms per edge direction,
  correlated with the template by :func:`cv2.filter2D`), then, for the best few starts, a
  least-squares fit (scipy) of the template's edges to subpixel edges found along their normals on a
  fine rectification, its 1-sigma (:func:`_sigma`) from the fit's Jacobian with the cluster-robust
  inflation for errors shared along an edge (as the CAD engine's, :mod:`app.vision.object_pose.uncertainty`,
  with its calibrated :data:`SIGMA_SCALE`), the table-pose error of the search picture and of the
  teach picture propagated through the fit (:func:`table_sensitivity`), and the view-dependent edge
  bias of both pictures (:data:`EDGE_BIAS_PX`); and the verification: supported share, edges inside the
  outline that the model does not have, rival poses, distinctiveness. It answers with the engine's
  :class:`~app.vision.object_pose.results.ObjectPose` or :class:`ObjectFailure`.
* :func:`recognise` chooses among several photo models at the same place; look-alikes (two plates
  that differ by one hole) are told apart by the edges in which they differ
  (:func:`lookalike_evidence`), and refused when those edges do not decide.

Frames and units: docs/design.md (``T_a_b``, mm, degrees at the boundary, radians inside). The
object is taken to rest on the table top (z = 0) with its top face at ``height_mm``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import least_squares

from app.geometry.model_edges import (
    PreparedModel,
    project_points_px,
    visible_edge_samples,
)
from app.geometry.transforms import inv, make_pose, transform_points
from app.vision.object_pose.results import ObjectFailure, ObjectPose
from app.vision.object_pose.uncertainty import (
    CONTACT_SIGMA_DEG,
    CONTACT_SIGMA_MM,
    SIGMA_SCALE,
)

FINE_MM_PER_PX = 0.25       # rectification of teaching and of the final fit
SUPPORT_MM = 0.4            # a template point is supported by an image edge this close (along its normal)
EXPLAINED_MM = 0.7          # an image edge inside the outline this close to a template point is explained
TEMPLATE_SPACING_MM = 0.5   # one template point per this square
CLUSTER_MM = 10.0           # template points in one such square share their errors (sigma's clusters)
# Edge bias (camera px) common to a picture's whole outline: where a top face's edge is found depends
# on the view (blur mixing the side wall or the table below into the edge's profile, the perspective of
# the rounded corner), so the template of the teach picture and the edges of a search picture are both
# displaced by a fraction of a camera pixel, the same way all along the outline (it does not average
# out over the edges). Its size is the one constant calibrated for photo models: fitted on the first
# half of benchmarks/photo_model.py's placements (BENCHMARKS.md#photo-model), checked on the second.
EDGE_BIAS_PX = 0.054


# ------------------------------------------------------------------------------------------ the plane grid
@dataclass(frozen=True)
class PlaneGrid:
    """A square pixel grid on the table plane ``z = z_mm`` (table frame): pixel (u, v) is table point
    ``(x0_mm + u * mm_per_px, y0_mm + v * mm_per_px, z_mm)`` (u along table x, v along table y)."""

    x0_mm: float
    y0_mm: float
    mm_per_px: float
    width: int
    height: int
    z_mm: float = 0.0

    @staticmethod
    def around(x_lo: float, x_hi: float, y_lo: float, y_hi: float, mm_per_px: float, z_mm: float) -> PlaneGrid:
        """The grid covering the box [x_lo, x_hi] x [y_lo, y_hi] (mm) at ``mm_per_px``."""
        w = int(np.ceil((x_hi - x_lo) / mm_per_px)) + 1
        h = int(np.ceil((y_hi - y_lo) / mm_per_px)) + 1
        return PlaneGrid(float(x_lo), float(y_lo), float(mm_per_px), max(w, 2), max(h, 2), float(z_mm))

    def to_mm(self, uv: np.ndarray) -> np.ndarray:
        """Grid pixels (N, 2) -> table x, y (N, 2), mm."""
        return np.asarray(uv, float) * self.mm_per_px + [self.x0_mm, self.y0_mm]

    def to_px(self, xy: np.ndarray) -> np.ndarray:
        """Table x, y (N, 2), mm -> grid pixels (N, 2)."""
        return (np.asarray(xy, float) - [self.x0_mm, self.y0_mm]) / self.mm_per_px

    def to_dict(self) -> dict:
        return {"x0_mm": self.x0_mm, "y0_mm": self.y0_mm, "mm_per_px": self.mm_per_px, "width": self.width,
                "height": self.height, "z_mm": self.z_mm}


def plane_homography(K: np.ndarray, T_cam_table: np.ndarray, grid: PlaneGrid) -> np.ndarray:
    """3x3 homography from grid pixels (u, v, 1) to ideal (undistorted) image pixels: the plane
    ``z = grid.z_mm`` of the table seen by the camera, ``K [r1 r2 (z r3 + t)] A`` with ``A`` the grid."""
    T = np.asarray(T_cam_table, float)
    H_plane = np.asarray(K, float) @ np.column_stack([T[:3, 0], T[:3, 1], grid.z_mm * T[:3, 2] + T[:3, 3]])
    A = np.array([[grid.mm_per_px, 0, grid.x0_mm], [0, grid.mm_per_px, grid.y0_mm], [0, 0, 1.0]])
    return H_plane @ A


def _maps(K, dist, T_cam_table, grid: PlaneGrid) -> tuple[np.ndarray, np.ndarray]:
    """Where each grid pixel is in the (distorted) camera image: float32 maps for :func:`cv2.remap`."""
    uu, vv = np.meshgrid(np.arange(grid.width, dtype=float), np.arange(grid.height, dtype=float))
    xy = grid.to_mm(np.stack([uu.ravel(), vv.ravel()], axis=1))
    P = transform_points(np.asarray(T_cam_table, float), np.column_stack([xy, np.full(len(xy), grid.z_mm)]))
    uv = project_points_px(P, K, dist)
    uv = np.where(np.isfinite(uv), uv, -1e6)
    return (uv[:, 0].reshape(grid.height, grid.width).astype(np.float32),
            uv[:, 1].reshape(grid.height, grid.width).astype(np.float32))


def rectify(image: np.ndarray, K: np.ndarray, dist, T_cam_table: np.ndarray, grid: PlaneGrid,
            mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The picture seen on the table plane ``z = grid.z_mm``.

    image : (H, W) grey or (H, W, 3) BGR uint8 as taken (distorted); K (3, 3) px; dist OpenCV's
    mask : optional (H, W) uint8 camera-image mask carried along (nearest neighbour)
    Returns (rectified float32 grey, valid uint8 (255 where the grid point is inside the picture),
    rectified mask or None). Without lens distortion this is :func:`cv2.warpPerspective` through
    :func:`plane_homography`; with distortion the same homography is composed with the lens model
    into one :func:`cv2.remap` (one interpolation either way, bicubic)."""
    img = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    img = img.astype(np.float32)
    d = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    size = (grid.width, grid.height)
    ones = np.full(img.shape, 255, np.uint8)
    if not np.any(d):
        Hm = plane_homography(K, T_cam_table, grid)
        flags = cv2.WARP_INVERSE_MAP
        out = cv2.warpPerspective(img, Hm, size, flags=cv2.INTER_CUBIC | flags, borderMode=cv2.BORDER_REPLICATE)
        valid = cv2.warpPerspective(ones, Hm, size, flags=cv2.INTER_NEAREST | flags, borderValue=0)
        m = None if mask is None else cv2.warpPerspective(mask, Hm, size, flags=cv2.INTER_NEAREST | flags,
                                                          borderValue=0)
        return out, valid, m
    mx, my = _maps(K, d, T_cam_table, grid)
    out = cv2.remap(img, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
    valid = cv2.remap(ones, mx, my, cv2.INTER_NEAREST, borderValue=0)
    m = None if mask is None else cv2.remap(mask, mx, my, cv2.INTER_NEAREST, borderValue=0)
    return out, valid, m


def camera_mm_per_px(K: np.ndarray, T_cam_table: np.ndarray, xy_mm: np.ndarray, z_mm: float) -> float:
    """Size (mm) on the plane ``z`` at table point ``xy_mm`` of one camera pixel (geometric mean)."""
    grid = PlaneGrid(float(xy_mm[0]), float(xy_mm[1]), 1.0, 2, 2, z_mm)
    Hm = plane_homography(K, T_cam_table, grid)
    p = Hm @ np.array([0.0, 0.0, 1.0])
    J = (Hm[:2, :2] * p[2] - np.outer(p[:2], Hm[2, :2])) / p[2] ** 2   # d(image px) / d(mm)
    return float(1.0 / np.sqrt(abs(np.linalg.det(J))))


# ------------------------------------------------------------------------------------------ edges
@dataclass(frozen=True, eq=False)
class PlaneEdges:
    """Edges of a rectified picture: subpixel positions (grid px), their gradient direction (rad) and
    strength, the Canny map, the smoothed gradient images and the valid area."""

    uv: np.ndarray
    angle: np.ndarray
    mag: np.ndarray
    canny: np.ndarray
    gx: np.ndarray
    gy: np.ndarray
    threshold: float
    valid: np.ndarray


def plane_edges(rect: np.ndarray, valid: np.ndarray, ignore: np.ndarray | None = None,
                smooth_px: float = 1.0) -> PlaneEdges:
    """Canny edges of a rectified picture with subpixel positions (parabola through the gradient
    magnitude across the edge). Thresholds follow the image noise (MAD), as the engine's
    :func:`~app.vision.object_pose.edge_image.prepare_image`. Edges within 3 px of the picture's
    border or of ``ignore`` (uint8, > 0: edges known to be something else) are dropped."""
    sm = cv2.GaussianBlur(rect, (0, 0), smooth_px)
    gx = cv2.Sobel(sm, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(sm, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    mag = np.hypot(gx, gy)
    inside = cv2.erode(valid, np.ones((7, 7), np.uint8)) > 0
    noise = float(1.4826 * np.median(mag[inside])) + 1e-3 if inside.any() else 1.0
    lo, hi = max(1.0, 3.0 * noise), max(2.5, 7.0 * noise)
    s = 8.0  # Canny on the Sobel scale
    canny = cv2.Canny(np.clip(np.round(gx * s), -32767, 32767).astype(np.int16),
                      np.clip(np.round(gy * s), -32767, 32767).astype(np.int16), lo * s, hi * s, L2gradient=True)
    keep = inside
    if ignore is not None and ignore.any():
        keep = keep & ~_explained_by(ignore, np.arctan2(gy, gx))
    canny = np.where(keep, canny, 0).astype(np.uint8)
    vv, uu = np.nonzero(canny)
    ang = np.arctan2(gy[vv, uu], gx[vv, uu])
    n = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    base = np.stack([uu, vv], axis=1).astype(np.float32)
    m0 = mag[vv, uu]
    mp = _sample(mag, base + n.astype(np.float32))
    mm = _sample(mag, base - n.astype(np.float32))
    den = mm - 2 * m0 + mp
    off = np.where(den < -1e-6, 0.5 * (mm - mp) / np.where(den < -1e-6, den, -1.0), 0.0)
    uv = base + n * np.clip(off, -0.5, 0.5)[:, None]
    return PlaneEdges(uv, ang, m0, canny, gx, gy, lo, valid)


def _explained_by(ignore: np.ndarray, angle: np.ndarray, max_deg: float = 25.0) -> np.ndarray:
    """Pixels whose edge the known geometry in ``ignore`` explains: inside the (1 px grown) mask and,
    where the mask is a thin band (a table edge drawn a few px wide), running along it (gradient
    within ``max_deg`` of the band's normal, from the mask's structure tensor); inside wide masked
    areas (printed labels) every edge. An object's edge crossing a table edge is so kept."""
    m = cv2.GaussianBlur(ignore.astype(np.float32) / 255.0, (0, 0), 1.0)
    mx = cv2.Sobel(m, cv2.CV_32F, 1, 0, ksize=3)
    my = cv2.Sobel(m, cv2.CV_32F, 0, 1, ksize=3)
    jxx = cv2.GaussianBlur(mx * mx, (0, 0), 2.5)
    jxy = cv2.GaussianBlur(mx * my, (0, 0), 2.5)
    jyy = cv2.GaussianBlur(my * my, (0, 0), 2.5)
    band_normal = 0.5 * np.arctan2(2 * jxy, jxx - jyy)
    strength = np.sqrt((jxx - jyy) ** 2 + 4 * jxy ** 2)
    masked = cv2.dilate(ignore, np.ones((3, 3), np.uint8)) > 0
    along = np.abs(np.sin(angle - band_normal)) < np.sin(np.radians(max_deg))
    band = strength > 0.02
    return masked & (along | ~band)


def _sample(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples of ``img`` at ``uv`` (N, 2) or (N, M, 2) px; outside: 0."""
    uv = np.asarray(uv, np.float32)
    shape = uv.shape[:-1]
    flat = uv.reshape(-1, 2)
    n = len(flat)
    if n == 0:
        return np.zeros(shape, np.float32)
    cols = 1024                       # remap's maps must stay under 32767 rows and columns
    pad = np.full(((n + cols - 1) // cols * cols, 2), -10.0, np.float32)
    pad[:n] = flat
    pad = pad.reshape(-1, cols, 2)
    out = cv2.remap(img, pad[..., 0], pad[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.reshape(-1)[:n].reshape(shape)


# ------------------------------------------------------------------------------------------ the model
@dataclass(frozen=True, eq=False)
class PhotoModel:
    """A taught object: the edges of its top face in its own frame (obj: origin at the outline's
    centroid on the table, z up; axes as the table's when it was taught), mm.

    points_mm (N, 2), normal_rad (N,) gradient direction of each edge point (mod 180 deg matters),
    cluster (N,) int: points in one ``CLUSTER_MM`` square (their errors are shared)
    height_mm : height of the top face above the table
    outline_mm : outer contour of the top face (M, 2); holes_mm : enclosed regions (holes, pockets)
    symmetry_deg : turns about z (other than 0) that map the template onto itself
    T_table_obj_teach : where the object lay when taught (4x4, mm); teach_grid : the stored teach
    picture's :class:`PlaneGrid` (so a click on it gives table, then obj coordinates)
    n_views : pictures that agreed on the edges
    teach_cov : 3x3 covariance (x mm, y mm, theta rad; obj axes) of the template's own placement, from
        the fit of the template to its first picture: every later pose inherits it
    teach_table_cov : 3x3 (obj axes, as ``teach_cov``) of where the obj frame lies on the object because
        of the first picture's table-pose error (the markers put the plane a little off, and the template
        with it): propagated from that picture's table covariance; every later pose inherits it. None
        (a model taught before it was kept): :func:`locate` takes the search picture's own table term
        in its stead
    teach_mm_per_px : size (mm) of one camera pixel of the first picture on the top face at the obj
        origin: the template's edge bias (:data:`EDGE_BIAS_PX`) is that many mm. None (an older model):
        the search picture's
    """

    points_mm: np.ndarray
    normal_rad: np.ndarray
    cluster: np.ndarray
    height_mm: float
    outline_mm: np.ndarray
    holes_mm: tuple = ()
    symmetry_deg: tuple = ()
    T_table_obj_teach: np.ndarray = field(default_factory=lambda: np.eye(4))
    teach_grid: PlaneGrid | None = None
    n_views: int = 1
    teach_cov: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    teach_table_cov: np.ndarray | None = None
    teach_mm_per_px: float | None = None

    @property
    def radius_mm(self) -> float:
        return float(np.max(np.linalg.norm(self.outline_mm, axis=1)))

    @property
    def edge_length_mm(self) -> float:
        """Length of the template's edges (its points are about ``spacing`` apart)."""
        return float(len(self.points_mm) * TEMPLATE_SPACING_MM)

    def to_dict(self) -> dict:
        return {"version": 1, "height_mm": self.height_mm,
                "points_mm": np.round(self.points_mm, 4).tolist(), "normal_rad": np.round(self.normal_rad, 5).tolist(),
                "cluster": self.cluster.astype(int).tolist(), "outline_mm": np.round(self.outline_mm, 3).tolist(),
                "holes_mm": [np.round(h, 3).tolist() for h in self.holes_mm], "symmetry_deg": list(self.symmetry_deg),
                "T_table_obj_teach": np.asarray(self.T_table_obj_teach).tolist(),
                "teach_grid": None if self.teach_grid is None else self.teach_grid.to_dict(), "n_views": self.n_views,
                "teach_cov": np.asarray(self.teach_cov).tolist(),
                "teach_table_cov": None if self.teach_table_cov is None else np.asarray(self.teach_table_cov).tolist(),
                "teach_mm_per_px": self.teach_mm_per_px}

    @staticmethod
    def from_dict(d: dict) -> PhotoModel:
        g = d.get("teach_grid")
        return PhotoModel(points_mm=np.asarray(d["points_mm"], float).reshape(-1, 2),
                          normal_rad=np.asarray(d["normal_rad"], float), cluster=np.asarray(d["cluster"], int),
                          height_mm=float(d["height_mm"]), outline_mm=np.asarray(d["outline_mm"], float).reshape(-1, 2),
                          holes_mm=tuple(np.asarray(h, float).reshape(-1, 2) for h in d.get("holes_mm", [])),
                          symmetry_deg=tuple(float(s) for s in d.get("symmetry_deg", [])),
                          T_table_obj_teach=np.asarray(d.get("T_table_obj_teach", np.eye(4).tolist()), float),
                          teach_grid=PlaneGrid(**g) if g else None, n_views=int(d.get("n_views", 1)),
                          teach_cov=np.asarray(d.get("teach_cov", np.zeros((3, 3)).tolist()), float),
                          teach_table_cov=(None if d.get("teach_table_cov") is None
                                           else np.asarray(d["teach_table_cov"], float).reshape(3, 3)),
                          teach_mm_per_px=None if d.get("teach_mm_per_px") is None else float(d["teach_mm_per_px"]))



@dataclass(frozen=True)
class View:
    """One teach or search picture with what locates it: image as taken, intrinsics, the table pose,
    an optional camera-image mask (uint8, > 0) of edges known to be something else, and the table
    pose's covariance (rotation about the table axes rad, shift along them mm at
    ``table_centroid_mm``: :class:`~app.vision.fiducials.TablePose`'s convention). Without it the
    table pose is taken as exact (synthetic tests with the true pose)."""

    image: np.ndarray
    K: np.ndarray
    dist: np.ndarray
    T_cam_table: np.ndarray
    ignore: np.ndarray | None = None
    table_cov: np.ndarray | None = None          # (6, 6) of T_cam_table as locate_table's TablePose.covariance
    table_centroid_mm: np.ndarray | None = None  # its centroid_table_mm (where that covariance's shift is)

    @staticmethod
    def of(image: np.ndarray, K: np.ndarray, dist, table, ignore: np.ndarray | None = None) -> View:
        """A view located by :func:`app.vision.fiducials.locate_table`'s ``TablePose`` (its pose and its
        covariance, so that the pose's error enters every sigma found in this picture)."""
        return View(image, K, dist, table.T_cam_table, ignore, np.asarray(table.covariance, float),
                    np.asarray(table.centroid_table_mm, float))


class TeachError(ValueError):
    """Teaching failed; the message says why in words for the admin."""


def known_edge_mask(shape: tuple[int, int], K, dist, T_cam_table, known: list[tuple[PreparedModel, np.ndarray]] = (),
                    regions_table: list = (), width_px: float = 1.5) -> np.ndarray:
    """Camera-image mask (uint8) of edges that known geometry explains: the visible edges of
    ``known`` models (pairs of prepared model and ``T_table_model``, e.g. the table's slots and
    border) drawn ``width_px`` wide, and ``regions_table`` polygons (table frame, (N, 3) mm, e.g. the
    printed marker labels) filled. The same geometry as the engine's
    :func:`~app.vision.object_pose.edge_image.mask_known_edges` and ``mask_table_regions``."""
    H, W = shape
    K = np.asarray(K, float)
    d = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    T_cam_table = np.asarray(T_cam_table, float)
    mask = np.zeros((H, W), np.uint8)
    for model, T_table_model in known:
        es = visible_edge_samples(model, T_cam_table @ np.asarray(T_table_model, float), K, d, W, H,
                                  max_buffer_px=1200)
        for u, v in np.rint(es.uv_px * 4).astype(np.int64):
            cv2.circle(mask, (int(u), int(v)), round(width_px * 4), 255, -1, shift=2)
    for poly in regions_table:
        P = transform_points(T_cam_table, np.asarray(poly, float).reshape(-1, 3))
        if np.any(P[:, 2] <= 1.0):
            continue
        uv = project_points_px(P, K, d)
        cv2.fillPoly(mask, [np.rint(uv * 4).astype(np.int32)], 255, shift=2)
    return mask


def _object_blob(edges: PlaneEdges, grid: PlaneGrid, join_mm: float = 3.0) -> np.ndarray:
    """The object in a rectification: the largest area enclosed by edges (gaps up to ``join_mm``
    closed), so that open lines (the table's machining marks, a slot's remains) do not count.
    Returns its filled mask (uint8), grown by ``join_mm``."""
    r = max(1, round(join_mm / grid.mm_per_px))
    sil, outers, _ = _silhouette(edges.canny, r)
    if not outers:
        raise TeachError("no object found on the table: no closed outline besides the table's edges "
                         "(is the whole object in view, and the table's markers?)")
    # the largest body: areas narrower than 10 mm (a strip between two lines) do not count
    k = max(1, round(5.0 / grid.mm_per_px))
    body = cv2.morphologyEx(sil, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1)))
    areas = []
    for c in outers:
        m = np.zeros(sil.shape, np.uint8)
        cv2.fillPoly(m, [np.rint(c).astype(np.int32)], 255)
        areas.append(int(np.count_nonzero(body[m > 0])))
    best = outers[int(np.argmax(areas))]
    if max(areas) * grid.mm_per_px ** 2 < 100.0:
        raise TeachError("no object found on the table: the largest closed outline is under 1 cm² "
                         "(or narrower than 10 mm)")
    blob = np.zeros(edges.canny.shape, np.uint8)
    cv2.fillPoly(blob, [np.rint(best).astype(np.int32)], 255)
    return cv2.dilate(blob, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))


def _silhouette(canny: np.ndarray, close_px: int) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """Areas closed by edge loops with gaps up to ``2 close_px``: (filled mask, outer contours,
    enclosed regions) in grid px. The edges are thickened by ``close_px`` (which bridges the gaps),
    the outside flooded, and the filled area thinned back by ``close_px``."""
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * close_px + 1, 2 * close_px + 1))
    thick = cv2.dilate(canny, k)
    H, W = thick.shape
    outside = np.pad(thick, 1)
    cv2.floodFill(outside, np.zeros((H + 4, W + 4), np.uint8), (0, 0), 128)
    sil = cv2.erode(np.where(outside[1:-1, 1:-1] == 128, 0, 255).astype(np.uint8), k)
    outer, _ = cv2.findContours(sil, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    free = np.where((sil > 0) & (thick == 0), 255, 0).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(free, connectivity=4)
    holes = []
    if n > 2:
        face = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        for i in range(1, n):
            if i == face or stats[i, cv2.CC_STAT_AREA] < 4:
                continue
            region = cv2.dilate(np.where(lab == i, 255, 0).astype(np.uint8), k)
            cs, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            holes += [c[:, 0, :].astype(float) for c in cs if len(c) >= 3]
    return sil, [c[:, 0, :].astype(float) for c in outer if len(c) >= 3], holes


def _thin(uv_mm: np.ndarray, spacing: float) -> np.ndarray:
    """Indices keeping one point per ``spacing`` square (the strongest first is not needed: any)."""
    cells = np.floor(uv_mm / spacing).astype(np.int64)
    _, idx = np.unique(cells, axis=0, return_index=True)
    return np.sort(idx)


def teach(views: list[View], height_mm: float, *, region_mm: tuple[float, float, float, float] | None = None,
          table_xy_mm: tuple[float, float, float, float] = (0.0, 800.0, 0.0, 400.0),
          min_agree: float = 0.5) -> tuple[PhotoModel, np.ndarray]:
    """A photo model from pictures of the object lying on the table (all of one placement).

    views : the pictures; the first shows where the obj frame is. The others may show the object moved
        or turned (better: turned, so that side walls and shadow fall elsewhere) and the camera anywhere
    height_mm : height of the object's top face above the table
    region_mm : (x_lo, x_hi, y_lo, y_hi) table box that holds the object; None: found as the largest
        group of edges on the table (``table_xy_mm``) besides those the views' ``ignore`` masks explain
    min_agree : share of the other views that must show a template edge for it to be kept
    Returns (model, the first view rectified onto the top face (uint8, the teach picture; its grid is
    ``model.teach_grid``)). Raises :class:`TeachError` with the reason.
    """
    if not views:
        raise TeachError("no picture to teach from")
    if not (0.5 <= float(height_mm) <= 1000.0):
        raise TeachError(f"height {height_mm} mm is not plausible: give the top face's height above the table, "
                         "0.5 to 1000 mm")
    h = float(height_mm)
    v0 = views[0]
    if region_mm is not None:
        x_lo, x_hi, y_lo, y_hi = (float(v) for v in region_mm)
        if not (x_hi - x_lo >= 5 and y_hi - y_lo >= 5 and (x_hi - x_lo) * (y_hi - y_lo) <= 1.0e6
                and max(abs(x_lo), abs(x_hi), abs(y_lo), abs(y_hi)) <= 10_000):
            raise TeachError(f"region {list(region_mm)} mm: give [x_lo, x_hi, y_lo, y_hi] on the table, each side "
                             "5 mm or more, at most 1 m², within 10 m of the table origin")
    # the outline on a 1 mm grid: the largest area closed by edges (gaps up to 6 mm: where the
    # table's own edges, masked out, cross the object's)
    box = region_mm if region_mm is not None else table_xy_mm
    g = PlaneGrid.around(box[0], box[1], box[2], box[3], 1.0, h)
    rect, valid, ign = rectify(v0.image, v0.K, v0.dist, v0.T_cam_table, g, v0.ignore)
    blob = _object_blob(plane_edges(rect, valid, ign, smooth_px=0.8), g, join_mm=6.0)
    outers, _ = cv2.findContours(cv2.erode(blob, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (13, 13))),
                                 cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    outer = max(outers, key=cv2.contourArea)[:, 0, :].astype(float)
    m = cv2.moments(outer.astype(np.float32))
    c_mm = g.to_mm(np.array([[m["m10"] / m["m00"], m["m01"] / m["m00"]]]))[0]
    outline_table = g.to_mm(outer)
    lo, hi = outline_table.min(axis=0) - 6.0, outline_table.max(axis=0) + 6.0
    x_lo, x_hi, y_lo, y_hi = lo[0], hi[0], lo[1], hi[1]
    if (x_hi - x_lo) * (y_hi - y_lo) > 1.0e6:
        raise TeachError(f"the object found is {x_hi - x_lo:.0f} x {y_hi - y_lo:.0f} mm: larger than 1 m²; "
                         "give the region that holds it")
    grid = PlaneGrid.around(x_lo, x_hi, y_lo, y_hi, FINE_MM_PER_PX, h)
    rect0, valid, ign = rectify(v0.image, v0.K, v0.dist, v0.T_cam_table, grid, v0.ignore)
    if np.mean(valid > 0) < 0.9:
        raise TeachError("the object is not wholly in the picture")
    e0 = plane_edges(rect0, valid, ign, smooth_px=1.5)
    # the template: the edges inside the outline grown by 2 mm; holes: areas they enclose
    sil = np.zeros((grid.height, grid.width), np.uint8)
    cv2.fillPoly(sil, [np.rint(grid.to_px(outline_table) * 4).astype(np.int32)], 255, shift=2)
    r2 = round(2.0 / FINE_MM_PER_PX)
    grown = cv2.dilate(sil, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r2 + 1, 2 * r2 + 1)))
    inner = cv2.erode(sil, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r2 + 1, 2 * r2 + 1)))
    _, _, holes = _silhouette(np.where(inner > 0, e0.canny, 0).astype(np.uint8), round(1.0 / FINE_MM_PER_PX))
    iu = np.clip(np.rint(e0.uv).astype(int), 0, [grid.width - 1, grid.height - 1])
    keep = grown[iu[:, 1], iu[:, 0]] > 0
    uv, ang = e0.uv[keep], e0.angle[keep]
    pts = grid.to_mm(uv) - c_mm
    sel = _thin(pts, TEMPLATE_SPACING_MM)
    pts, ang = pts[sel], ang[sel]
    if len(pts) < 40:
        raise TeachError(f"only {len(pts) * TEMPLATE_SPACING_MM:.0f} mm of edges on the object: too few to locate it")
    outline = outline_table - c_mm
    model = PhotoModel(points_mm=pts, normal_rad=ang, cluster=_clusters(pts), height_mm=h, outline_mm=outline,
                       holes_mm=tuple(grid.to_mm(hh) - c_mm for hh in holes),
                       T_table_obj_teach=make_pose(t=[c_mm[0], c_mm[1], 0.0]), teach_grid=grid, n_views=1)
    if len(views) > 1:
        model = _agree(model, views[1:], table_xy_mm, min_agree)
    model = _face(model)
    fit = _refine(v0, model, (float(c_mm[0]), float(c_mm[1]), 0.0))
    model = PhotoModel(**{**model.__dict__, "teach_cov": SIGMA_SCALE ** 2 * _fit_cov(fit, model),
                          "teach_table_cov": _table_term(fit, model, v0),
                          "teach_mm_per_px": camera_mm_per_px(v0.K, v0.T_cam_table, c_mm, h)})
    teach_pic = np.clip(rect0, 0, 255).astype(np.uint8)
    return _with_symmetry(model), teach_pic


def _agree(model: PhotoModel, others: list[View], table_xy_mm, min_agree: float) -> PhotoModel:
    """Keep the template's edges that most other pictures show, at their mean position. Each other
    picture may show the object moved or turned (better: turned, so its side walls, shadow and
    reflections fall elsewhere): it is located with the first picture's template first."""
    votes = np.zeros(len(model.points_mm))
    acc = model.points_mm.copy()
    for k, v in enumerate(others, start=2):
        p = locate(v, model, "object", search_xy=table_xy_mm, min_score=0.35, min_margin=0.0,
                   max_unexplained_mm=1e9)
        if not p:
            raise TeachError(f"picture {k}: the object of the first picture is not found in it ({p.reason})")
        x, y = float(p.T_table_obj[0, 3]), float(p.T_table_obj[1, 3])
        t = float(np.arctan2(p.T_table_obj[1, 0], p.T_table_obj[0, 0]))
        fit = _refine_fixed(v, model, (x, y, t))
        ok = fit.found & (np.abs(np.nan_to_num(fit.residual_mm, nan=9.0)) < SUPPORT_MM)
        Q, N = _transform(model, x, y, t)
        seen = Q + np.nan_to_num(fit.residual_mm)[:, None] * N
        votes += ok
        acc[ok] += ((seen - [x, y]) @ _rot(t))[ok]           # back into the obj frame
    keep = votes >= max(1.0, min_agree * len(others))
    if keep.sum() < 40:
        raise TeachError(f"the {len(others) + 1} pictures agree on only {keep.sum() * TEMPLATE_SPACING_MM:.0f} mm of "
                         "edges: is the height right, and is it the same object?")
    pts = acc[keep] / (1 + votes[keep])[:, None]
    return PhotoModel(**{**model.__dict__, "points_mm": pts, "normal_rad": model.normal_rad[keep],
                         "cluster": _clusters(pts), "n_views": len(others) + 1})


def _face(model: PhotoModel) -> PhotoModel:
    """The top face from the template's own edges: the largest area they close (gaps to 4 mm) is the
    face; the template keeps the edges that border it (its outline, the rims of its holes and pockets,
    lines on it), and drops what lies beyond them (inside a hole: its wall and what shows through it;
    beyond the outline: a side wall's foot), which depends on the view. Outline and holes are redrawn
    from the face. Where the edges do not close a face, the model stays as it is."""
    P = model.points_mm
    lo = P.min(axis=0) - 4
    g = PlaneGrid(float(lo[0]), float(lo[1]), 0.25, int((P[:, 0].max() - lo[0] + 4) / 0.25) + 1,
                  int((P[:, 1].max() - lo[1] + 4) / 0.25) + 1)
    img = np.zeros((g.height, g.width), np.uint8)
    ij = np.rint(g.to_px(P)).astype(int)
    img[ij[:, 1], ij[:, 0]] = 255

    def disk(r: int) -> np.ndarray:
        return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))

    thick = cv2.dilate(img, disk(8))
    outside = np.pad(thick, 1)
    cv2.floodFill(outside, np.zeros((g.height + 4, g.width + 4), np.uint8), (0, 0), 128)
    free = ((thick == 0) & (outside[1:-1, 1:-1] != 128)).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(free, connectivity=4)
    if n < 2:
        return model
    face_id = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    face = np.where(lab == face_id, 255, 0).astype(np.uint8)
    area_mm2 = stats[face_id, cv2.CC_STAT_AREA] * g.mm_per_px ** 2
    if area_mm2 < 0.5 * cv2.contourArea(model.outline_mm.astype(np.float32)):
        return model      # the edges do not close the face: keep the outline seen in the picture
    keep = cv2.dilate(face, disk(10))[ij[:, 1], ij[:, 0]] > 0
    outers, _ = cv2.findContours(cv2.dilate(face, disk(8)), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    outer = max(outers, key=cv2.contourArea)[:, 0, :].astype(float)
    body = np.zeros_like(face)
    cv2.fillPoly(body, [np.rint(outer).astype(np.int32)], 255)
    holes_px = cv2.subtract(body, cv2.dilate(face, disk(8)))
    hs, _ = cv2.findContours(cv2.morphologyEx(holes_px, cv2.MORPH_OPEN, disk(2)), cv2.RETR_EXTERNAL,
                             cv2.CHAIN_APPROX_SIMPLE)
    pts = P[keep]
    return PhotoModel(**{**model.__dict__, "points_mm": pts, "normal_rad": model.normal_rad[keep],
                         "cluster": _clusters(pts), "outline_mm": g.to_mm(outer),
                         "holes_mm": tuple(g.to_mm(h[:, 0, :].astype(float)) for h in hs if len(h) >= 3)})


def _clusters(pts: np.ndarray) -> np.ndarray:
    cells = np.floor(pts / CLUSTER_MM).astype(np.int64)
    _, inv_idx = np.unique(cells, axis=0, return_inverse=True)
    return inv_idx.ravel()


def _with_symmetry(model: PhotoModel) -> PhotoModel:
    """The model with the turns about z that map its template onto itself (within 0.5 mm for 95 %)."""
    P = model.points_mm
    lo = P.min(axis=0) - 5
    g = PlaneGrid(float(lo[0]), float(lo[1]), 0.25, int((P[:, 0].max() - lo[0] + 5) / 0.25) + 1,
                  int((P[:, 1].max() - lo[1] + 5) / 0.25) + 1)
    img = np.full((g.height, g.width), 255, np.uint8)
    ij = np.rint(g.to_px(P)).astype(int)
    img[ij[:, 1], ij[:, 0]] = 0
    dmap = cv2.distanceTransform(img, cv2.DIST_L2, 5)
    sym = []
    for deg in range(1, 360):
        t = np.radians(deg)
        R = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
        q = np.rint(g.to_px(P @ R.T)).astype(int)
        ok = (q[:, 0] >= 0) & (q[:, 1] >= 0) & (q[:, 0] < g.width) & (q[:, 1] < g.height)
        if ok.mean() < 0.95:
            continue
        d = dmap[q[ok, 1], q[ok, 0]] * 0.25
        if np.mean(d < 0.5) > 0.95:
            sym.append(float(deg))
    # keep the centre of each run of neighbouring turns (a symmetry shows over a degree or two)
    out, run = [], []
    for s in sym + [1e9]:
        if run and s - run[-1] > 1.5:
            out.append(float(np.round(np.mean(run))))
            run = []
        run.append(s)
    return PhotoModel(**{**model.__dict__, "symmetry_deg": tuple(s for s in out if s < 1e8)})


# ------------------------------------------------------------------------------------------ height from two views
def measure_height(views: list[View], region_mm: tuple[float, float, float, float],
                   z_range_mm: tuple[float, float] = (2.0, 200.0)) -> tuple[float, float]:
    """Height (mm) of an object's top face from two or more pictures of it (one placement) taken from
    different camera poses: the plane ``z`` on which the rectified edges of the views coincide best
    (a plane sweep, 1 mm steps on a 1 mm grid, then 0.1 mm steps on a 0.25 mm grid, inside
    ``region_mm``). Returns (height, the share of edge
    points that coincide there). Raises :class:`TeachError` when the views cannot tell."""
    if len(views) < 2:
        raise TeachError("measuring the height needs two pictures from different camera poses")
    C = [inv(np.asarray(v.T_cam_table, float))[:3, 3] for v in views]
    base = max(np.linalg.norm(c - C[0]) for c in C[1:])
    if base < 50.0:
        raise TeachError(f"the camera moved only {base:.0f} mm between the pictures: too little to measure the "
                         "height (move it 100 mm or more, or give the height)")
    x_lo, x_hi, y_lo, y_hi = region_mm

    def agreement(z: float, res: float) -> tuple[float, float]:
        """(share of view 1's edge points within 2 px of view 2's edges, their mean distance capped at
        1 mm) on the plane z."""
        g = PlaneGrid.around(x_lo, x_hi, y_lo, y_hi, res, z)
        es = []
        for v in views[:2]:
            rect, valid, ign = rectify(v.image, v.K, v.dist, v.T_cam_table, g, v.ignore)
            es.append(plane_edges(rect, valid, ign, smooth_px=1.0))
        dmap = _edge_distance(es[1].canny)
        ij = np.clip(np.rint(es[0].uv).astype(int), 0, [g.width - 1, g.height - 1])
        if len(ij) < 20:
            return 0.0, 1.0
        d = dmap[ij[:, 1], ij[:, 0]]
        return float(np.mean(d < 2.0)), float(np.mean(np.minimum(d * res, 1.0)))

    zs = np.arange(z_range_mm[0], z_range_mm[1] + 1e-9, 1.0)
    # chosen by the mean distance: the share within 2 px saturates over a few millimetres
    z0 = float(zs[int(np.argmin([agreement(z, 1.0)[1] for z in zs]))])
    fine = np.arange(z0 - 1.5, z0 + 1.5001, 0.1)
    fs = [agreement(z, 0.25) for z in fine]
    best = int(np.argmin([f[1] for f in fs]))
    if fs[best][0] < 0.3:
        raise TeachError(f"the pictures agree on no plane (best {fs[best][0]:.0%} of edges at {fine[best]:.1f} mm): "
                         "give the height")
    return float(fine[best]), float(fs[best][0])


# ------------------------------------------------------------------------------------------ locating
def _edge_distance(canny: np.ndarray) -> np.ndarray:
    """Distance (grid px) of every pixel to the nearest edge pixel of a Canny map."""
    return cv2.distanceTransform(np.where(canny > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, 5)


def _rot(t: float) -> np.ndarray:
    return np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])


@dataclass(frozen=True, eq=False)
class _Fit:
    x: float
    y: float
    theta: float
    coverage: float
    residual_mm: np.ndarray      # per template point (NaN: no edge found)
    found: np.ndarray            # per template point: an edge was found along the normal
    J: np.ndarray
    grid: PlaneGrid
    edges: PlaneEdges

    @property
    def edge_dt(self) -> np.ndarray:
        """Distance (grid px) of every grid pixel to the nearest image edge."""
        return _edge_distance(self.edges.canny)


def _coarse_starts(view: View, model: PhotoModel, search_xy: tuple[float, float, float, float],
                   n_starts: int = 3) -> list[tuple[float, float, float, float]]:
    """Oriented edge search: (score, x, y, theta) of the best distinct starts.

    The plane is rectified at ~R/25 mm per pixel. The score of a pose is the mean over the template's
    points of ``w cos(2 (phi - psi))``: ``phi`` the image's gradient direction there, ``psi`` the
    point's (turned by theta), ``w`` the image edge's strength (saturating at the Canny threshold), so
    an edge of the right direction counts +1, across -1, none or random texture about 0, and the sign
    of the contrast does not matter. ``cos 2(phi - psi) = cos 2phi cos 2psi + sin 2phi sin 2psi``
    makes it two correlations per turn (:func:`cv2.filter2D` of the images ``w cos 2phi`` and
    ``w sin 2phi``, slightly blurred for capture range, with kernels holding ``cos 2psi`` and
    ``sin 2psi`` at the points): a distance-free oriented chamfer."""
    R = max(model.radius_mm, float(np.max(np.linalg.norm(model.points_mm, axis=1))), 10.0)
    res = float(np.clip(R / 25.0, 1.0, 3.0))
    x_lo, x_hi, y_lo, y_hi = search_xy
    g = PlaneGrid.around(x_lo, x_hi, y_lo, y_hi, res, model.height_mm)
    rect, valid, ign = rectify(view.image, view.K, view.dist, view.T_cam_table, g, view.ignore)
    e = plane_edges(rect, valid, ign, smooth_px=0.8)
    phi = np.arctan2(e.gy, e.gx)
    w = np.clip(np.hypot(e.gx, e.gy) / e.threshold - 0.5, 0.0, 1.0)
    if ign is not None and ign.any():
        w = np.where(_explained_by(ign, phi), 0.0, w)
    w = (w * (cv2.erode(valid, np.ones((5, 5), np.uint8)) > 0)).astype(np.float32)
    Cimg = cv2.GaussianBlur((w * np.cos(2 * phi)).astype(np.float32), (0, 0), 0.7)
    Simg = cv2.GaussianBlur((w * np.sin(2 * phi)).astype(np.float32), (0, 0), 0.7)
    sel = _thin(model.points_mm, res)
    P, A = model.points_mm[sel], model.normal_rad[sel]
    step = float(np.degrees(0.7 * res / R))
    sym = min([s for s in model.symmetry_deg] + [360.0])
    thetas = np.radians(np.arange(0.0, sym, max(step, 0.5)))
    half = int(np.ceil(R / res)) + 2
    ks = 2 * half + 1
    found = []
    for t in thetas:
        q = np.rint(P @ _rot(t).T / res + half).astype(int)
        kc = np.zeros((ks, ks), np.float32)
        ksn = np.zeros((ks, ks), np.float32)
        np.add.at(kc, (q[:, 1], q[:, 0]), np.cos(2 * (A + t)))
        np.add.at(ksn, (q[:, 1], q[:, 0]), np.sin(2 * (A + t)))
        score = (cv2.filter2D(Cimg, -1, kc, anchor=(half, half), borderType=cv2.BORDER_CONSTANT)
                 + cv2.filter2D(Simg, -1, ksn, anchor=(half, half), borderType=cv2.BORDER_CONSTANT)) / len(P)
        for _ in range(2):
            _, s, _, (u, v) = cv2.minMaxLoc(score)
            xy = g.to_mm(np.array([[u, v]], float))[0]
            found.append((float(s), float(xy[0]), float(xy[1]), float(t)))
            cv2.circle(score, (u, v), max(2, int(0.3 * R / res)), -1.0, -1)
    found.sort(key=lambda f: -f[0])
    out: list[tuple[float, float, float, float]] = []
    for f in found:
        if f[0] < 0.5 * found[0][0]:
            break
        if all(np.hypot(f[1] - o[1], f[2] - o[2]) > 0.3 * R or _angle_gap(f[3], o[3], model) > np.radians(10)
               for o in out):
            out.append(f)
        if len(out) >= n_starts:
            break
    return out


def _angle_gap(a: float, b: float, model: PhotoModel) -> float:
    """Smallest turn (rad) between two angles, counting the model's symmetries as the same."""
    gaps = [abs((a - b - np.radians(s) + np.pi) % (2 * np.pi) - np.pi) for s in (0.0, *model.symmetry_deg)]
    return float(min(gaps))


def _fine_grid(model: PhotoModel, x: float, y: float, margin_mm: float = 8.0) -> PlaneGrid:
    R = model.radius_mm + margin_mm
    return PlaneGrid.around(x - R, x + R, y - R, y + R, FINE_MM_PER_PX, model.height_mm)


def _correspond(e: PlaneEdges, grid: PlaneGrid, Q: np.ndarray, N: np.ndarray, reach_mm: float
                ) -> tuple[np.ndarray, np.ndarray]:
    """Along each normal ``N`` (unit, table axes) from each point ``Q`` (mm): the strongest image edge
    of that direction within ``reach_mm`` (subpixel). Returns (offset mm along N, found)."""
    step = 0.5
    n_s = int(np.ceil(reach_mm / (grid.mm_per_px * step)))
    s = np.arange(-n_s, n_s + 1) * step                          # grid px
    q = grid.to_px(Q)
    pts = q[:, None, :] + s[None, :, None] * N[:, None, :]
    gx, gy = _sample(e.gx, pts), _sample(e.gy, pts)
    along = np.abs(gx * N[:, None, 0] + gy * N[:, None, 1])
    mag = np.hypot(gx, gy) + 1e-9
    score = np.where(along > 0.85 * mag, along, 0.0)
    k = np.argmax(score, axis=1)
    best = score[np.arange(len(k)), k]
    inner = (k > 0) & (k < len(s) - 1)
    kk = np.clip(k, 1, len(s) - 2)
    a, b, c = (along[np.arange(len(k)), kk - 1], along[np.arange(len(k)), kk], along[np.arange(len(k)), kk + 1])
    den = a - 2 * b + c
    off = np.where(den < -1e-9, 0.5 * (a - c) / np.where(den < -1e-9, den, -1.0), 0.0)
    pos = (s[kk] + np.clip(off, -1, 1) * step) * grid.mm_per_px
    found = inner & (best > e.threshold)
    return np.where(found, pos, np.nan), found


def _transform(model: PhotoModel, x: float, y: float, t: float) -> tuple[np.ndarray, np.ndarray]:
    R = _rot(t)
    Q = model.points_mm @ R.T + [x, y]
    a = model.normal_rad + t
    return Q, np.stack([np.cos(a), np.sin(a)], axis=1)


def _refine(view: View, model: PhotoModel, start: tuple[float, float, float]) -> _Fit:
    """Least-squares fit of the template's edges to subpixel image edges along their normals on a
    fine rectification, correspondences found anew with a shrinking reach (ICP, point to line)."""
    x, y, t = start
    grid = _fine_grid(model, x, y)
    rect, valid, ign = rectify(view.image, view.K, view.dist, view.T_cam_table, grid, view.ignore)
    e = plane_edges(rect, valid, ign, smooth_px=1.5)
    P = model.points_mm
    for reach in (4.0, 2.5, 1.5, 1.0, 0.8, 0.8):
        Q, N = _transform(model, x, y, t)
        off, found = _correspond(e, grid, Q, N, reach)
        if found.sum() < 10:
            break
        T = Q[found] + off[found][:, None] * N[found]        # the image edge points
        Pf, Af = P[found], model.normal_rad[found]

        def res(p, Pf=Pf, Af=Af, T=T):
            R = _rot(p[2])
            n = np.stack([np.cos(Af + p[2]), np.sin(Af + p[2])], axis=1)
            return np.einsum("ij,ij->i", n, Pf @ R.T + p[:2] - T)

        sol = least_squares(res, [x, y, t], loss="soft_l1", f_scale=0.25, x_scale=[1.0, 1.0, 0.01])
        x, y, t = (float(v) for v in sol.x)
    Q, N = _transform(model, x, y, t)
    off, found = _correspond(e, grid, Q, N, 0.8)
    # d residual / d (x, y, theta): the normal, and the normal on dR/dtheta p
    J = np.column_stack([N, np.einsum("ij,ij->i", N, (model.points_mm @ _rot(t + np.pi / 2).T))])
    cov = float(np.mean(found & (np.abs(np.nan_to_num(off, nan=9.0)) < SUPPORT_MM)))
    return _Fit(x, y, t, cov, off, found, J, grid, e)


def _pose(model: PhotoModel, x: float, y: float, t: float) -> np.ndarray:
    c, s = np.cos(t), np.sin(t)
    return make_pose(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), [x, y, 0.0])


def _inliers(fit: _Fit) -> np.ndarray:
    """The fit's robust inliers (residual within 3 MAD-sigmas, at least 0.1 mm): the points sigma uses."""
    r = fit.residual_mm
    scale = 1.4826 * float(np.nanmedian(np.abs(r))) + 1e-6
    return fit.found & (np.abs(np.nan_to_num(r, nan=1e9)) < max(3 * scale, 0.1))


def _fit_cov(fit: _Fit, model: PhotoModel) -> np.ndarray:
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


def table_sensitivity(fit: _Fit, model: PhotoModel, view: View) -> np.ndarray:
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
    Q, N = _transform(model, fit.x, fit.y, fit.theta)
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


def _table_term(fit: _Fit, model: PhotoModel, view: View) -> np.ndarray:
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
    R[:2, :2] = _rot(theta)
    return R @ np.asarray(cov, float) @ R.T


def _sigma(fit: _Fit, model: PhotoModel, view: View) -> tuple[np.ndarray, np.ndarray, dict]:
    """Covariance of a located pose: (3x3 of x mm, y mm, theta rad in table axes about the obj
    origin, the 6x6 of (x, y, z mm, rotation vector rad) with the table contact's height and tilt as
    the CAD engine's, and the parts). The 3x3 is the sum of

    * fit: :func:`_fit_cov` of this picture times the CAD engine's :data:`SIGMA_SCALE` squared, and the
      model's ``teach_cov`` (the template's own placement in its first picture) turned into table axes;
    * table: this picture's table-pose error propagated through the fit (:func:`table_sensitivity`),
      and the first teach picture's (``teach_table_cov``, obj axes, turned; a model without it takes
      this picture's term in its stead);
    * edge bias: :data:`EDGE_BIAS_PX` camera pixels of the teach picture and of this one (mm on the top
      face at the object), in x and in y: a shift of the whole outline that no fit can see.

    Returns (cov3, cov6, parts) with parts {"fit", "table": 3x3 lists, "edge_bias_mm2": teach px^2 +
    this px^2 (mm^2), "edge_bias_px"} so that a benchmark can refit the edge bias."""
    fit_c = SIGMA_SCALE ** 2 * _fit_cov(fit, model) + _turned(model.teach_cov, fit.theta)
    table = _table_term(fit, model, view)
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


def _dt_coverage(fit: _Fit, model: PhotoModel, x: float, y: float, t: float, d: np.ndarray) -> float:
    """Share of template points within ``SUPPORT_MM`` of an image edge at pose (x, y, t) (no normals:
    for the distinctiveness probes); ``d`` is ``fit.edge_dt``."""
    Q, _ = _transform(model, x, y, t)
    ij = np.rint(fit.grid.to_px(Q)).astype(int)
    ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < fit.grid.width) & (ij[:, 1] < fit.grid.height)
    v = np.full(len(Q), 1e9)
    v[ok] = d[ij[ok, 1], ij[ok, 0]] * fit.grid.mm_per_px
    return float(np.mean(v < SUPPORT_MM + 0.15))


def _unexplained(fit: _Fit, model: PhotoModel) -> tuple[float, float, float]:
    """Edges inside the fitted outline (grown by 1 mm) that no template point explains: (their share
    of the edges there, their total length mm, the longest connected piece mm)."""
    g = fit.grid
    R = _rot(fit.theta)
    inside = np.zeros((g.height, g.width), np.uint8)
    cv2.fillPoly(inside, [np.rint(g.to_px(model.outline_mm @ R.T + [fit.x, fit.y]) * 4).astype(np.int32)], 255, shift=2)
    # not in the holes: what shows through them (their walls, the table below) depends on the view
    holes = np.zeros_like(inside)
    for h in model.holes_mm:
        cv2.fillPoly(holes, [np.rint(g.to_px(h @ R.T + [fit.x, fit.y]) * 4).astype(np.int32)], 255, shift=2)
    r = max(1, round(1.0 / g.mm_per_px))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    inside = cv2.dilate(inside, disk) & ~cv2.dilate(holes, disk)
    tmpl = np.full((g.height, g.width), 255, np.uint8)
    Q, _ = _transform(model, fit.x, fit.y, fit.theta)
    ij = np.rint(g.to_px(Q)).astype(int)
    ok = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < g.width) & (ij[:, 1] < g.height)
    tmpl[ij[ok, 1], ij[ok, 0]] = 0
    near = cv2.distanceTransform(tmpl, cv2.DIST_L2, 5) * g.mm_per_px < EXPLAINED_MM
    edges_in = (fit.edges.canny > 0) & (inside > 0)
    unexpl = (edges_in & ~near).astype(np.uint8)
    n_in = int(edges_in.sum())
    if not unexpl.any():
        return 0.0, 0.0, 0.0
    n, lab, _stats, _ = cv2.connectedComponentsWithStats(cv2.dilate(unexpl, np.ones((3, 3), np.uint8)), connectivity=8)
    longest = max(float(np.sum(unexpl[lab == i])) for i in range(1, n)) * g.mm_per_px
    return float(unexpl.sum() / max(n_in, 1)), float(unexpl.sum() * g.mm_per_px), longest


def _missing_inner(fit: _Fit, model: PhotoModel) -> float:
    """Longest connected piece (mm) of the template's inner edges (more than 1.5 mm inside the outline:
    holes, pockets, steps) that the picture does not show at the fit. The outline may be hidden in
    part (a clamp over an edge); a whole inner feature missing means another object (a plate without
    that hole)."""
    P = model.points_mm
    contour = model.outline_mm.astype(np.float32).reshape(-1, 1, 2)
    depth = np.array([cv2.pointPolygonTest(contour, (float(x), float(y)), True) for x, y in P])
    seen = fit.found & (np.abs(np.nan_to_num(fit.residual_mm, nan=9.0)) < SUPPORT_MM + 0.2)
    miss = (depth > 1.5) & ~seen
    if not miss.any():
        return 0.0
    lo = P.min(axis=0) - 2
    g = PlaneGrid(float(lo[0]), float(lo[1]), 0.25, int((P[:, 0].max() - lo[0] + 2) / 0.25) + 1,
                  int((P[:, 1].max() - lo[1] + 2) / 0.25) + 1)
    img = np.zeros((g.height, g.width), np.uint8)
    ij = np.rint(g.to_px(P[miss])).astype(int)
    img[ij[:, 1], ij[:, 0]] = 255
    n, lab = cv2.connectedComponents(cv2.dilate(img, np.ones((7, 7), np.uint8)), connectivity=8)
    per = np.bincount(lab[ij[:, 1], ij[:, 0]], minlength=n)
    return float(per[1:].max() * TEMPLATE_SPACING_MM) if n > 1 else 0.0


def locate(view: View, model: PhotoModel, name: str, *,
           search_xy: tuple[float, float, float, float] = (0.0, 800.0, 0.0, 400.0), min_score: float = 0.6,
           min_margin: float = 0.1, max_sigma_mm: float = 0.3, max_sigma_deg: float = 0.05,
           max_unexplained_mm: float | None = None, n_starts: int = 3) -> ObjectPose | ObjectFailure:
    """Locate a photo model in a picture whose table pose is known (``view.T_cam_table``).

    search_xy : (x_lo, x_hi, y_lo, y_hi) table box to search (mm)
    min_score : least share of the template's edges supported after the fit
    min_margin : least lead of the score over the best different pose (symmetries are the same pose)
    max_unexplained_mm : longest piece of edge inside the outline that the model lacks before the
        fit is refused as another object (None: 8 mm or 3 % of the template's edge length)
    Returns the engine's :class:`ObjectPose` (resting on the table, ``T_table_obj`` turned about table
    z only, sigma and 6x6 covariance as the CAD fit's) or :class:`ObjectFailure` with the reason."""
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    starts = _coarse_starts(view, model, search_xy, n_starts=n_starts)
    timings["search"] = (time.perf_counter() - t0) * 1e3
    if not starts:
        return ObjectFailure(name, "not_found", f"{name} not found: no edges on the table", 0.0, (), timings)
    t1 = time.perf_counter()
    fits = [_refine(view, model, (x, y, t)) for _, x, y, t in starts]
    timings["fit"] = (time.perf_counter() - t1) * 1e3
    fits.sort(key=lambda f: -f.coverage)
    best = fits[0]
    rivals = [f for f in fits[1:] if np.hypot(f.x - best.x, f.y - best.y) > 3.0
              or _angle_gap(f.theta, best.theta, model) > np.radians(3)]
    runner = max((f.coverage for f in rivals), default=float("nan"))
    cands = tuple({"T_table_obj": _pose(model, f.x, f.y, f.theta).tolist(), "score": f.coverage} for f in fits[:3])
    T_table_obj = _pose(model, best.x, best.y, best.theta)
    if best.coverage < min_score:
        return ObjectFailure(name, "not_found", f"{name} not found: the best fit has {best.coverage:.0%} of its edges "
                             f"in the picture (at least {min_score:.0%} needed)", best.coverage, cands, timings)
    margin = best.coverage - runner if np.isfinite(runner) else float("nan")
    if np.isfinite(margin) and margin < min_margin:
        return ObjectFailure(name, "ambiguous", f"{name} is ambiguous: another pose fits almost as well "
                             f"({best.coverage:.0%} against {runner:.0%})", best.coverage, cands, timings)
    share, unexpl_mm, longest = _unexplained(best, model)
    limit = max_unexplained_mm if max_unexplained_mm is not None else max(8.0, 0.03 * model.edge_length_mm)
    if longest > limit:
        return ObjectFailure(name, "not_found", f"{name} not found: the object there has {longest:.0f} mm of edges "
                             f"inside its outline that {name} does not have (another object?)", best.coverage,
                             cands, timings)
    missing = _missing_inner(best, model)
    if missing > limit:
        return ObjectFailure(name, "not_found", f"{name} not found: {missing:.0f} mm of its edges inside its outline "
                             "(a hole, a pocket) are not in the picture (another object, or that part hidden?)",
                             best.coverage, cands, timings)
    _cov3, cov6, parts = _sigma(best, model, view)
    sd = np.sqrt(np.maximum(np.diag(cov6), 0.0))
    sigma = {"x_mm": float(sd[0]), "y_mm": float(sd[1]), "z_mm": float(sd[2]), "rx_deg": float(np.degrees(sd[3])),
             "ry_deg": float(np.degrees(sd[4])), "rz_deg": float(np.degrees(sd[5]))}
    unc_ok = max(sd[:3]) <= max_sigma_mm and sigma["rz_deg"] <= max_sigma_deg
    xy = np.array([best.x, best.y])
    cam_mm = camera_mm_per_px(view.K, view.T_cam_table, xy, model.height_mm)
    probe_mm = 4.0 * cam_mm
    probes = [(best.x + dx, best.y + dy, best.theta) for dx, dy in ((probe_mm, 0), (-probe_mm, 0), (0, probe_mm),
                                                                     (0, -probe_mm))]
    probes += [(best.x, best.y, best.theta + s * probe_mm / model.radius_mm) for s in (1, -1)]
    dt = best.edge_dt
    base = _dt_coverage(best, model, best.x, best.y, best.theta, dt)
    distinct = float(base - max(_dt_coverage(best, model, *p, dt) for p in probes))
    r = best.residual_mm
    inl = best.found & (np.abs(np.nan_to_num(r, nan=1e9)) < SUPPORT_MM)
    flags = []
    if not unc_ok:
        flags.append("uncertainty")
    if inl.sum() < 100:
        flags.append("few_edges")
    equivalent = tuple(T_table_obj @ make_pose(np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0],
                                                         [0, 0, 1.0]]))
                       for a in np.radians(model.symmetry_deg))
    note = "" if not equivalent else (f"the outline looks the same turned by {', '.join(f'{s:g}°' for s in model.symmetry_deg)}"
                                      "; choose which pose is meant")
    if equivalent:
        flags.append("datum_ambiguous")
    timings["total"] = (time.perf_counter() - t0) * 1e3
    return ObjectPose(
        model_name=name, T_cam_obj=np.asarray(view.T_cam_table, float) @ T_table_obj, T_table_obj=T_table_obj,
        resting_state=0, score=float(best.coverage), inlier_edge_fraction=float(inl.mean()),
        residual_px=float(np.sqrt(np.mean(r[inl] ** 2)) / cam_mm) if inl.any() else float("nan"),
        visible_fraction=float(best.found.mean()), supported_edge_px=float(inl.sum() * TEMPLATE_SPACING_MM / cam_mm),
        unexplained_fraction=share, n_edge_samples=len(model.points_mm), sigma=sigma, uncertainty_ok=bool(unc_ok),
        T_table_obj_6dof=T_table_obj, tilt_deg=0.0, tilt_sigma_deg=float(CONTACT_SIGMA_DEG), height_offset_mm=0.0,
        margin=float(margin), runner_up_score=float(runner), distinctiveness=distinct,
        equivalent_poses=equivalent, datum_ambiguous=bool(equivalent), datum_note=note, flags=tuple(flags),
        timings_ms=timings, covariance=cov6,
        photo={"unexplained_mm": unexpl_mm, "longest_unexplained_mm": longest, "edge_length_mm": model.edge_length_mm,
               "edge_iou": edge_iou(best.coverage, model, unexpl_mm), "cam_mm_per_px": cam_mm,
               "cov_parts": parts})


def locate_near(view: View, model: PhotoModel, name: str, T_table_obj: np.ndarray,
                reach_mm: float = 20.0) -> ObjectPose | ObjectFailure:
    """:func:`locate` searched only within the model's size plus ``reach_mm`` of a pose (table frame):
    "refine from here" after an operator moved the object on the screen."""
    r = model.radius_mm + reach_mm
    x, y = float(T_table_obj[0, 3]), float(T_table_obj[1, 3])
    return locate(view, model, name, search_xy=(x - r, x + r, y - r, y + r))


def edge_iou(coverage: float, model: PhotoModel, unexplained_mm: float) -> float:
    """Supported template edge length over (template length + unexplained edge length inside the
    outline): 1 for the right object; a plate without a hole fitted to one with it scores lower."""
    L = model.edge_length_mm
    return float(coverage * L / (L + unexplained_mm))


# ------------------------------------------------------------------------------------------ look-alikes
def lookalike_evidence(view: View, a: PhotoModel, T_a: np.ndarray, b: PhotoModel, T_b: np.ndarray,
                       apart_mm: float = 1.5) -> tuple[float, float, int, int]:
    """How the picture decides between two models located at (nearly) the same place: the edges of
    ``a`` (at ``T_a``) farther than ``apart_mm`` from every edge of ``b`` (at ``T_b``), and the other
    way round. Returns (share of a's own edges that the picture shows, share of b's own edges it shows,
    number of a's own points, number of b's own points); a share is NaN when there are none."""
    def own(m1, T1, m2, T2):
        P1 = m1.points_mm @ T1[:2, :2].T + T1[:2, 3]
        P2 = m2.points_mm @ T2[:2, :2].T + T2[:2, 3]
        lo = np.minimum(P1.min(0), P2.min(0)) - 5
        g = PlaneGrid(float(lo[0]), float(lo[1]), 0.25, int((max(P1[:, 0].max(), P2[:, 0].max()) - lo[0] + 5) / 0.25) + 1,
                      int((max(P1[:, 1].max(), P2[:, 1].max()) - lo[1] + 5) / 0.25) + 1)
        img = np.full((g.height, g.width), 255, np.uint8)
        ij = np.rint(g.to_px(P2)).astype(int)
        img[ij[:, 1], ij[:, 0]] = 0
        d = cv2.distanceTransform(img, cv2.DIST_L2, 5) * 0.25
        q = np.rint(g.to_px(P1)).astype(int)
        return d[q[:, 1], q[:, 0]] > apart_mm

    out = []
    for m, T, mo, To in ((a, T_a, b, T_b), (b, T_b, a, T_a)):
        sel = own(m, T, mo, To)
        if sel.sum() < 5:
            out.append((float("nan"), int(sel.sum())))
            continue
        t = float(np.arctan2(T[1, 0], T[0, 0]))
        fit = _refine_fixed(view, m, (float(T[0, 3]), float(T[1, 3]), t))
        ok = fit.found & (np.abs(np.nan_to_num(fit.residual_mm, nan=9.0)) < SUPPORT_MM + 0.2)
        out.append((float(ok[sel].mean()), int(sel.sum())))
    return out[0][0], out[1][0], out[0][1], out[1][1]


def _refine_fixed(view: View, model: PhotoModel, pose: tuple[float, float, float]) -> _Fit:
    """Correspondences of ``model`` at a fixed pose (no fit): which of its edges the picture shows."""
    x, y, t = pose
    grid = _fine_grid(model, x, y)
    rect, valid, ign = rectify(view.image, view.K, view.dist, view.T_cam_table, grid, view.ignore)
    e = plane_edges(rect, valid, ign, smooth_px=1.5)
    Q, N = _transform(model, x, y, t)
    off, found = _correspond(e, grid, Q, N, 0.8)
    return _Fit(x, y, t, float(np.mean(found & (np.abs(np.nan_to_num(off, nan=9.0)) < SUPPORT_MM))), off, found,
                np.zeros((len(Q), 3)), grid, e)


def decide_lookalikes(view: View, located: list[tuple[str, PhotoModel, ObjectPose]], *, min_margin: float = 0.1,
                      own_present: float = 0.6, own_absent: float = 0.35) -> tuple[list[int], dict[int, str]]:
    """Which of several photo models located in one picture are accepted. Models located at the same
    place (centres closer than half the larger radius) compete: the best by edge IoU wins when it leads
    by ``min_margin``, or when :func:`lookalike_evidence` shows its own edges (>= ``own_present``) and
    not the rival's own (<= ``own_absent``). Otherwise none of the group is accepted. Returns (indices
    accepted, {index: reason refused})."""
    order = sorted(range(len(located)), key=lambda i: -located[i][2].photo["edge_iou"])
    accepted: list[int] = []
    undecided: list[int] = []          # places where look-alikes could not be told apart
    refused: dict[int, str] = {}

    def same_place(i: int, j: int) -> bool:
        (_, mi, pi), (_, mj, pj) = located[i], located[j]
        d = float(np.hypot(*(pi.T_table_obj[:2, 3] - pj.T_table_obj[:2, 3])))
        return d < 0.5 * max(mi.radius_mm, mj.radius_mm)

    for i in order:
        name, m, p = located[i]
        blocked = next((j for j in undecided if same_place(i, j)), None)
        if blocked is not None:
            refused[i] = refused[blocked]
            continue
        clash = next((j for j in accepted if same_place(i, j)), None)
        if clash is None:
            accepted.append(i)
            continue
        # i is the weaker at that place (sorted by edge IoU): it loses when the lead is clear or the
        # edges in which the two differ show the winner's and not its own
        nj, mj, pj = located[clash]
        lead = pj.photo["edge_iou"] - p.photo["edge_iou"]
        sa, sb, na, nb = lookalike_evidence(view, mj, pj.T_table_obj, m, p.T_table_obj)
        a_ok = (not np.isfinite(sa)) or sa >= own_present
        b_absent = (not np.isfinite(sb)) or sb <= own_absent
        if lead >= min_margin or (a_ok and b_absent and (na + nb) > 0):
            refused[i] = (f"lost to {nj} at the same place (edge IoU {p.photo['edge_iou']:.0%} against "
                          f"{pj.photo['edge_iou']:.0%}; edges only {name} has: {_pct(sb)} seen, only {nj} has: "
                          f"{_pct(sa)} seen)")
        else:
            accepted.remove(clash)
            undecided.append(clash)
            why = (f"{name} and {nj} look alike at the same place and the picture does not decide "
                   f"(edge IoU {p.photo['edge_iou']:.0%} against {pj.photo['edge_iou']:.0%}; edges only {name} has: "
                   f"{_pct(sb)} seen, only {nj} has: {_pct(sa)} seen)")
            refused[i] = refused[clash] = why
    return accepted, refused


def _pct(v: float) -> str:
    return "none to see" if not np.isfinite(v) else f"{v:.0%}"
