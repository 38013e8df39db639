"""Scale on a cutting bed: the reference's mm-per-pixel and the proper bed-plane mapping.

Two ways to turn pixels into millimetres on a laser/plasma bed:

* **Reference method** (:func:`reference_scale`): 3 to 10 images of a rectangular plate of measured
  side lengths; one global mm/px per image from the plate's perimeter in pixels, averaged. It assumes
  a distortion-free camera looking straight down at the plate's height, so it is only right near the
  image centre and at the plate's thickness.
* **Proper method** (:class:`BedPlane`): intrinsics ``K``, ``dist`` and the bed pose ``T_cam_bed``
  (from markers or a board lying on the slat tips, see :func:`bed_pose_from_points`). A pixel is
  undistorted, turned into a ray and intersected with the plane ``z = height_mm`` of the bed frame
  (the sheet's top face is ``z = thickness_mm``; the slat tips are ``z = 0``). The local scale then
  varies across the image and with the thickness, as it does in the real camera.

Conventions: pixels ``uv_px`` are OpenCV (u right, v down, pixel centres at integer coordinates, so a
pixel is ``img[v, u]``). "Ideal" pixels are undistorted pinhole pixels with the same ``K``. The bed
frame has its origin at a front-left corner of the slat field, x along the long side, z up.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike

from app.geometry.transforms import check_pose, inv, rvec_tvec_to_pose
from app.vision.intrinsics import distort_px, undistort_px

# ---------------------------------------------------------------------------------------------------
# pixel <-> ideal pixel <-> bed plane


def plane_homography(K: np.ndarray, T_cam_bed: np.ndarray, height_mm: float) -> np.ndarray:
    """Homography ``H`` (3, 3) mapping bed (x_mm, y_mm) on the plane ``z = height_mm`` to ideal pixels.

    With ``T_cam_bed = [R | t]``, a bed point ``(x, y, h)`` is seen at ``K (x r1 + y r2 + h r3 + t)``,
    so ``H = K [r1, r2, h r3 + t]`` (Hartley & Zisserman, *Multiple View Geometry*, 2nd ed., eq. 8.1
    with the plane moved to ``z = h``).
    """
    R = T_cam_bed[:3, :3]
    t = T_cam_bed[:3, 3]
    return np.asarray(K, dtype=np.float64) @ np.column_stack([R[:, 0], R[:, 1], height_mm * R[:, 2] + t])


def _apply_h(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    q = np.concatenate([p, np.ones((len(p), 1))], axis=1) @ H.T
    return q[:, :2] / q[:, 2:3]


@dataclass(frozen=True)
class BedPlane:
    """Mapping between raw image pixels and bed millimetres on the plane ``z = height_mm``.

    Attributes
    ----------
    K : ndarray, shape (3, 3)
        Camera matrix (px).
    dist : ndarray, shape (5,) or more
        OpenCV distortion coefficients.
    T_cam_bed : ndarray, shape (4, 4)
        Pose of the bed frame in the camera frame, translation in mm.
    height_mm : float
        Height of the plane above the slat tips: the sheet thickness for the sheet's top face.
    """

    K: np.ndarray
    dist: np.ndarray
    T_cam_bed: np.ndarray
    height_mm: float = 0.0

    @staticmethod
    def create(K: ArrayLike, dist: ArrayLike, T_cam_bed: ArrayLike, height_mm: float = 0.0) -> "BedPlane":
        """Validate the inputs (``check_pose``, plane in front of the camera) and build the mapping."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"K: expected shape (3, 3), got {K.shape}")
        T = check_pose(T_cam_bed, "T_cam_bed", tol=1e-5)
        if not 0.0 <= float(height_mm) <= 200.0:
            raise ValueError(f"plane height {height_mm} mm is outside 0..200 mm; give the sheet thickness in mm")
        plane = BedPlane(K, np.asarray(dist, dtype=np.float64).ravel(), T, float(height_mm))
        cam_in_bed = inv(T)[:3, 3]
        if cam_in_bed[2] <= plane.height_mm:
            raise ValueError(
                f"camera is {cam_in_bed[2]:.1f} mm above the bed, not above the plane z = {height_mm} mm; "
                "check T_cam_bed (bed z must point up, towards the camera)"
            )
        return plane

    @property
    def H(self) -> np.ndarray:
        """Homography bed (x, y) mm on the plane -> ideal px."""
        return plane_homography(self.K, self.T_cam_bed, self.height_mm)

    def at_height(self, height_mm: float) -> "BedPlane":
        """The same camera and bed, another plane height (e.g. slat tips at 0 vs sheet top)."""
        return BedPlane(self.K, self.dist, self.T_cam_bed, float(height_mm))

    def ideal_to_bed(self, uv_ideal_px: ArrayLike) -> np.ndarray:
        """Ideal pixels (N, 2) -> bed (x_mm, y_mm) (N, 2) on the plane."""
        return _apply_h(np.linalg.inv(self.H), uv_ideal_px)

    def px_to_bed(self, uv_px: ArrayLike) -> np.ndarray:
        """Raw pixels (N, 2) -> bed (x_mm, y_mm) (N, 2) on the plane."""
        return self.ideal_to_bed(undistort_px(uv_px, self.K, self.dist))

    def bed_to_ideal(self, xy_mm: ArrayLike) -> np.ndarray:
        """Bed (x_mm, y_mm) (N, 2) on the plane -> ideal pixels (N, 2)."""
        return _apply_h(self.H, xy_mm)

    def bed_to_px(self, xy_mm: ArrayLike) -> np.ndarray:
        """Bed (x_mm, y_mm) (N, 2) on the plane -> raw pixels (N, 2)."""
        return distort_px(self.bed_to_ideal(xy_mm), self.K, self.dist)

    def mm_per_px(self, uv_px: ArrayLike, step_px: float = 0.5) -> np.ndarray:
        """Local scale (N,) in mm/px at raw pixels: ``sqrt(|det J|)`` of the px -> mm map.

        ``J`` is the 2x2 Jacobian d(x_mm, y_mm)/d(u, v), by central differences of ``step_px``; the
        square root of its determinant is the side of the bed square that one pixel covers.
        """
        uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
        du = np.array([step_px, 0.0])
        dv = np.array([0.0, step_px])
        ju = (self.px_to_bed(uv + du) - self.px_to_bed(uv - du)) / (2 * step_px)
        jv = (self.px_to_bed(uv + dv) - self.px_to_bed(uv - dv)) / (2 * step_px)
        det = ju[:, 0] * jv[:, 1] - ju[:, 1] * jv[:, 0]
        return np.sqrt(np.abs(det))


# ---------------------------------------------------------------------------------------------------
# bed pose from known points on the bed


@dataclass(frozen=True)
class BedPose:
    """``T_cam_bed`` from points of known bed position, with the reprojection residual."""

    T_cam_bed: np.ndarray
    rms_px: float
    max_px: float
    n_points: int


def bed_pose_from_points(
    uv_px: ArrayLike, xyz_bed_mm: ArrayLike, K: ArrayLike, dist: ArrayLike
) -> BedPose:
    """Pose of the bed in the camera from >= 4 points (markers, board corners) of known bed position.

    Parameters
    ----------
    uv_px : array-like, shape (N, 2)
        Raw image pixels of the points.
    xyz_bed_mm : array-like, shape (N, 3) or (N, 2)
        Their bed coordinates (mm); (N, 2) means on the slat tips, z = 0.
    K, dist : camera intrinsics (OpenCV model).

    Uses ``cv2.solvePnP`` (IPPE for coplanar points, then Levenberg-Marquardt refinement).
    """
    uv = np.asarray(uv_px, dtype=np.float64).reshape(-1, 2)
    xyz = np.asarray(xyz_bed_mm, dtype=np.float64)
    if xyz.ndim == 2 and xyz.shape[1] == 2:
        xyz = np.concatenate([xyz, np.zeros((len(xyz), 1))], axis=1)
    xyz = xyz.reshape(-1, 3)
    if len(uv) != len(xyz) or len(uv) < 4:
        raise ValueError(f"need >= 4 matching points for the bed pose, got {len(uv)} pixels and {len(xyz)} bed points")
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    planar = np.ptp(xyz[:, 2]) < 1e-9
    flag = cv2.SOLVEPNP_IPPE if planar else cv2.SOLVEPNP_ITERATIVE
    ok, rvec, tvec = cv2.solvePnP(xyz, uv, K, dist, flags=flag)
    if not ok:
        raise ValueError("bed pose not found: solvePnP failed on the given points; check their order and bed coordinates")
    rvec, tvec = cv2.solvePnPRefineLM(xyz, uv, K, dist, rvec, tvec)
    proj, _ = cv2.projectPoints(xyz, rvec, tvec, K, dist)
    err = np.linalg.norm(proj.reshape(-1, 2) - uv, axis=1)
    return BedPose(rvec_tvec_to_pose(rvec, tvec), float(np.sqrt(np.mean(err**2))), float(err.max()), len(uv))


# ---------------------------------------------------------------------------------------------------
# the two scale methods on a measured plate


def _side_lengths(corners: np.ndarray) -> np.ndarray:
    """Lengths (4,) of the sides 0-1, 1-2, 2-3, 3-0 of a quadrilateral (4, 2)."""
    return np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)


def _check_plate(corners_px_per_image: ArrayLike, side_a_mm: float, side_b_mm: float) -> np.ndarray:
    c = np.asarray(corners_px_per_image, dtype=np.float64)
    if c.ndim == 2:
        c = c[None]
    if c.ndim != 3 or c.shape[1:] != (4, 2):
        raise ValueError(f"plate corners: expected shape (n, 4, 2) px, got {c.shape}")
    if not 3 <= len(c) <= 10:
        raise ValueError(f"the reference scale needs 3 to 10 images of the plate, got {len(c)}")
    if side_a_mm <= 0 or side_b_mm <= 0:
        raise ValueError(f"plate sides must be positive mm, got {side_a_mm} x {side_b_mm}")
    return c


@dataclass(frozen=True)
class ScaleReport:
    """Scale from a measured rectangular plate, and how well it reproduces the plate's sides.

    Attributes
    ----------
    method : str
        "reference perimeter" or "bed plane".
    mm_per_px : float
        The reference method's single factor; for the bed plane the local scale at the image centre.
    mm_per_px_per_image : ndarray, shape (n,)
        Per image: perimeter_mm / perimeter_px (reference) or the mean local scale over the plate's
        corners (bed plane).
    side_residuals_mm : ndarray, shape (n, 4)
        Measured side length minus the plate's true length, per image and side (0-1, 1-2, 2-3, 3-0;
        sides 0-1 and 2-3 have length ``side_a_mm``).
    rms_mm, max_abs_mm : float
        Over all sides of all images.
    """

    method: str
    mm_per_px: float
    mm_per_px_per_image: np.ndarray
    side_residuals_mm: np.ndarray
    rms_mm: float
    max_abs_mm: float

    def as_dict(self) -> dict:
        return {
            "method": self.method,
            "mm_per_px": self.mm_per_px,
            "mm_per_px_per_image": [float(x) for x in self.mm_per_px_per_image],
            "side_residuals_mm": np.round(self.side_residuals_mm, 4).tolist(),
            "rms_mm": self.rms_mm,
            "max_abs_mm": self.max_abs_mm,
        }


def _report(method: str, mm_per_px: float, per_image: np.ndarray, measured_mm: np.ndarray, a: float, b: float) -> ScaleReport:
    truth = np.array([a, b, a, b])
    res = measured_mm - truth[None, :]
    return ScaleReport(method, float(mm_per_px), per_image, res, float(np.sqrt(np.mean(res**2))), float(np.abs(res).max()))


def reference_scale(corners_px_per_image: ArrayLike, side_a_mm: float, side_b_mm: float) -> ScaleReport:
    """The reference's scale: mm/px = plate perimeter (mm) / plate perimeter (px), averaged over images.

    Parameters
    ----------
    corners_px_per_image : array-like, shape (n, 4, 2), 3 <= n <= 10
        The plate's corners (raw px) in each image, in order around the plate, the side 0-1 being
        ``side_a_mm`` long.
    side_a_mm, side_b_mm : float
        The plate's measured side lengths.

    Residuals are the plate sides measured with this single factor minus their true lengths.
    """
    c = _check_plate(corners_px_per_image, side_a_mm, side_b_mm)
    sides_px = np.stack([_side_lengths(q) for q in c])
    per_image = 2.0 * (side_a_mm + side_b_mm) / sides_px.sum(axis=1)
    k = float(per_image.mean())
    return _report("reference perimeter", k, per_image, sides_px * k, side_a_mm, side_b_mm)


def bed_plane_scale(
    corners_px_per_image: ArrayLike, side_a_mm: float, side_b_mm: float, plane: BedPlane,
    image_size: tuple[int, int] | None = None,
) -> ScaleReport:
    """The proper scale: plate corners mapped onto the bed plane ``z = plane.height_mm``.

    Same input as :func:`reference_scale`; ``plane`` should be at the plate's thickness. Residuals are
    the plate sides measured on the bed plane minus their true lengths. ``mm_per_px`` is the local
    scale at the image centre (``image_size`` = (width, height) px; default: the principal point).
    """
    c = _check_plate(corners_px_per_image, side_a_mm, side_b_mm)
    measured = np.stack([_side_lengths(plane.px_to_bed(q)) for q in c])
    per_image = np.array([plane.mm_per_px(q).mean() for q in c])
    centre = plane.K[:2, 2] if image_size is None else (np.asarray(image_size, dtype=float) - 1.0) / 2.0
    return _report("bed plane", float(plane.mm_per_px(centre)[0]), per_image, measured, side_a_mm, side_b_mm)


@dataclass(frozen=True)
class ScaleComparison:
    """Both methods on the same plate images, plus how much the bed-plane scale varies over the image."""

    reference: ScaleReport
    bed_plane: ScaleReport
    mm_per_px_min: float
    mm_per_px_max: float

    def as_dict(self) -> dict:
        return {
            "reference": self.reference.as_dict(),
            "bed_plane": self.bed_plane.as_dict(),
            "bed_plane_mm_per_px_range": [self.mm_per_px_min, self.mm_per_px_max],
        }


def compare_scales(
    corners_px_per_image: ArrayLike, side_a_mm: float, side_b_mm: float, plane: BedPlane,
    image_size: tuple[int, int],
) -> ScaleComparison:
    """Run :func:`reference_scale` and :func:`bed_plane_scale`; report the local scale's range.

    The range is over a 9 x 7 grid of raw pixels covering ``image_size`` = (width, height).
    """
    w, h = image_size
    uu, vv = np.meshgrid(np.linspace(0, w - 1, 9), np.linspace(0, h - 1, 7))
    local = plane.mm_per_px(np.stack([uu.ravel(), vv.ravel()], axis=1))
    return ScaleComparison(
        reference_scale(corners_px_per_image, side_a_mm, side_b_mm),
        bed_plane_scale(corners_px_per_image, side_a_mm, side_b_mm, plane, image_size),
        float(local.min()), float(local.max()),
    )


__all__ = [
    "BedPlane", "BedPose", "ScaleComparison", "ScaleReport", "bed_plane_scale", "bed_pose_from_points",
    "compare_scales", "distort_px", "plane_homography", "reference_scale", "undistort_px",
]
