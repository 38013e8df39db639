"""Synthetic images of a circular target on a rotary axis, with an injected angle-error curve.

Frames (DESIGN.md convention, ``p_a = T_a_b @ p_b``, mm):

* ``axis``: the rotary axis; z along the axis (pointing towards the camera side), origin on it.
* ``tgt``: the printed target (see :mod:`app.vision.rotary_target`), fixed to the rotating table
  with an eccentricity and a small mounting tilt: ``T_axis_tgt(a) = Rz(a) @ T_axis_mount``.
* ``cam``: OpenCV camera, looking at the axis from ``camera_distance_mm`` with its optical axis
  tilted ``camera_tilt_deg`` away from the rotary axis.

The actual axis angle of image i is ``a_i = commanded_i + e(commanded_i, direction_i)`` with the
error curve ``e`` of :class:`ErrorCurve`; the ground truth of the measurement is therefore
``E_i = (c_i - c_0) - (a_i - a_0)`` (commanded increment minus actual increment, arc-seconds).

Rendering (anti-aliased, sub-pixel exact edges): for every pixel the ray through it (exact
inverse of OpenCV's lens model, :func:`app.vision.rotary.undistort_normalized`) is intersected
with the target plane. The printed pattern is a sum of filled discs (black/white steps at each
circle radius). Each step is blurred by a Gaussian PSF of ``blur_sigma_px`` and integrated over
the pixel's square area (``supersample``² sub-samples, or with ``supersample`` 1 a Gaussian of
variance 1/12 px² for the square); for that the step is treated as straight within a few pixels
(signed distance in pixels = radius difference / pixel-space gradient of the radius), which is
exact to first order in (pixel / radius of curvature). Then illumination gradient, Gaussian noise (linear light), gamma,
8-bit quantisation and optional JPEG.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from scipy.special import ndtr

from app.geometry.transforms import inv, make_pose, pose_from_xyz_euler
from app.vision.rotary import undistort_normalized
from app.vision.rotary_target import RotaryTarget


@dataclass(frozen=True)
class ErrorCurve:
    """Injected angular positioning error, arc-seconds: actual - commanded angle.

    ``e(a, dir) = amp1*sin(a + phase1) + amp2*sin(2a + phase2) + slope*a + dir*reversal/2``
    plus, per visit, Gaussian repeat noise of ``repeat_sigma_arcsec``. ``dir`` is +1 for an
    approach in the positive direction, -1 for the negative one.
    """

    amp1_arcsec: float = 8.0
    phase1_deg: float = 30.0
    amp2_arcsec: float = 3.0
    phase2_deg: float = -50.0
    slope_arcsec_per_deg: float = 0.02
    reversal_arcsec: float = 4.0
    repeat_sigma_arcsec: float = 0.0

    def error_arcsec(self, angle_deg: np.ndarray, direction: np.ndarray,
                     rng: np.random.Generator | None = None) -> np.ndarray:
        a = np.radians(np.asarray(angle_deg, dtype=float))
        d = np.asarray(direction, dtype=float)
        e = (self.amp1_arcsec * np.sin(a + math.radians(self.phase1_deg))
             + self.amp2_arcsec * np.sin(2 * a + math.radians(self.phase2_deg))
             + self.slope_arcsec_per_deg * np.degrees(a) + d * self.reversal_arcsec / 2.0)
        if self.repeat_sigma_arcsec > 0:
            rng = rng if rng is not None else np.random.default_rng(0)
            e = e + rng.normal(0.0, self.repeat_sigma_arcsec, size=np.shape(e))
        return e


@dataclass(frozen=True)
class RotaryScene:
    """Camera, mounting and image-formation parameters (lengths mm, angles deg, sigmas px)."""

    width: int = 1280
    height: int = 960
    K: tuple = ((1500.0, 0.0, 641.3), (0.0, 1500.0, 478.9), (0.0, 0.0, 1.0))
    dist: tuple = (-0.08, 0.05, 0.0004, -0.0003, 0.0)
    camera_distance_mm: float = 340.0
    camera_tilt_deg: float = 0.0
    camera_tilt_azimuth_deg: float = 20.0
    camera_roll_deg: float = 7.0
    look_offset_mm: tuple = (3.0, -2.0)
    eccentricity_mm: tuple = (1.2, -0.7)
    mount_tilt_deg: float = 0.15
    target_rotation0_deg: float = 11.0
    blur_sigma_px: float = 0.8
    supersample: int = 1
    white: float = 0.85
    black: float = 0.06
    background: float = 0.25
    illumination_gradient: float = 0.15
    noise_sigma: float = 0.01
    gamma: float = 2.2
    jpeg_quality: int | None = None

    @property
    def K_array(self) -> np.ndarray:
        return np.array(self.K, dtype=float)

    @property
    def dist_array(self) -> np.ndarray:
        return np.array(self.dist, dtype=float)

    def intrinsics_dict(self) -> dict:
        """The DESIGN.md intrinsics JSON of this camera."""
        return {"width": self.width, "height": self.height,
                "K": [list(r) for r in self.K], "dist": list(self.dist)}

    def T_cam_axis(self) -> np.ndarray:
        """Pose of the axis frame in the camera, shape (4, 4), mm."""
        t = math.radians(self.camera_tilt_deg)
        az = math.radians(self.camera_tilt_azimuth_deg)
        look = np.array([self.look_offset_mm[0], self.look_offset_mm[1], 0.0])
        p = look + self.camera_distance_mm * np.array([math.sin(t) * math.cos(az),
                                                       math.sin(t) * math.sin(az), math.cos(t)])
        z = (look - p) / np.linalg.norm(look - p)
        x0 = np.array([1.0, 0.0, 0.0])
        x = x0 - z * (x0 @ z)
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z], axis=1)
        T_axis_cam = make_pose(R, p) @ pose_from_xyz_euler(c_deg=self.camera_roll_deg)
        return inv(T_axis_cam)

    def T_axis_tgt(self, actual_deg: float) -> np.ndarray:
        """Pose of the target in the axis frame at the actual axis angle (deg)."""
        mount = (pose_from_xyz_euler(self.eccentricity_mm[0], self.eccentricity_mm[1], 0.0,
                                     a_deg=self.mount_tilt_deg, b_deg=0.4 * self.mount_tilt_deg)
                 @ pose_from_xyz_euler(c_deg=self.target_rotation0_deg))
        return pose_from_xyz_euler(c_deg=actual_deg) @ mount


@dataclass(frozen=True)
class RotaryShot:
    """One generated image with its exact ground truth.

    image : uint8 (H, W) grey image.
    commanded_deg, actual_deg : commanded and true axis angle, deg.
    direction : +1 / -1 approach direction.
    injected_error_arcsec : actual - commanded, arc-seconds.
    T_cam_tgt : (4, 4) true pose of the target in the camera, mm.
    """

    image: np.ndarray = field(repr=False)
    commanded_deg: float
    actual_deg: float
    direction: int
    injected_error_arcsec: float
    T_cam_tgt: np.ndarray = field(repr=False)


@functools.lru_cache(maxsize=4)
def _rays_for(width: int, height: int, K: tuple, dist: tuple) -> np.ndarray:
    """Undistorted normalised ray (x, y) of every pixel centre, shape (H, W, 2); cached, the
    benchmark renders many runs with one camera."""
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    m = undistort_normalized(np.stack([u.ravel(), v.ravel()], axis=1), np.array(K, float),
                             np.array(dist, float)).reshape(height, width, 2)
    m.flags.writeable = False  # shared by every caller of the cache
    return m


def _plane_coords(m: np.ndarray, T_cam_tgt: np.ndarray) -> np.ndarray:
    """Target-plane (x, y) mm hit by the ray of every pixel, shape (H, W, 2)."""
    R, t = T_cam_tgt[:3, :3], T_cam_tgt[:3, 3]
    n = R[:, 2]
    denom = m[..., 0] * n[0] + m[..., 1] * n[1] + n[2]
    s = (n @ t) / denom
    P = np.stack([m[..., 0] * s, m[..., 1] * s, s], axis=-1) - t
    return np.stack([P @ R[:, 0], P @ R[:, 1]], axis=-1)


def _coverage(xy: np.ndarray, J: np.ndarray, center: tuple[float, float], radii: list[float],
              sigma_px: float, offsets: np.ndarray, band_px: float) -> np.ndarray:
    """Blurred, pixel-integrated coverage of alternating filled discs about ``center``.

    xy : (h, w, 2) plane coordinates (mm) of the pixels; J : (h, w, 2, 2) d plane / d pixel.
    Returns ``sum_k (-1)^k * coverage(disc r_k)``, shape (h, w) (1 = inside the outermost black
    disc only). Near an edge (``band_px``) the coverage of a disc is the mean over the sub-pixel
    ``offsets`` of ``Phi(signed distance / sigma)``, the distance in pixels being
    ``(r_k - r) / |grad_px r|``.
    """
    dx = xy[..., 0] - center[0]
    dy = xy[..., 1] - center[1]
    r = np.hypot(dx, dy)
    with np.errstate(invalid="ignore", divide="ignore"):
        gx = (J[..., 0, 0] * dx + J[..., 1, 0] * dy) / r  # J^T (dx, dy) / r: mm per px
        gy = (J[..., 0, 1] * dx + J[..., 1, 1] * dy) / r
    g = np.maximum(np.nan_to_num(np.hypot(gx, gy), nan=1e-12), 1e-12)
    total = np.zeros(r.shape)
    for k, R in enumerate(radii):
        d0 = (R - r) / g  # px, positive inside the disc
        cov = (d0 > 0).astype(float)
        sel = np.abs(d0) < band_px
        if np.any(sel):
            nx, ny = gx[sel] / g[sel], gy[sel] / g[sel]
            t = nx[:, None] * offsets[None, :, 0] + ny[:, None] * offsets[None, :, 1]
            cov[sel] = ndtr((d0[sel][:, None] - t) / sigma_px).mean(axis=1)
        total += cov if k % 2 == 0 else -cov
    return total


def _bbox(scene: RotaryScene, T_cam_tgt: np.ndarray, center: tuple[float, float], radius_mm: float,
          margin_px: float) -> tuple[slice, slice]:
    """Pixel rows/cols (slices) holding the image of a circle, with a margin."""
    a = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    P = np.stack([center[0] + radius_mm * np.cos(a), center[1] + radius_mm * np.sin(a), 0 * a], axis=1)
    R, t = T_cam_tgt[:3, :3], T_cam_tgt[:3, 3]
    uv, _ = cv2.projectPoints(P, cv2.Rodrigues(R)[0], t, scene.K_array, scene.dist_array)
    uv = uv.reshape(-1, 2)
    u0, v0 = np.floor(uv.min(axis=0) - margin_px).astype(int)
    u1, v1 = np.ceil(uv.max(axis=0) + margin_px).astype(int)
    return (slice(max(v0, 0), min(v1 + 1, scene.height)), slice(max(u0, 0), min(u1 + 1, scene.width)))


def render_target(scene: RotaryScene, target: RotaryTarget, T_cam_tgt: np.ndarray,
                  rng: np.random.Generator) -> np.ndarray:
    """Render one grey uint8 image (H, W) of ``target`` at pose ``T_cam_tgt`` (mm).

    With ``supersample`` 1 the pixel's square aperture is folded into the Gaussian PSF
    (variance 1/12 px² per axis); otherwise it is integrated by supersample² samples.
    """
    rays = _rays_for(scene.width, scene.height, scene.K, scene.dist)
    ss = max(1, int(scene.supersample))
    o = (np.arange(ss) + 0.5) / ss - 0.5
    offsets = np.stack(np.meshgrid(o, o), axis=-1).reshape(-1, 2)
    sigma = max(scene.blur_sigma_px, 0.25)
    if ss == 1:
        sigma = math.sqrt(sigma ** 2 + 1.0 / 12.0)
    band = 6.0 * sigma + 2.0
    H, W = scene.height, scene.width
    lin = np.full((H, W), scene.background)
    disc_r = target.disc_radius_mm if target.disc_radius_mm is not None else target.extent_mm() + 5.0
    rows, cols = _bbox(scene, T_cam_tgt, (0.0, 0.0), disc_r, band + 2)
    xy = _plane_coords(rays[rows, cols], T_cam_tgt)
    J = np.empty(xy.shape[:2] + (2, 2))
    for i in range(2):
        dv, du = np.gradient(xy[..., i])
        J[..., i, 0] = du
        J[..., i, 1] = dv
    crop = scene.background + (scene.white - scene.background) * _coverage(
        xy, J, (0.0, 0.0), [disc_r], sigma, offsets, band)
    shapes = [(g.center_mm, list(g.circle_radii_mm)) for g in target.groups]
    if target.mark_mm is not None:
        shapes.append((target.mark_mm, [target.mark_radius_mm]))
    for center, radii in shapes:
        r2, c2 = _bbox(scene, T_cam_tgt, center, radii[0], band + 2)
        rr = slice(max(r2.start - rows.start, 0), max(r2.stop - rows.start, 0))
        cc = slice(max(c2.start - cols.start, 0), max(c2.stop - cols.start, 0))
        crop[rr, cc] -= (scene.white - scene.black) * _coverage(xy[rr, cc], J[rr, cc], center, radii,
                                                                sigma, offsets, band)
    lin[rows, cols] = crop
    u = np.arange(W) / W - 0.5
    lin = lin * (1.0 + scene.illumination_gradient * u[None, :])
    if scene.noise_sigma > 0:
        lin = lin + rng.normal(0.0, scene.noise_sigma, size=lin.shape)
    out = np.clip(lin, 0.0, 1.0) ** (1.0 / scene.gamma)
    img = np.clip(np.round(out * 255.0), 0, 255).astype(np.uint8)
    if scene.jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(scene.jpeg_quality)])
        img = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    return img


def iso_bidirectional_angles(targets_deg: list[float], repeats: int = 1) -> tuple[list[float], list[int]]:
    """ISO 230-2 style cycle: each repeat goes up through the targets (+1) then down (-1)."""
    angles: list[float] = []
    dirs: list[int] = []
    for _ in range(repeats):
        angles += list(targets_deg)
        dirs += [1] * len(targets_deg)
        angles += list(targets_deg[::-1])
        dirs += [-1] * len(targets_deg)
    return angles, dirs


def generate_run(target: RotaryTarget, angles_deg: list[float], directions: list[int] | None = None,
                 scene: RotaryScene | None = None, curve: ErrorCurve | None = None,
                 seed: int = 0) -> list[RotaryShot]:
    """Images of ``target`` at the commanded angles (deg) with the injected ``curve``.

    ``directions`` defaults to +1 where the angle rose from the previous one, else -1.
    """
    scene = scene if scene is not None else RotaryScene()
    curve = curve if curve is not None else ErrorCurve()
    rng = np.random.default_rng(seed)
    c = np.asarray(angles_deg, dtype=float)
    if directions is None:
        d = np.sign(np.diff(c, prepend=c[0] - 1.0))
        d[d == 0] = 1
        directions = d.astype(int).tolist()
    e = curve.error_arcsec(c, np.asarray(directions), rng)
    T_cam_axis = scene.T_cam_axis()
    shots = []
    for ci, di, ei in zip(c, directions, e):
        actual = float(ci + ei / 3600.0)
        T = T_cam_axis @ scene.T_axis_tgt(actual)
        img = render_target(scene, target, T, rng)
        shots.append(RotaryShot(img, float(ci), actual, int(di), float(ei), T))
    return shots


def true_errors_arcsec(shots: list[RotaryShot]) -> np.ndarray:
    """Ground truth E_i = commanded increment - actual increment (arc-seconds), E_0 = 0."""
    c = np.array([s.commanded_deg for s in shots])
    a = np.array([s.actual_deg for s in shots])
    return ((c - c[0]) - (a - a[0])) * 3600.0


def scaled_scene(scene: RotaryScene, width: int, height: int) -> RotaryScene:
    """The same view at another resolution (focal length scaled with the width, principal point
    kept at the same relative position)."""
    s = width / scene.width
    K = np.array(scene.K, dtype=float)
    K[0, 0] *= s
    K[1, 1] *= s
    K[0, 2] = (K[0, 2] + 0.5) * width / scene.width - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * height / scene.height - 0.5
    return replace(scene, width=width, height=height, K=tuple(tuple(r) for r in K.tolist()))
