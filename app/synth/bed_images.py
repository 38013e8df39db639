"""Generated camera images of a slatted laser/plasma bed with a sheet on it, with exact ground truth.

The scene is rendered per pixel by ray casting, so the ground truth is the real camera model:
every pixel's ray (OpenCV intrinsics with distortion, undistorted by ``cv2.undistortPoints``) is
intersected with

* the slats: vertical plates along bed y at ``x = k * slat_pitch_mm``, ``slat_width_mm`` thick, whose
  top edge carries teeth (tips at z = 0, the slat-tip plane of the bed frame), marched in depth;
* the floor under the slats (slag texture);
* scrap parts lying on the slats (convex polygons at ``z = thickness_mm``);
* the sheet: its top face at ``z = thickness_mm`` and its side faces down to the slat tips, which
  the camera sees on the sides facing it.

Edges of the sheet and the scrap parts are anti-aliased analytically: the signed distance of a
pixel centre to each polygon edge is converted from mm to px with the local Jacobian of the
pixel -> plane map, and the pixel's coverage is ``clip(0.5 - d_px, 0, 1)`` (a box pixel on a
straight edge), so the 50 % level lies exactly on the true edge. Then come a soft shadow of the
sheet on the bed, optional soft shadows across everything (gantry), Gaussian blur, Gaussian noise
and JPEG, all seeded.

Frames and units: bed frame as in DESIGN.md and issue 6 (origin at a front-left corner of the slat
field, x along the long side, z up, slat tips at z = 0), mm; pixels OpenCV (u right, v down,
pixel centres at integer coordinates). Corners are ordered nearest-to-origin first, then
counter-clockwise seen from above.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import cv2
import numpy as np
from numpy.typing import ArrayLike

from app.geometry.transforms import inv, make_pose, pose_to_rvec_tvec

VARIANTS = ("plain", "shadows", "scrap", "bright", "flat")


@dataclass(frozen=True)
class BedCamera:
    """A camera over the bed: intrinsics (OpenCV model) and ``T_cam_bed`` (mm)."""

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray
    T_cam_bed: np.ndarray

    def intrinsics_dict(self) -> dict:
        """The DESIGN.md intrinsics file content."""
        return {"width": self.width, "height": self.height, "K": self.K.tolist(), "dist": self.dist.tolist()}


def bed_camera(
    width_px: int = 1600,
    height_px: int = 1200,
    mm_per_px: float = 0.5,
    target_bed_mm: tuple[float, float] = (650.0, 420.0),
    tilt_deg: float = 12.0,
    azimuth_deg: float = -90.0,
    roll_deg: float = 0.0,
    dist: ArrayLike = (-0.08, 0.03, 0.0005, -0.0003, 0.0),
    focal_factor: float = 1.3,
) -> BedCamera:
    """A camera looking down at ``target_bed_mm`` with a scale of about ``mm_per_px`` there.

    ``f = focal_factor * width_px``; the distance to the target is ``f * mm_per_px``. The camera
    leans ``tilt_deg`` from vertical, standing on the side ``azimuth_deg`` (bed frame, -90 = in front
    of the target, towards -y). Image u runs roughly along bed +x and v along bed -y, turned by
    ``roll_deg``.
    """
    f = focal_factor * width_px
    K = np.array([[f, 0.0, (width_px - 1) / 2.0 + 3.0], [0.0, f, (height_px - 1) / 2.0 - 2.0], [0.0, 0.0, 1.0]])
    dist_mm = f * mm_per_px
    tilt, az, roll = np.radians([tilt_deg, azimuth_deg, roll_deg])
    target = np.array([target_bed_mm[0], target_bed_mm[1], 0.0])
    eye = target + dist_mm * np.array([np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)])
    z_cam = (target - eye) / np.linalg.norm(target - eye)
    x_ref = np.array([np.cos(roll), np.sin(roll), 0.0])
    x_cam = x_ref - (x_ref @ z_cam) * z_cam
    x_cam /= np.linalg.norm(x_cam)
    y_cam = np.cross(z_cam, x_cam)
    T_bed_cam = make_pose(np.column_stack([x_cam, y_cam, z_cam]), eye)
    return BedCamera(width_px, height_px, K, np.asarray(dist, dtype=float), inv(T_bed_cam))


@dataclass(frozen=True)
class BedScene:
    """What lies on the bed. The sheet's local corner (0, 0) sits at ``sheet_xy_mm``; the sheet is
    turned by ``sheet_angle_deg`` about it (counter-clockwise seen from above)."""

    sheet_size_mm: tuple[float, float] = (500.0, 350.0)
    sheet_xy_mm: tuple[float, float] = (400.0, 250.0)
    sheet_angle_deg: float = 2.0
    thickness_mm: float = 3.0
    variant: str = "plain"
    n_scrap: int = 0
    slat_pitch_mm: float = 50.0
    slat_width_mm: float = 3.0
    slat_x0_mm: float = 12.0
    tooth_pitch_mm: float = 25.0
    tooth_depth_mm: float = 10.0
    seed: int = 0

    def sheet_corners_mm(self) -> np.ndarray:
        """The sheet's corners (4, 2) bed mm, nearest to the bed origin first, counter-clockwise."""
        w, h = self.sheet_size_mm
        a = np.radians(self.sheet_angle_deg)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        local = np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])
        c = local @ R.T + np.asarray(self.sheet_xy_mm, dtype=float)
        k = int(np.argmin(np.linalg.norm(c, axis=1)))
        return np.roll(c, -k, axis=0)


def scene_variant(name: str, **kwargs) -> BedScene:
    """A :class:`BedScene` for one of ``VARIANTS``: plain, shadows, scrap (parts near the sheet),
    bright (a bright sheet on a bright bed), flat (a dark flat plate, no slats)."""
    if name not in VARIANTS:
        raise ValueError(f"unknown bed scene variant {name!r}; use one of {', '.join(VARIANTS)}")
    if name == "scrap":
        kwargs.setdefault("n_scrap", 6)
    return BedScene(variant=name, **kwargs)


@dataclass(frozen=True)
class BedImage:
    """A rendered image and its ground truth.

    image : ndarray (H, W, 3) uint8 BGR
    corners_px : ndarray (4, 2), raw image pixels of the sheet's top corners (exact projection)
    corners_bed_mm : ndarray (4, 2), bed (x, y) of the same corners, at z = thickness_mm
    angle_deg : float, direction of the edge corner 0 -> corner 1 against bed x
    """

    image: np.ndarray
    corners_px: np.ndarray
    corners_bed_mm: np.ndarray
    angle_deg: float
    camera: BedCamera
    scene: BedScene
    scrap_polygons_mm: tuple = field(default=())


# ---------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Rays:
    origin: np.ndarray  # (3,) camera centre in bed mm
    dirs: np.ndarray  # (H, W, 3) ray directions in the bed frame (z component < 0)

    def plane(self, z_mm: float) -> np.ndarray:
        """(H, W, 2) bed xy where each pixel's ray meets the plane z = z_mm."""
        s = (z_mm - self.origin[2]) / self.dirs[..., 2]
        return (self.origin[:2] + s[..., None] * self.dirs[..., :2]).astype(np.float32)


def _rays(cam: BedCamera) -> _Rays:
    u, v = np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64))
    uv = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    xn = cv2.undistortPoints(uv, cam.K, cam.dist).reshape(cam.height, cam.width, 2)
    d_cam = np.concatenate([xn, np.ones((cam.height, cam.width, 1))], axis=2)
    T_bed_cam = inv(cam.T_cam_bed)
    dirs = d_cam @ T_bed_cam[:3, :3].T
    return _Rays(T_bed_cam[:3, 3].copy(), dirs)


def _jacobian(xy: np.ndarray) -> tuple[np.ndarray, ...]:
    """d(x, y)/d(u, v) of a per-pixel plane map (H, W, 2): (dx/du, dx/dv, dy/du, dy/dv)."""
    dxdv, dxdu = np.gradient(xy[..., 0])
    dydv, dydu = np.gradient(xy[..., 1])
    return dxdu, dxdv, dydu, dydv


def _convex_coverage(xy: np.ndarray, jac: tuple[np.ndarray, ...], poly_mm: np.ndarray) -> np.ndarray:
    """Anti-aliased coverage (H, W) in [0, 1] of a convex counter-clockwise polygon (M, 2) mm.

    Per edge: outward signed distance f (mm) of the pixel centre, over |grad_uv f| (mm/px), gives the
    distance in px; the box-pixel coverage of a straight edge is clip(0.5 - d_px, 0, 1). The product
    over edges is exact away from the corners.
    """
    dxdu, dxdv, dydu, dydv = jac
    cov = np.zeros(xy.shape[:2], dtype=np.float32)
    lo = poly_mm.min(axis=0) - 20.0
    hi = poly_mm.max(axis=0) + 20.0
    near = (xy[..., 0] > lo[0]) & (xy[..., 0] < hi[0]) & (xy[..., 1] > lo[1]) & (xy[..., 1] < hi[1])
    rows = np.flatnonzero(near.any(axis=1))
    cols = np.flatnonzero(near.any(axis=0))
    if len(rows) == 0 or len(cols) == 0:
        return cov
    win = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    x, y = xy[win][..., 0], xy[win][..., 1]
    c = np.ones(x.shape, dtype=np.float32)
    for a, b in zip(poly_mm, np.roll(poly_mm, -1, axis=0)):
        e = b - a
        n = np.array([e[1], -e[0]]) / np.linalg.norm(e)  # outward for a CCW polygon
        f = (x - a[0]) * n[0] + (y - a[1]) * n[1]
        g = np.hypot(n[0] * dxdu[win] + n[1] * dydu[win], n[0] * dxdv[win] + n[1] * dydv[win])
        c *= np.clip(0.5 - f / np.maximum(g, 1e-9), 0.0, 1.0)
    cov[win] = c
    return cov


def _value_noise(xy: np.ndarray, cell_mm: float, rng: np.random.Generator, amplitude: float) -> np.ndarray:
    """Smooth random texture (H, W) in bed coordinates: bilinear value noise of ``cell_mm`` cells."""
    sub = xy[::8, ::8].reshape(-1, 2)
    lo = sub.min(axis=0) - 8 * cell_mm
    hi = sub.max(axis=0) + 8 * cell_mm
    n = np.ceil((hi - lo) / cell_mm).astype(int) + 2
    n = np.minimum(n, 4000)
    grid = rng.normal(0.0, amplitude, size=(n[1], n[0])).astype(np.float32)
    cx = ((xy[..., 0] - lo[0]) / cell_mm).astype(np.float32)
    cy = ((xy[..., 1] - lo[1]) / cell_mm).astype(np.float32)
    return cv2.remap(grid, cx, cy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


_LEVELS = {  # grey levels: floor, slat, sheet; strength of the sheet's shadow on the bed
    "plain": (38.0, 120.0, 190.0, 0.45),
    "shadows": (38.0, 120.0, 190.0, 0.45),
    "scrap": (38.0, 120.0, 190.0, 0.45),
    "bright": (165.0, 185.0, 212.0, 0.85),
    "flat": (40.0, 40.0, 190.0, 0.45),
}


def _background(scene: BedScene, rays: _Rays, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Slats and floor: grey values (H, W) and the hit points (H, W, 3) in bed mm.

    The ray is marched down in depth steps, only for pixels whose ray passes through a slat's slab
    between the slat tips and the slat bottom (xy(z) = a + z b is linear in z).
    """
    floor_val, slat_val, _, _ = _LEVELS[scene.variant]
    slat_h, floor_z = 80.0, -260.0
    shape = rays.dirs.shape[:2]
    if scene.variant == "flat":  # a dark plate instead of slats: the reference method's conditions
        slat_h, floor_z = 1.0, 0.0
    b = (rays.dirs[..., :2] / rays.dirs[..., 2:3]).reshape(-1, 2).astype(np.float32)
    a = (rays.origin[:2] - rays.origin[2] * b).astype(np.float32)
    x_top = a[:, 0]
    x_bot = a[:, 0] - slat_h * b[:, 0]
    lo = np.minimum(x_top, x_bot) - scene.slat_x0_mm - scene.slat_width_mm
    hi = np.maximum(x_top, x_bot) - scene.slat_x0_mm
    cand = np.flatnonzero(np.floor(hi / scene.slat_pitch_mm) >= np.ceil(lo / scene.slat_pitch_mm))
    if scene.variant == "flat":
        cand = cand[:0]
    ac, bc = a[cand], b[cand]
    hit_c = np.full(len(cand), np.nan, dtype=np.float32)
    for z in np.linspace(0.0, -slat_h, 33, dtype=np.float32):
        x = ac[:, 0] + z * bc[:, 0]
        y = ac[:, 1] + z * bc[:, 1]
        phase = np.mod(y, scene.tooth_pitch_mm) / scene.tooth_pitch_mm
        top = -scene.tooth_depth_mm * np.clip(1.0 - np.abs(phase - 0.5) / 0.32, 0.0, 1.0)
        occ = (np.mod(x - scene.slat_x0_mm, scene.slat_pitch_mm) < scene.slat_width_mm) & (z <= top + 1e-6)
        hit_c[occ & np.isnan(hit_c)] = z
    hit_z = np.full(shape[0] * shape[1], np.nan, dtype=np.float32)
    hit_z[cand] = hit_c
    hit_z = hit_z.reshape(shape)
    on_slat = ~np.isnan(hit_z)
    hit_z = np.where(on_slat, hit_z, floor_z)
    hit_xy = (a + hit_z.reshape(-1, 1) * b).reshape(shape + (2,))
    hit = np.concatenate([hit_xy, hit_z[..., None]], axis=2)
    slag = _value_noise(hit_xy, 4.0, rng, 0.12) + _value_noise(hit_xy, 40.0, rng, 0.08)
    depth = -hit_z / slat_h
    val = np.where(on_slat, slat_val * (1.0 - 0.45 * depth) * (1.0 + slag), floor_val * (1.0 + 1.5 * slag))
    return val.astype(np.float32), hit


def _scrap_polygons(scene: BedScene, rng: np.random.Generator) -> list[np.ndarray]:
    """Convex scrap parts (CCW, bed mm) placed close to the sheet's edges without overlapping it."""
    from shapely.geometry import Polygon

    sheet = Polygon(scene.sheet_corners_mm())
    corners = scene.sheet_corners_mm()
    out: list[np.ndarray] = []
    tries = 0
    while len(out) < scene.n_scrap and tries < 400:
        tries += 1
        k = int(rng.integers(4))
        a, b = corners[k], corners[(k + 1) % 4]
        t = rng.uniform(0.15, 0.85)
        e = (b - a) / np.linalg.norm(b - a)
        n_out = np.array([e[1], -e[0]])
        size = rng.uniform(25.0, 90.0)
        gap = rng.choice([rng.uniform(0.3, 3.0), rng.uniform(3.0, 25.0)])
        centre = a + t * (b - a) + n_out * (gap + size / 2)
        m = int(rng.integers(4, 7))
        ang = np.sort(rng.uniform(0, 2 * np.pi, m))
        rad = size / 2 * rng.uniform(0.7, 1.0, m)
        pts = centre + np.stack([rad * np.cos(ang), rad * np.sin(ang)], axis=1)
        poly = Polygon(pts).convex_hull
        if poly.area < 200 or poly.distance(sheet) < 0.3 or any(poly.distance(Polygon(q)) < 2 for q in out):
            continue
        q = np.asarray(poly.exterior.coords)[:-1]
        if Polygon(q).exterior.is_ccw is False:
            q = q[::-1]
        out.append(q)
    return out


def _render(
    scene: BedScene, cam: BedCamera, rays: _Rays, rng: np.random.Generator,
    noise_sigma: float, blur_sigma_px: float, jpeg_quality: int | None, scrap: list[np.ndarray],
) -> np.ndarray:
    floor_val, _, sheet_val, shadow_k = _LEVELS[scene.variant]
    t = scene.thickness_mm
    corners = scene.sheet_corners_mm()
    val, hit = _background(scene, rays, rng)

    # soft shadow of the sheet on the bed, light from above-behind-right
    light = np.array([0.25, 0.35, 1.0])
    sxy = hit[..., :2] + (t - hit[..., 2:3]) * light[:2] / light[2]
    d = np.stack([sxy[..., 0], sxy[..., 1]], axis=-1)
    ones = (np.full(d.shape[:2], 8.0),) * 2
    in_shadow = _convex_coverage(d, (ones[0], np.zeros_like(ones[0]), np.zeros_like(ones[0]), ones[1]), corners)
    val = val * (1.0 - (1.0 - shadow_k) * in_shadow)

    top_xy = rays.plane(t)
    jac_top = _jacobian(top_xy)
    for q in scrap:
        c = _convex_coverage(top_xy, jac_top, q)
        tone = sheet_val * rng.uniform(0.85, 1.02) * (1.0 + _value_noise(top_xy, 30.0, rng, 0.02))
        val = val * (1.0 - c) + c * tone

    bot_xy = rays.plane(0.0)
    cov_top = _convex_coverage(top_xy, jac_top, corners)
    cov_bot = _convex_coverage(bot_xy, _jacobian(bot_xy), corners)
    side = np.clip(cov_bot - cov_top, 0.0, 1.0)
    gx = (top_xy[..., 0] - corners[0, 0]) / max(scene.sheet_size_mm)
    surface = sheet_val * (1.0 + 0.04 * gx + _value_noise(top_xy, 60.0, rng, 0.015) + _value_noise(top_xy, 2.0, rng, 0.008))
    val = val * (1.0 - cov_top - side) + side * 0.55 * sheet_val + cov_top * surface

    if scene.variant == "shadows":  # soft shadows of the gantry and the head across sheet and bed
        for _ in range(2):
            p = corners[int(rng.integers(4))] + rng.uniform(-60, 60, 2)
            a = rng.uniform(0, np.pi)
            n = np.array([np.cos(a), np.sin(a)])
            dist_mm = (top_xy[..., 0] - p[0]) * n[0] + (top_xy[..., 1] - p[1]) * n[1]
            width = rng.uniform(80, 200)
            band = _smoothstep((dist_mm + 40) / 80) * _smoothstep((width + 40 - dist_mm) / 80)
            val = val * (1.0 - 0.45 * band)

    img = np.stack([val * 0.96, val, val * 1.03], axis=-1)
    if blur_sigma_px > 0:
        img = cv2.GaussianBlur(img, (0, 0), blur_sigma_px)
    img = img + rng.normal(0.0, noise_sigma, img.shape)
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    if jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return img


def _truth(scene: BedScene, cam: BedCamera) -> tuple[np.ndarray, np.ndarray, float]:
    c = scene.sheet_corners_mm()
    xyz = np.concatenate([c, np.full((4, 1), scene.thickness_mm)], axis=1)
    rvec, tvec = pose_to_rvec_tvec(cam.T_cam_bed)
    px, _ = cv2.projectPoints(xyz, rvec, tvec, cam.K, cam.dist)
    e = c[1] - c[0]
    return px.reshape(4, 2), c, float(np.degrees(np.arctan2(e[1], e[0])))


def render_bed_image(
    scene: BedScene,
    camera: BedCamera,
    noise_sigma: float = 2.0,
    blur_sigma_px: float = 0.7,
    jpeg_quality: int | None = 92,
) -> BedImage:
    """Render ``scene`` through ``camera``; seeded by ``scene.seed``.

    Raises ``ValueError`` when a sheet corner is outside the image (the generator never returns a
    picture whose ground truth cannot be seen).
    """
    rng = np.random.default_rng(scene.seed)
    px, mm, ang = _truth(scene, camera)
    margin = 5.0
    if np.any(px < margin) or np.any(px[:, 0] > camera.width - 1 - margin) or np.any(px[:, 1] > camera.height - 1 - margin):
        raise ValueError(f"sheet corner outside the image: corners at {np.round(px, 1).tolist()} px, image {camera.width} x {camera.height}")
    scrap = _scrap_polygons(scene, rng) if scene.n_scrap else []
    img = _render(scene, camera, _rays(camera), rng, noise_sigma, blur_sigma_px, jpeg_quality, scrap)
    return BedImage(img, px, mm, ang, camera, scene, tuple(scrap))


# ---------------------------------------------------------------------------------------------------
# drift sequences


@dataclass(frozen=True)
class DriftSequence:
    """Frames of a sheet that shifts while it is cut.

    frames : list of ndarray (H, W, 3) uint8, ``None`` (missing frame) or ``bytes`` (unreadable data)
    truths : list of :class:`BedImage` or ``None`` for the missing/unreadable ones
    shifts : ndarray (n, 3) of (dx_mm, dy_mm, dangle_deg) of the sheet against frame 0
    """

    frames: list
    truths: list
    shifts: np.ndarray


def drift_sequence(
    scene: BedScene,
    camera: BedCamera,
    shifts: ArrayLike,
    missing: tuple[int, ...] = (),
    unreadable: tuple[int, ...] = (),
    noise_sigma: float = 2.0,
    blur_sigma_px: float = 0.7,
    jpeg_quality: int | None = 92,
) -> DriftSequence:
    """Render one frame per row of ``shifts`` (dx_mm, dy_mm, dangle_deg against ``scene``).

    The sheet turns by dangle about its own centre and moves by (dx, dy); each frame has fresh noise
    (seed ``scene.seed + i``). Frames in ``missing`` are ``None``, those in ``unreadable`` are bytes
    that do not decode as an image.
    """
    sh = np.asarray(shifts, dtype=float).reshape(-1, 3)
    rays = _rays(camera)
    w, h = scene.sheet_size_mm
    a0 = np.radians(scene.sheet_angle_deg)
    centre = np.asarray(scene.sheet_xy_mm) + np.array([[np.cos(a0), -np.sin(a0)], [np.sin(a0), np.cos(a0)]]) @ [w / 2, h / 2]
    scrap = _scrap_polygons(scene, np.random.default_rng(scene.seed)) if scene.n_scrap else []
    frames: list = []
    truths: list = []
    for i, (dx, dy, da) in enumerate(sh):
        if i in missing:
            frames.append(None)
            truths.append(None)
            continue
        if i in unreadable:
            frames.append(b"\xff\xd8\xff\xe0 not a complete jpeg")
            truths.append(None)
            continue
        a = np.radians(scene.sheet_angle_deg + da)
        c_new = centre + [dx, dy]
        xy0 = c_new - np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]) @ [w / 2, h / 2]
        s_i = replace(scene, sheet_xy_mm=(float(xy0[0]), float(xy0[1])), sheet_angle_deg=float(scene.sheet_angle_deg + da), seed=scene.seed + i)
        rng = np.random.default_rng(s_i.seed)
        img = _render(s_i, camera, rays, rng, noise_sigma, blur_sigma_px, jpeg_quality, scrap)
        px, mm, ang = _truth(s_i, camera)
        frames.append(img)
        truths.append(BedImage(img, px, mm, ang, camera, s_i, tuple(scrap)))
    return DriftSequence(frames, truths, sh)


__all__ = [
    "VARIANTS", "BedCamera", "BedImage", "BedScene", "DriftSequence", "bed_camera", "drift_sequence",
    "render_bed_image", "scene_variant",
]
