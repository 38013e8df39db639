"""Table pose ``T_cam_table`` from the table's ArUco markers (one image, known intrinsics).

Pipeline of :func:`locate_table`:

1. ``cv2.aruco.ArucoDetector`` with the layout's dictionary finds markers and rough corners.
   Ids not in the layout, and ids seen twice, are rejected with that reason.
2. Corner refinement (:func:`refine_marker_corners`): each side of a marker's black square is a
   straight line in UNDISTORTED (ideal pinhole) pixel coordinates. Along each side, intensity
   profiles across the edge are sampled from the raw image (bilinear; sample positions mapped
   through OpenCV's distortion model), linearised by undoing the camera gamma, and the 50 %
   crossing between the black border and the white quiet zone is taken as the edge point
   (several times more precise than the strongest gradient on blurred, gamma-encoded edges).
   A line is fitted to each side (total least squares with outlier trimming), twice (the second
   time around the first fit), and the corners are the intersections of adjacent lines. OpenCV's
   own corners (detector contour / cornerSubPix) sit a few tenths of a pixel inside the square;
   the line fit removes that bias (see benchmarks/table_pose.md).
3. One joint PnP over all markers' corners: a robust start (pose hypotheses from all markers,
   every pair of markers (``cv2.SOLVEPNP_SQPNP``) and each marker alone (IPPE_SQUARE), scored by
   how many markers each explains), then Levenberg-Marquardt (``scipy.optimize.least_squares``)
   on the corner reprojection error in ideal pixels. Markers whose RMS residual exceeds
   ``max_marker_residual_px`` (or 5x the median of the others) are rejected one at a time, worst
   first ("moved or misdetected"), and the pose is refined again.
4. Final fit to the border points themselves (``final_fit="edges"``): residual = distance of each
   measured edge point to the projected side of its marker. Corners made by intersecting lines
   carry errors that are strongly correlated within a marker (a line's tilt moves its two corners
   in opposite directions; measured: the error of a marker's centre is 0.26x its corner error
   instead of 0.5x for independent corners), which a corner fit weighs wrongly; edge points of
   different sides are independent, and their correlation along a side is accounted for in 5.
   On the benchmark: same median as the corner fit, lower maximum (0.13 vs 0.18 mm), and a
   1 sigma that matches the errors (the corner fit's is about twice too large).
5. Uncertainty: covariance ``sigma^2 (J^T J)^-1 (1 + rho) / (1 - rho)`` of the final fit, with
   ``sigma^2`` the residual variance (floored at ``min_corner_sigma_px^2``) and ``rho`` the lag-1
   correlation of the residuals along each side (neighbouring edge points share pixels: AR(1)
   effective sample size), expressed as a rotation about the table axes (deg) and a shift of the
   table at the centroid of the used markers along the table axes (mm). With 2-3 markers, or
   markers on one line, the rotation about that line is weak and this shows in ``sigma_rot_deg``;
   beyond ``max_sigma_rot_deg`` the result is a failure. The markers' placement against their
   layout (the layout's ``placement_sigma``, position, turn and print scale) is then added through
   the fit's linear response (:func:`_placement_jacobian`): with 2-3 markers nothing else can show
   it, and a marker 0.1 mm off moves a 3-marker table up to 0.6 mm along the line of sight (the
   table's distance rests on the markers' spread). So is an error all the points of one marker
   side share (:data:`SIDE_OFFSET_PX`, :func:`_side_jacobian`: a shadow edge along a border, a
   grazing view): with two markers their tilt about the line between them rests on each one's
   perspective, and such errors tilted devset tables by up to 0.3-1 deg where the points' scatter
   said 0.04. With 4 or more markers the covariance is
   then held at least as large as the jackknife over the markers (the fit taken without each in
   turn, one Gauss-Newton step from the full fit): a marker placed, turned or printed off its
   layout moves all its points alike, which the points' scatter does not show (the devset told its
   layout 0.2 mm / 0.2 deg / 0.2 % off: NEES per dof 2.8 -> 1.9, no longer a result passing the gate
   beyond 1.3 sigma).

Pixel convention: OpenCV (u, v), pixel centres at integers, ``img[v, u]``. Marker corners in
OpenCV's order, marker frame as in DESIGN (corner 0 at (-s/2, +s/2, 0)).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.ndimage import map_coordinates
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from app.geometry.fiducial_layout import PLACEMENT_KEYS, placement_sigma
from app.geometry.transforms import check_pose, make_pose, rvec_tvec_to_pose, transform_points
from app.vision.encoding_gamma import GammaReading, clipped_edge_bias_px, marker_transitions, read_encoding_gamma
from app.vision.intrinsics import (
    DEFAULT_INTRINSICS_SIGMA,
    INTRINSICS_STEPS,
    distort_px,
    moved_intrinsics,
    undistort_px,
)
from app.vision.overlay_text import put_banner, put_label, style_for

# ---------------------------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RejectedMarker:
    """A marker seen but not used, with the reason in plain words."""

    id: int
    reason: str
    corners_px: np.ndarray | None = None      # (4, 2) distorted px, as detected


@dataclass(frozen=True)
class TablePose:
    """The table located in the image.

    T_cam_table : (4, 4) pose of the table frame in the camera frame, mm.
    ids_used : marker ids in the final fit; ids_rejected : markers seen but not used (with reason).
    rms_px : RMS reprojection residual over all used corners (ideal pixels) at the final pose.
    residual_px : {id: RMS residual of that marker's 4 corners}.
    sigma_xyz_mm : 1-sigma shift of the table along its own x, y, z axes, at ``centroid_table_mm``
        (the centroid of the used markers); sigma_rot_deg : 1-sigma rotation about the table's
        x, y, z axes. covariance : (6, 6) of (rotation about x, y, z in rad, shift x, y, z in mm).
    corners_px : {id: (4, 2)} refined corners, distorted px (as in the image).
    intrinsics_jacobian : (6, 3) how the pose (as ``covariance``) moves per unit of the intrinsics
        (focal length relative, cx px, cy px; :func:`app.vision.intrinsics.moved_intrinsics`);
        intrinsics_sigma : their 1-sigma (None: the intrinsics are taken as exact).
    placement_sigma : the markers' placement error (position mm, rotation deg, scale relative) that
        ``covariance`` holds; placement_jacobian : (6, 4 n + 1) how the pose
        moves per unit of each placement parameter, markers in ``ids_used`` order
        (:func:`_placement_jacobian`).
    """

    T_cam_table: np.ndarray
    ids_used: tuple[int, ...]
    ids_rejected: tuple[RejectedMarker, ...]
    rms_px: float
    residual_px: dict[int, float]
    sigma_xyz_mm: np.ndarray
    sigma_rot_deg: np.ndarray
    covariance: np.ndarray
    centroid_table_mm: np.ndarray
    corners_px: dict[int, np.ndarray]
    method: str = "markers"
    time_ms: float = 0.0
    warnings: tuple[str, ...] = ()
    K: np.ndarray | None = None               # intrinsics used (for drawing the axes)
    dist: np.ndarray | None = None
    gamma: float = 2.2                        # the image decoded with it (edges of every later stage too)
    gamma_reading: GammaReading | None = None  # what the markers said about it
    intrinsics_jacobian: np.ndarray | None = None
    intrinsics_sigma: tuple[float, float, float] | None = None
    placement_sigma: tuple[float, float, float] = (0.0, 0.0, 0.0)
    placement_jacobian: np.ndarray | None = None
    side_jacobian: np.ndarray | None = None

    def __bool__(self) -> bool:
        return True

    def frame_error(self) -> tuple:
        """What every object's pose in this table frame inherits from it, as
        :func:`app.vision.object_pose.uncertainty.table_covariance` takes it: (covariance, centroid,
        intrinsics jacobian, intrinsics sigma)."""
        return (self.covariance, self.centroid_table_mm, self.intrinsics_jacobian, self.intrinsics_sigma)

    def to_dict(self) -> dict:
        """JSON-ready: poses as 4x4 lists (mm), sigmas in mm and degrees."""
        return {
            "ok": True, "method": self.method,
            "T_cam_table": self.T_cam_table.tolist(),
            "ids_used": list(self.ids_used),
            "ids_rejected": [{"id": r.id, "reason": r.reason} for r in self.ids_rejected],
            "rms_px": round(float(self.rms_px), 4),
            "residual_px": {str(k): round(float(v), 4) for k, v in self.residual_px.items()},
            "sigma_xyz_mm": [round(float(v), 4) for v in self.sigma_xyz_mm],
            "sigma_rot_deg": [round(float(v), 5) for v in self.sigma_rot_deg],
            "centroid_table_mm": [round(float(v), 3) for v in self.centroid_table_mm],
            "time_ms": round(float(self.time_ms), 1),
            "warnings": list(self.warnings),
            "gamma": self.gamma,
            "gamma_reading": self.gamma_reading.to_dict() if self.gamma_reading is not None else None,
            "placement_sigma": dict(zip(PLACEMENT_KEYS, self.placement_sigma)),
            "intrinsics_sigma": None if self.intrinsics_sigma is None else
            {"f_rel": self.intrinsics_sigma[0], "cx_px": self.intrinsics_sigma[1], "cy_px": self.intrinsics_sigma[2]},
        }


@dataclass(frozen=True)
class TableFailure:
    """The table could not be located; ``reason`` says what was seen and what is needed."""

    reason: str
    ids_seen: tuple[int, ...] = ()
    ids_rejected: tuple[RejectedMarker, ...] = ()
    corners_px: dict[int, np.ndarray] = field(default_factory=dict)
    time_ms: float = 0.0

    def __bool__(self) -> bool:
        return False

    def to_dict(self) -> dict:
        return {"ok": False, "reason": self.reason, "ids_seen": list(self.ids_seen),
                "ids_rejected": [{"id": r.id, "reason": r.reason} for r in self.ids_rejected],
                "time_ms": round(float(self.time_ms), 1)}


# ---------------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------------


def _gray(image: np.ndarray) -> np.ndarray:
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return image


def _dictionary(name: str) -> cv2.aruco.Dictionary:
    code = getattr(cv2.aruco, str(name), None)
    if not isinstance(code, int):
        raise ValueError(f"layout dictionary {name!r} is not an OpenCV ArUco dictionary "
                         "(use a name such as DICT_5X5_100)")
    return cv2.aruco.getPredefinedDictionary(code)


def _ids_text(ids) -> str:
    ids = [str(i) for i in ids]
    if len(ids) == 1:
        return f"id {ids[0]}"
    return "ids " + ", ".join(ids[:-1]) + " and " + ids[-1]


def marker_corners_table_mm(marker: dict) -> np.ndarray:
    """(4, 3) corners of a layout marker's black square in the table frame, OpenCV order."""
    T = check_pose(marker["T_table_marker"], f"T_table_marker of marker {marker['id']}")
    h = float(marker["size_mm"]) / 2
    c = np.array([[-h, h, 0], [h, h, 0], [h, -h, 0], [-h, -h, 0]], float)
    return transform_points(T, c)


def detect_markers(image: np.ndarray, dictionary: str) -> tuple[dict[int, list[np.ndarray]], np.ndarray]:
    """ArUco markers in ``image``: {id: [corners (4, 2) distorted px, ...]} (a list: an id may
    appear more than once) and the grey image used."""
    gray = _gray(image)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
    det = cv2.aruco.ArucoDetector(_dictionary(dictionary), params)
    corners, ids, _ = det.detectMarkers(gray)
    out: dict[int, list[np.ndarray]] = {}
    if ids is not None:
        for c, i in zip(corners, ids.ravel()):
            out.setdefault(int(i), []).append(c.reshape(4, 2).astype(np.float64))
    return out, gray


# ---------------------------------------------------------------------------------------------
# Corner refinement by line fits to the marker's border
# ---------------------------------------------------------------------------------------------

def _fit_line(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Total least squares line through pts (N, 2): (point, unit direction, inlier mask), with
    outliers beyond 3 MAD trimmed (up to three rounds)."""
    keep = np.ones(len(pts), bool)
    for _ in range(3):
        if keep.sum() < 4:
            return None
        p = pts[keep]
        c = p.mean(axis=0)
        _, _, vt = np.linalg.svd(p - c)
        d = vt[0]
        n = np.array([-d[1], d[0]])
        r = (pts - c) @ n
        mad = np.median(np.abs(r[keep] - np.median(r[keep]))) * 1.4826
        new = np.abs(r) <= max(3 * mad, 0.05)
        if np.array_equal(new, keep):
            break
        keep = new
    return c, d, keep


def _lit_side(pts: np.ndarray, contrast: np.ndarray) -> np.ndarray:
    """The crossings of one side that lie on the line its fully lit profiles give.

    Where at least 30 % of a side's profiles have 0.7 of its full contrast (the 90th percentile),
    their crossings fix the line and the others are kept only within 3 MAD (at least 0.1 px) of it:
    a darker profile is a margin in shadow, whose crossing holds, or an object in front of the plate
    whose edge runs across the border, whose crossing does not (devset setup_039, marker 90: a
    grey edge 1-2 px inside the border along half of one side turned that side by a pixel). Else
    every crossing stays."""
    strong = contrast >= 0.7 * np.percentile(contrast, 90)
    if strong.sum() < max(4, 0.3 * len(pts)):
        return pts
    line = _fit_line(pts[strong])
    if line is None:
        return pts
    c, d, inl = line
    r = (pts - c) @ np.array([-d[1], d[0]])
    rs = r[strong][inl]
    tol = max(3.0 * 1.4826 * float(np.median(np.abs(rs - np.median(rs)))), 0.1)
    return pts[np.abs(r) <= tol]


def _intersect(l1, l2) -> np.ndarray | None:
    (p1, d1, _), (p2, d2, _) = l1, l2
    A = np.column_stack([d1, -d2])
    if abs(np.linalg.det(A)) < 1e-9:
        return None
    s = np.linalg.solve(A, p2 - p1)
    return p1 + s[0] * d1


def linearise(gray: np.ndarray, gamma: float = 2.2) -> np.ndarray:
    """Undo the camera's gamma: (H, W) uint8 -> float32 relative radiance 0..1."""
    lut = ((np.arange(256) / 255.0) ** gamma).astype(np.float32)
    return lut[gray]


def refine_marker_corners(gray: np.ndarray, corners_px: np.ndarray, K: np.ndarray,
                          dist: np.ndarray, bits: int, *, gamma: float = 2.2,
                          iterations: int = 2, linear: np.ndarray | None = None,
                          return_edges: bool = False, clip_bias_px: float = 0.0):
    """Subpixel corners of one marker from line fits to its outer border.

    gray : (H, W) uint8 raw image; corners_px : (4, 2) rough corners (distorted px, OpenCV order);
    bits : marker bits per side (5 for DICT_5X5_*); linear : ``linearise(gray, gamma)`` if already
    computed. Returns (4, 2) corners in IDEAL (undistorted) pixels with the same K, or None when the
    marker is too small or an edge cannot be measured. With ``return_edges`` returns
    ``(corners, edges)``, edges a list of 4 arrays (N_i, 2): the inlier edge points (ideal px) of
    side i (corner i -> corner i + 1). clip_bias_px : how far a clipped white moved the crossings
    towards their bright side (negative: towards the black), taken off every crossing
    (:func:`app.vision.encoding_gamma.clipped_edge_bias_px`); 0: not corrected.
    """
    H, W = gray.shape
    lin = linearise(gray, gamma) if linear is None else linear
    ideal = undistort_px(corners_px, K, dist)
    side = np.linalg.norm(np.roll(ideal, -1, axis=0) - ideal, axis=1)
    cell = float(side.min()) / (bits + 2)
    if cell < 2.0:
        return None
    half_w = float(np.clip(0.7 * cell, 1.5, 8.0))       # profile half-length (px) across the edge
    step = 0.2
    offs = np.arange(-half_w, half_w + 1e-9, step)
    centre = ideal.mean(axis=0)
    lines = [None] * 4
    edge_pts = [None] * 4
    for it in range(iterations):
        for i in range(4):
            if it == 0:
                a, b = ideal[i], ideal[(i + 1) % 4]
            else:
                a, b = corners_it[i], corners_it[(i + 1) % 4]
            L = np.linalg.norm(b - a)
            d = (b - a) / L
            n = np.array([-d[1], d[0]])
            if n @ ((a + b) / 2 - centre) < 0:
                n = -n                                       # outward normal
            ts = np.arange(1.2 * cell, L - 1.2 * cell, max(0.7, L / 80))
            if len(ts) < 4:
                return None
            P = a + ts[:, None] * d                          # (T, 2) points on the side
            Q = P[:, None, :] + offs[None, :, None] * n      # (T, S, 2) profile points, ideal px
            q = distort_px(Q.reshape(-1, 2), K, dist).reshape(len(ts), len(offs), 2)
            # profiles leaving the image are dropped (a marker cut by the image border keeps
            # the rest of its side if at least 40 % of it is inside)
            inside = np.all((q >= 1) & (q <= [W - 2, H - 2]), axis=(1, 2))
            if inside.sum() < max(4, 0.4 * len(ts)):
                return None
            P, ts, q = P[inside], ts[inside], q[inside]
            val = map_coordinates(lin, [q[..., 1].ravel(), q[..., 0].ravel()],
                                  order=1).reshape(len(ts), len(offs))
            k = max(2, len(offs) // 5)
            dark = np.median(val[:, :k])
            bright = np.median(val[:, -k:])
            if bright - dark < 0.05:
                return None
            # 50 % crossing per profile, the first rising one from the dark side, between the
            # profile's own dark and bright ends (medians of its inner and outer fifth): a shadow over
            # part of a margin halves its light there, and against one level for the whole side
            # those crossings sat 1-2 px outward and turned the side (devset setup_016, marker 57:
            # 1.9 px RMS). A profile with under 0.3 of the side's contrast has no margin to cross to.
            dark_p = np.median(val[:, :k], axis=1, keepdims=True)
            bright_p = np.median(val[:, -k:], axis=1, keepdims=True)
            level = (dark_p + bright_p) / 2
            above = val >= level
            idx = np.argmax(above, axis=1)
            ok = (idx > 0) & above[np.arange(len(ts)), idx] & (bright_p[:, 0] - dark_p[:, 0] >= 0.3 * (bright - dark))
            level = level[:, 0][ok]
            j = idx[ok]
            rows = np.nonzero(ok)[0]
            v0 = val[rows, j - 1]
            v1 = val[rows, j]
            frac = (level - v0) / np.maximum(v1 - v0, 1e-9)
            s50 = offs[j - 1] + frac * step
            if len(rows) < 4:
                return None
            pts = P[rows] + (s50 - clip_bias_px)[:, None] * n
            pts = _lit_side(pts, (bright_p - dark_p)[rows, 0])
            lines[i] = _fit_line(pts)
            if lines[i] is None:
                return None
            edge_pts[i] = pts[lines[i][2]]
        new = []
        for i in range(4):
            c = _intersect(lines[(i - 1) % 4], lines[i])     # corner i: sides i-1 and i
            if c is None:
                return None
            new.append(c)
        corners_it = np.array(new)
    if np.max(np.linalg.norm(corners_it - ideal, axis=1)) > max(3.0, cell):
        return None                                           # refinement ran away: distrust
    return (corners_it, edge_pts) if return_edges else corners_it


# ---------------------------------------------------------------------------------------------
# Joint PnP with robust marker rejection
# ---------------------------------------------------------------------------------------------

def _project_ideal(K: np.ndarray, T_cam_table: np.ndarray, p_table: np.ndarray) -> np.ndarray:
    """Ideal pinhole pixels (N, 2) of table points (N, 3)."""
    p = transform_points(T_cam_table, p_table) @ K.T
    return p[:, :2] / p[:, 2:3]


def _marker_rms(K, T, obj: dict[int, np.ndarray], img: dict[int, np.ndarray]) -> dict[int, float]:
    out = {}
    for i in obj:
        r = _project_ideal(K, T, obj[i]) - img[i]
        out[i] = float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))
    return out


def _solve_pnp(K, obj_pts: np.ndarray, img_pts: np.ndarray) -> np.ndarray | None:
    """SQPnP (global) on ideal pixels: T_cam_table or None."""
    ok, rvec, tvec = cv2.solvePnP(np.ascontiguousarray(obj_pts, np.float64),
                                  np.ascontiguousarray(img_pts, np.float64), K, None,
                                  flags=cv2.SOLVEPNP_SQPNP)
    return rvec_tvec_to_pose(rvec, tvec) if ok else None


def _about(T0: np.ndarray, centroid: np.ndarray):
    """``pose(x)``: ``T0`` turned by the rotation vector ``x[:3]`` (rad) about ``centroid`` and
    shifted by ``x[3:6]`` (mm), table axes; the fits' parameters."""
    Tc = make_pose(None, centroid)
    return lambda x: T0 @ Tc @ make_pose(Rotation.from_rotvec(x[:3]).as_matrix(), x[3:6])


def _corner_residuals(K, T0: np.ndarray, obj_pts: np.ndarray, img_pts: np.ndarray, centroid: np.ndarray):
    """``res(x)``: reprojection error (ideal px, flat) of the corners ``obj_pts`` (table mm) against
    ``img_pts`` at ``pose(x)`` (:func:`_about`); and ``pose``."""
    pose = _about(T0, centroid)
    obj_c = obj_pts - centroid                         # points relative to the centroid
    return (lambda x: (_project_ideal(K, pose(x), obj_c) - img_pts).ravel()), pose


def _edge_residuals(K, T0: np.ndarray, obj: dict[int, np.ndarray], edges: dict[int, list[np.ndarray]],
                    centroid: np.ndarray):
    """``res(x)``: signed distance (ideal px) of each border point in ``edges`` to the projected side
    of its marker (corners ``obj``, table mm) at ``pose(x)`` (:func:`_about`); ``pose``; and each
    point's side (4 * marker index + side)."""
    pose = _about(T0, centroid)
    ids = sorted(edges)
    P = np.concatenate([obj[i] for i in ids]) - centroid          # (4n, 3) corners
    pts = np.concatenate([e for i in ids for e in edges[i]])       # (M, 2)
    side = np.concatenate([np.full(len(e), 4 * k + j) for k, i in enumerate(ids)
                           for j, e in enumerate(edges[i])])
    nxt = (side // 4) * 4 + (side % 4 + 1) % 4

    def res(x):
        uv = _project_ideal(K, pose(x), P)
        a, b = uv[side], uv[nxt]
        d = b - a
        n = np.column_stack([-d[:, 1], d[:, 0]]) / np.linalg.norm(d, axis=1, keepdims=True)
        return np.einsum("ij,ij->i", pts - a, n)

    return res, pose, side


def _refine(K, obj_pts: np.ndarray, img_pts: np.ndarray, T0: np.ndarray,
            centroid: np.ndarray, min_sigma_px: float):
    """LM refinement of the corner reprojection error about the markers' centroid.

    Returns T, residuals (N, 2) ideal px, covariance (6, 6) of (rotation about the table axes in
    rad, shift along the table axes in mm at ``centroid``): ``s^2 (J^T J)^-1``.
    """
    Tc_inv = make_pose(None, -centroid)
    res, pose = _corner_residuals(K, T0, obj_pts, img_pts, centroid)
    sol = least_squares(res, np.zeros(6), method="lm", x_scale=np.array([1e-3] * 3 + [0.1] * 3))
    r = sol.fun.reshape(-1, 2)
    s2 = max(float(np.sum(r ** 2)) / max(r.size - 6, 1), min_sigma_px ** 2)
    try:
        cov = s2 * np.linalg.inv(sol.jac.T @ sol.jac)
    except np.linalg.LinAlgError:
        cov = np.full((6, 6), np.inf)
    return pose(sol.x) @ Tc_inv, r, cov


def _refine_edges(K, T0: np.ndarray, obj: dict[int, np.ndarray], edges: dict[int, list[np.ndarray]],
                  centroid: np.ndarray, min_sigma_px: float):
    """Final fit to the border points themselves: residual = distance (ideal px) of each edge point
    to the projected side of its marker. Corners from line intersections have errors that are
    strongly correlated within a marker (a line's tilt moves its two corners in opposite
    directions), so a corner fit overstates the uncertainty; edge points are close to independent.
    Returns T, covariance (6, 6) (rotation about table axes rad, shift mm at ``centroid``), RMS px.
    """
    Tc_inv = make_pose(None, -centroid)
    res, pose, side = _edge_residuals(K, T0, obj, edges, centroid)
    sol = least_squares(res, np.zeros(6), method="lm", x_scale=np.array([1e-3] * 3 + [0.1] * 3))
    r = sol.fun
    s2 = max(float(np.sum(r ** 2)) / max(r.size - 6, 1), min_sigma_px ** 2)
    # Neighbouring edge points share pixels (profiles < 1 px apart, optical blur, JPEG blocks), so
    # their errors are positively correlated along a side. With lag-1 correlation rho (AR(1)) the
    # variance of a fitted quantity grows by (1 + rho) / (1 - rho) (effective sample size).
    same = side[1:] == side[:-1]
    rho = float(np.sum(r[1:][same] * r[:-1][same]) / max(np.sum(r ** 2), 1e-300))
    rho = float(np.clip(rho, 0.0, 0.9))
    inflate = (1 + rho) / (1 - rho)
    try:
        cov = s2 * inflate * np.linalg.inv(sol.jac.T @ sol.jac)
    except np.linalg.LinAlgError:
        cov = np.full((6, 6), np.inf)
    return pose(sol.x) @ Tc_inv, cov, float(np.sqrt(np.mean(r ** 2)))


def _frame_step(T: np.ndarray, T2: np.ndarray, centroid: np.ndarray) -> np.ndarray:
    """``e`` (rotation vector rad, shift mm; as the fits' covariance) with ``T2 = T @ E(e)``, ``E`` a
    rotation about ``centroid`` and a shift."""
    E = np.linalg.inv(T) @ T2
    R = E[:3, :3]
    return np.concatenate([Rotation.from_matrix(R).as_rotvec(), E[:3, 3] - centroid + R @ centroid])


def _final_residuals(K, T: np.ndarray, obj: dict, img: dict, edges: dict | None, ids: list,
                     centroid: np.ndarray, ideal=lambda q: q):
    """The final fit's residual function ``res(x)`` about ``T`` (:func:`_about`) over the markers
    ``ids`` (on the border points ``edges``, or on the corners ``img`` where it was a corner fit), its
    ideal pixels mapped by ``ideal``; each residual's marker id; and its marker side (4 * marker index
    + side; None for a corner fit, whose residuals are not distances to a side)."""
    ids = sorted(ids)
    if edges is not None:
        res, _, side = _edge_residuals(K, T, obj, {i: [ideal(q) for q in edges[i]] for i in ids}, centroid)
        return res, np.asarray(ids)[side // 4], side
    res = _corner_residuals(K, T, np.concatenate([obj[i] for i in ids]),
                            np.concatenate([ideal(img[i]) for i in ids]), centroid)[0]
    return res, np.repeat(ids, 8), None


# central-difference steps of the final fit's Jacobian: rotation rad, shift mm
_FIT_STEPS = np.array([1e-6] * 3 + [1e-4] * 3)


def _fit_jacobian(res) -> np.ndarray:
    """(M, 6) Jacobian of the final fit's residuals at ``x = 0`` (central differences)."""
    return np.column_stack([(res(h * e) - res(-h * e)) / (2 * h) for h, e in zip(_FIT_STEPS, np.eye(6))])


def _intrinsics_jacobian(K, dist, T: np.ndarray, obj: dict, img: dict, edges: dict | None, use: list,
                         centroid: np.ndarray, J_x: np.ndarray) -> np.ndarray:
    """(6, 3): how the final fit's pose (as its covariance: rotation rad, shift mm at ``centroid``)
    moves per unit of each of :func:`moved_intrinsics`' directions, linearised at the fit
    (Gauss-Newton, ``-J_x^+ dr/dk``, central differences in k). The markers' points are measured in
    the raw image; their ideal pixels are recomputed with the moved intrinsics. (Six refits give
    the same columns to 1e-4 of their largest on the devset's 40 images, at 1.5x the table's time.)
    ``J_x``: :func:`_fit_jacobian` of the final fit."""
    cols = []
    for k, h in enumerate(INTRINSICS_STEPS):
        r = []
        for step in (h, -h):
            K2 = moved_intrinsics(K, k, step)
            res = _final_residuals(K2, T, obj, img, edges, use, centroid,
                                   ideal=lambda q, K2=K2: undistort_px(distort_px(q, K, dist), K2, dist))[0]
            r.append(res(np.zeros(6)))
        cols.append((r[0] - r[1]) / (2.0 * h))
    return -np.linalg.lstsq(J_x, np.column_stack(cols), rcond=None)[0]


def _placement_jacobian(K, T: np.ndarray, obj: dict, img: dict, edges: dict | None, use: list,
                        centroid: np.ndarray, J_x: np.ndarray) -> np.ndarray:
    """(6, 4 n + 1): how the final fit's pose (as its covariance: rotation rad, shift mm at
    ``centroid``) moves per unit of each used marker's placement, linearised at the fit: per marker
    its centre along the table's x, y, z (mm) and its turn about its normal (rad), and last the
    print's scale (relative, all markers about their centres). Gauss-Newton: ``-J_x^+ J_p`` of the
    final fit's residuals (``J_x``: :func:`_fit_jacobian` of the final fit)."""
    def residuals(o: dict):
        """The final fit's residual function with the markers' corners at ``o``."""
        return _final_residuals(K, T, o, img, edges, use, centroid)[0]

    at_fit = np.zeros(6)
    moves: list[dict[int, np.ndarray]] = []        # per parameter: the corners' motion per unit
    scale = {}
    for i in use:
        c = obj[i]
        m = c.mean(axis=0)
        ex, ey = c[1] - c[0], c[0] - c[3]
        ez = np.cross(ex, ey)
        ez /= np.linalg.norm(ez)
        moves += [{i: np.tile(a, (4, 1))} for a in np.eye(3)]
        moves.append({i: np.cross(ez, c - m)})
        scale[i] = c - m
    moves.append(scale)
    h = 1e-3
    cols = []
    for mv in moves:
        plus = {i: obj[i] + h * mv[i] if i in mv else obj[i] for i in use}
        minus = {i: obj[i] - h * mv[i] if i in mv else obj[i] for i in use}
        cols.append((residuals(plus)(at_fit) - residuals(minus)(at_fit)) / (2 * h))
    return -np.linalg.lstsq(J_x, np.column_stack(cols), rcond=None)[0]


def _side_jacobian(side: np.ndarray, J_x: np.ndarray) -> np.ndarray:
    """(6, n_sides): how the final fit's pose (as its covariance) moves per pixel that all the border
    points of one marker side are off together (Gauss-Newton, ``-J_x^+ E`` with ``E`` each side's
    indicator), sides as in :func:`_edge_residuals`."""
    E = (side[:, None] == np.arange(int(side.max()) + 1)[None, :]).astype(float)
    return -np.linalg.lstsq(J_x, E, rcond=None)[0]


def placement_covariance(jacobian: np.ndarray, sigma: tuple[float, float, float]) -> np.ndarray:
    """(6, 6) table pose covariance from the markers' placement error ``sigma`` (position mm,
    rotation deg, scale relative; :func:`app.geometry.fiducial_layout.placement_sigma`) through
    :func:`_placement_jacobian`."""
    pos, rot, sc = sigma
    n = (jacobian.shape[1] - 1) // 4
    var = np.r_[np.tile([pos ** 2] * 3 + [np.radians(rot) ** 2], n), sc ** 2]
    return (jacobian * var) @ jacobian.T


# An error that all the border points of one marker side share (a shadow edge or a smear along the
# border, the bright plate beside it, blur at a grazing view): the points' scatter about their side
# does not show it, the jackknife only with 4 or more markers. Each side is taken as off by this much
# (px, 1 sigma), independently of the others. Fitted on the devset's first half, every pair and triple
# of its fully visible markers (benchmarks/devset_pose.md, twenty-fourth stop): the least value with at
# most 0.5 % of the tables more than 4 sigma off and 99 % within 3 sigma at the part (0 px: 1.2 %
# and 98 %; the held-out half's pairs 4.1 % and 95 %, with it 1.1 % and 99 %).
SIDE_OFFSET_PX = 0.05

# With at least this many markers in the final fit, the fit is taken leaving out one marker at a time
# and the spread of those poses (the jackknife) bounds the stated covariance from below: an error a
# marker's points share (placed 0.2 mm off, turned, printed at another scale) is not in the scatter of
# the points about their own marker, which is all the least-squares covariance sees.
MIN_JACKKNIFE_MARKERS = 4


def _marker_jackknife(use: list, marker: np.ndarray, r0: np.ndarray, J_x: np.ndarray) -> np.ndarray | None:
    """Jackknife covariance (6, 6; as the fit's) of the table pose over its markers, or None with
    fewer than :data:`MIN_JACKKNIFE_MARKERS`: ``(n - 1) / n * sum (e_i - mean)(e_i - mean)^T`` of the
    poses fitted without marker ``i`` (Efron & Stein 1981), each one Gauss-Newton step from the
    full fit (the steps are hundredths of a millimetre, where the fit is linear): the final fit's
    residuals ``r0`` at the fit, their markers ``marker`` and Jacobian ``J_x``
    (:func:`_final_residuals`, :func:`_fit_jacobian`)."""
    n = len(use)
    if n < MIN_JACKKNIFE_MARKERS:
        return None
    e = [-np.linalg.lstsq(J_x[marker != i], r0[marker != i], rcond=None)[0] for i in use]
    d = np.asarray(e) - np.mean(e, axis=0)
    return (n - 1) / n * d.T @ d


def at_least(cov: np.ndarray, other: np.ndarray) -> np.ndarray:
    """The covariance that holds ``cov`` in every direction and ``other`` where it is larger: in the
    directions where ``cov^-1/2 other cov^-1/2`` has eigenvalues above 1, those eigenvalues."""
    w, V = np.linalg.eigh(cov)
    if np.any(w <= 0) or not np.all(np.isfinite(other)):
        return cov
    half = V @ np.diag(np.sqrt(w)) @ V.T
    ihalf = V @ np.diag(1.0 / np.sqrt(w)) @ V.T
    lam, U = np.linalg.eigh(ihalf @ other @ ihalf)
    return half @ U @ np.diag(np.maximum(lam, 1.0)) @ U.T @ half


def locate_table(image: np.ndarray, K: np.ndarray, dist: np.ndarray, layout: dict, *,
                 min_markers: int = 2, max_marker_residual_px: float = 0.75,
                 max_sigma_rot_deg: float = 0.5, gamma: float = 2.2,
                 refine_corners: bool = True, min_corner_sigma_px: float = 0.02,
                 final_fit: str = "edges", read_gamma: bool = True,
                 intrinsics_sigma: tuple | None = DEFAULT_INTRINSICS_SIGMA,
                 markers_placed: tuple | None = None) -> TablePose | TableFailure:
    """Locate the table from its markers in one raw (distorted) image.

    Parameters
    ----------
    image : (H, W) grey or (H, W, 3) BGR uint8, as taken.
    K : (3, 3) camera matrix (px); dist : OpenCV distortion (k1, k2, p1, p2, k3).
    layout : DESIGN fiducial layout of the table ({"dictionary", "markers": [...]}).
    min_markers : markers of the layout needed in the final fit.
    max_marker_residual_px : a marker whose corners' RMS residual exceeds this (ideal px) after
        the joint fit is rejected as moved or misdetected (also when > 5x the median of the others).
    max_sigma_rot_deg : a fit whose 1-sigma rotation about any table axis exceeds this is a failure
        (markers on one line or too few and small to fix the table's tilt).
    gamma : the camera's gamma, undone before taking 50 % edge crossings.
    read_gamma : read the gamma from the markers' cells (:func:`read_encoding_gamma`) and use the
        reading where ``gamma`` measurably is not the image's (``TablePose.gamma``: the one used).
    refine_corners : False uses OpenCV's detector corners (for comparison).
    final_fit : "edges" (default) refines the pose and its covariance on the border points
        themselves (see ``_refine_edges``); "corners" keeps the joint corner fit.
    intrinsics_sigma : 1-sigma of the focal length (relative) and of cx, cy (px): with it the pose's
        dependence on them is measured (``TablePose.intrinsics_jacobian``) for the objects' sigma;
        None takes ``K`` as exact.
    markers_placed : 1-sigma of the markers' placement against the layout (position mm, rotation
        deg, scale relative); None: the layout's ``placement_sigma``
        (:func:`app.geometry.fiducial_layout.placement_sigma`).
        (0, 0, 0) takes the layout as exact.

    Returns :class:`TablePose` or :class:`TableFailure` (falsy, with ``reason``).
    """
    t0 = time.perf_counter()
    K = np.asarray(K, np.float64)
    dist = np.zeros(5) if dist is None else np.asarray(dist, np.float64).ravel()
    by_id = {int(m["id"]): m for m in layout["markers"]}
    dic = _dictionary(layout["dictionary"])
    found, gray = detect_markers(image, layout["dictionary"])
    ms = lambda: (time.perf_counter() - t0) * 1e3      # noqa: E731
    seen = tuple(sorted(found))
    rough = {i: c[0] for i, c in found.items()}
    need = f"need at least {min_markers} non-collinear markers of the layout"
    if not found:
        return TableFailure(f"table markers not found: no {layout['dictionary']} markers in the image; "
                            f"{need}; check that the table's markers are in view, lit and in focus",
                            time_ms=ms())
    rejected: list[RejectedMarker] = []
    obj: dict[int, np.ndarray] = {}
    img: dict[int, np.ndarray] = {}
    warnings = []
    reading = None
    # each marker's cells, read once for the gamma and for a clipped white's shift
    single = {i: cs[0] for i, cs in found.items() if i in by_id and len(cs) == 1}
    transitions = marker_transitions(gray, single, dic) if refine_corners else {}
    if read_gamma and refine_corners:
        reading = read_encoding_gamma(gray, single, dic, assumed=gamma, transitions=transitions)
        if reading.changed:
            warnings.append(reading.reason)
            gamma = reading.gamma
    lin = linearise(gray, gamma) if refine_corners else None
    edges: dict[int, list[np.ndarray]] = {}
    for i, cs in sorted(found.items()):
        if i not in by_id:
            rejected.append(RejectedMarker(i, f"id {i} is not in the table's layout", cs[0]))
            continue
        if len(cs) > 1:
            rejected.append(RejectedMarker(i, f"id {i} seen {len(cs)} times", cs[0]))
            continue
        c_ideal = None
        if refine_corners:
            got = refine_marker_corners(gray, cs[0], K, dist, dic.markerSize, gamma=gamma, linear=lin,
                                        return_edges=True,
                                        clip_bias_px=clipped_edge_bias_px(transitions[i], gamma) if i in transitions
                                        else 0.0)
            c_ideal = None
            if got is not None:
                c_ideal, edges[i] = got
            if c_ideal is None:
                warnings.append(f"marker {i}: border too small or cut off for line fits; "
                                "OpenCV's corners used")
        if c_ideal is None:
            c_ideal = undistort_px(cs[0], K, dist)
        obj[i] = marker_corners_table_mm(by_id[i])
        img[i] = c_ideal

    def fail(msg: str) -> TableFailure:
        corners = {i: distort_px(c, K, dist) for i, c in img.items()}
        return TableFailure(msg, seen, tuple(rejected), corners, ms())

    if len(obj) < min_markers:
        bad = [r for r in rejected if r.id in found]
        detail = ""
        if bad:
            detail = " (" + "; ".join(r.reason for r in bad) + ")"
        return fail(f"table markers not found: saw {_ids_text(seen)}{detail}; {need}")

    # Robust start: pose hypotheses from all markers jointly, from every pair of markers (SQPnP)
    # and from each marker alone (IPPE_SQUARE, both solutions); the hypothesis that explains the
    # most markers within a generous gate (then the lowest median residual) wins.
    gate_px = max(5 * max_marker_residual_px, 3.0)
    ids = sorted(obj)
    hyps: list[np.ndarray] = []
    groups = [ids] + ([[a, b] for k, a in enumerate(ids) for b in ids[k + 1:]] if len(ids) <= 24 else [])
    for g in groups:
        T = _solve_pnp(K, np.concatenate([obj[i] for i in g]), np.concatenate([img[i] for i in g]))
        if T is not None:
            hyps.append(T)
    for i in ids:
        s = float(np.linalg.norm(obj[i][1] - obj[i][0]))
        sq = np.array([[-s / 2, s / 2, 0], [s / 2, s / 2, 0], [s / 2, -s / 2, 0], [-s / 2, -s / 2, 0]])
        _, rvecs, tvecs, _ = cv2.solvePnPGeneric(sq, img[i], K, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
        T_mt = np.linalg.inv(check_pose(by_id[i]["T_table_marker"]))
        hyps += [rvec_tvec_to_pose(rv, tv) @ T_mt for rv, tv in zip(rvecs, tvecs)]
    best, best_key = None, None
    for T in hyps:
        rms = _marker_rms(K, T, obj, img)
        key = (-sum(v < gate_px for v in rms.values()), float(np.median(list(rms.values()))))
        if best_key is None or key < best_key:
            best, best_key = T, key
    use = [i for i, v in _marker_rms(K, best, obj, img).items() if v < gate_px]
    if len(use) < min_markers:
        use = list(obj)
    for i in obj:
        if i not in use:
            rejected.append(RejectedMarker(i, f"marker {i} disagrees with markers "
                                              f"{', '.join(map(str, use))} by more than {gate_px:.1f} px "
                                              "(moved or misdetected)", rough.get(i)))

    while True:
        P = np.concatenate([obj[i] for i in use])
        Q = np.concatenate([img[i] for i in use])
        T0 = _solve_pnp(K, P, Q)
        if T0 is None:
            T0 = best
        centroid = np.mean([obj[i].mean(axis=0) for i in use], axis=0)
        T, r, cov = _refine(K, P, Q, T0, centroid, min_corner_sigma_px)
        per = {i: float(np.sqrt(np.mean(np.sum(rr ** 2, axis=1))))
               for i, rr in zip(use, np.split(r, len(use)))}
        worst = max(per, key=per.get)
        others = [v for k, v in per.items() if k != worst]
        limit = max_marker_residual_px
        if len(others) >= 2:
            limit = max(min(limit, 5 * float(np.median(others))), 0.15)
        if per[worst] <= limit:
            break
        if len(use) - 1 < min_markers:
            return fail(f"table markers disagree: {_ids_text(sorted(use))} do not fit one table pose "
                        f"(marker {worst} off by {per[worst]:.2f} px RMS, allowed "
                        f"{max_marker_residual_px:.2f} px); a marker may have moved; {need}")
        rejected.append(RejectedMarker(worst, f"marker {worst} off by {per[worst]:.2f} px RMS "
                                              f"(allowed {limit:.2f} px): moved or misdetected",
                                       rough.get(worst)))
        use.remove(worst)

    fit_used = "corners"
    if final_fit == "edges" and all(i in edges for i in use):
        T, cov, _ = _refine_edges(K, T, obj, {i: edges[i] for i in use}, centroid, min_corner_sigma_px)
        fit_used = "edges"
        r = np.concatenate([_project_ideal(K, T, obj[i]) - img[i] for i in use])
        per = {i: float(np.sqrt(np.mean(np.sum((_project_ideal(K, T, obj[i]) - img[i]) ** 2, axis=1))))
               for i in use}
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    sigma_rot_deg = np.degrees(sig[:3])
    sigma_xyz = sig[3:]
    if not np.all(np.isfinite(sig)) or sigma_rot_deg.max() > max_sigma_rot_deg:
        worst_axis = "xyz"[int(np.nanargmax(np.where(np.isfinite(sigma_rot_deg), sigma_rot_deg, np.inf)))]
        return fail(f"table markers degenerate: {_ids_text(sorted(use))} fix the table's rotation about its "
                    f"{worst_axis} axis only to {float(np.max(sigma_rot_deg)):.2f} deg (1 sigma, allowed "
                    f"{max_sigma_rot_deg:.2f} deg); {need} spread over the table")
    if len(use) <= 3:
        warnings.append(f"only {len(use)} markers used: the pose is weaker, see sigma; an error of a marker's "
                        f"own placement is not measured with fewer than {MIN_JACKKNIFE_MARKERS}: the layout's "
                        "placement sigma is taken as stated")
    # the geometry was judged on the points' own scatter; what the markers share is stated on top:
    # their placement as the layout declares it, and at least what their disagreement shows
    final_edges = edges if fit_used == "edges" else None
    placed = placement_sigma(layout) if markers_placed is None else tuple(float(v) for v in markers_placed)
    # the final fit linearised once for the three responses below
    res, marker, side = _final_residuals(K, T, obj, img, final_edges, use, centroid)
    J_x = _fit_jacobian(res)
    p_jac = _placement_jacobian(K, T, obj, img, final_edges, sorted(use), centroid, J_x)
    cov = cov + placement_covariance(p_jac, placed)
    s_jac = None if side is None else _side_jacobian(side, J_x)
    if s_jac is not None:
        cov = cov + SIDE_OFFSET_PX ** 2 * s_jac @ s_jac.T
    jack = _marker_jackknife(use, marker, res(np.zeros(6)), J_x)
    if jack is not None:
        cov = at_least(cov, jack)
    sig = np.sqrt(np.clip(np.diag(cov), 0, None))
    sigma_rot_deg, sigma_xyz = np.degrees(sig[:3]), sig[3:]
    k_jac = None
    if intrinsics_sigma is not None:
        k_jac = _intrinsics_jacobian(K, dist, T, obj, img, final_edges, use, centroid, J_x)
    rms = float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))
    return TablePose(
        T_cam_table=T, ids_used=tuple(sorted(use)), ids_rejected=tuple(rejected), rms_px=rms,
        method=f"markers ({fit_used} fit)",
        residual_px=per, sigma_xyz_mm=sigma_xyz, sigma_rot_deg=sigma_rot_deg, covariance=cov,
        centroid_table_mm=centroid, corners_px={i: distort_px(img[i], K, dist) for i in use},
        time_ms=ms(), warnings=tuple(warnings), K=K, dist=dist, gamma=gamma, gamma_reading=reading,
        intrinsics_jacobian=k_jac, placement_sigma=placed, placement_jacobian=p_jac, side_jacobian=s_jac,
        intrinsics_sigma=None if intrinsics_sigma is None else tuple(float(v) for v in intrinsics_sigma))


# ---------------------------------------------------------------------------------------------
# Picture
# ---------------------------------------------------------------------------------------------

def draw_table(image: np.ndarray, result: TablePose | TableFailure, K: np.ndarray | None = None,
               dist: np.ndarray | None = None, axis_mm: float = 100.0) -> np.ndarray:
    """BGR picture: used markers green, rejected red (with ids and reasons' short form), and the
    table axes (x red, y green, z blue) when the pose and ``K`` are known."""
    out = image.copy() if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    style = style_for(out)
    th = style.thickness
    corners = getattr(result, "corners_px", {}) or {}
    for i, c in corners.items():
        pts = np.round(np.asarray(c) * 16).astype(np.int32)
        cv2.polylines(out, [pts], True, (0, 200, 0), th, cv2.LINE_AA, shift=4)
        put_label(out, str(i), tuple(np.round(np.asarray(c).mean(0)).astype(int)), (0, 200, 0), style)
    for rj in getattr(result, "ids_rejected", ()):
        if rj.corners_px is None:
            continue
        pts = np.round(np.asarray(rj.corners_px) * 16).astype(np.int32)
        cv2.polylines(out, [pts], True, (0, 0, 255), th, cv2.LINE_AA, shift=4)
        put_label(out, f"{rj.id}", tuple(np.round(rj.corners_px.mean(0)).astype(int)), (0, 0, 255), style)
    if result:
        K = result.K if K is None else K
        dist = result.dist if dist is None else dist
    if result and K is not None:
        rvec = Rotation.from_matrix(result.T_cam_table[:3, :3]).as_rotvec()
        cv2.drawFrameAxes(out, np.asarray(K, float), np.asarray(dist if dist is not None else np.zeros(5), float),
                          rvec, result.T_cam_table[:3, 3], axis_mm, th + 1)
    text = (f"table: {len(result.ids_used)} markers, RMS {result.rms_px:.2f} px" if result
            else result.reason)
    put_banner(out, text, (0, 200, 0) if result else (0, 0, 255))
    return out
