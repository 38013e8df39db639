"""The bed image generator: exact ground truth, subpixel-true edges, variants, drift sequences."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from shapely.geometry import Polygon

from app.geometry.transforms import pose_to_rvec_tvec
from app.synth.bed_images import VARIANTS, bed_camera, drift_sequence, render_bed_image, scene_variant
from app.vision.bed_scale import distort_px, undistort_px

CAM = bed_camera(480, 360, 1.0, target_bed_mm=(520, 380))


def _scene(variant="plain", **kw):
    kw.setdefault("sheet_size_mm", (240.0, 160.0))
    kw.setdefault("sheet_xy_mm", (400.0, 300.0))
    return scene_variant(variant, **kw)


def test_ground_truth_is_the_camera_projection_and_ordered():
    b = render_bed_image(_scene(sheet_angle_deg=-6.0, thickness_mm=5.0), CAM)
    xyz = np.c_[b.corners_bed_mm, np.full(4, 5.0)]
    rvec, tvec = pose_to_rvec_tvec(CAM.T_cam_bed)
    px, _ = cv2.projectPoints(xyz, rvec, tvec, CAM.K, CAM.dist)
    np.testing.assert_allclose(b.corners_px, px.reshape(4, 2), atol=1e-9)
    c = b.corners_bed_mm
    assert np.argmin(np.linalg.norm(c, axis=1)) == 0
    area2 = np.sum(c[:, 0] * np.roll(c[:, 1], -1) - np.roll(c[:, 0], -1) * c[:, 1])
    assert area2 > 0  # counter-clockwise seen from above
    assert b.angle_deg == pytest.approx(-6.0, abs=1e-9)


def test_edges_are_antialiased_onto_the_true_line():
    """Noise-free, unblurred, no JPEG: the 50 % level across the back edge lies on the true edge."""
    b = render_bed_image(_scene("flat", sheet_angle_deg=4.0), CAM, noise_sigma=0.0, blur_sigma_px=0.0, jpeg_quality=None)
    gray = cv2.cvtColor(b.image, cv2.COLOR_BGR2GRAY).astype(np.float32)
    ideal = undistort_px(b.corners_px, CAM.K, CAM.dist)
    p0, p1 = ideal[2], ideal[3]  # back edge: its side face is hidden from the camera
    errs = []
    for t in np.linspace(0.2, 0.8, 7):
        q = p0 + t * (p1 - p0)
        e = (p1 - p0) / np.linalg.norm(p1 - p0)
        n = np.array([e[1], -e[0]])
        s = np.arange(-6.0, 6.01, 0.05)
        raw = distort_px(q + s[:, None] * n, CAM.K, CAM.dist).astype(np.float32)
        prof = cv2.remap(gray, raw[:, 0][None].copy(), raw[:, 1][None].copy(), cv2.INTER_LINEAR)[0]
        if prof[0] < prof[-1]:
            prof, s = prof[::-1], -s[::-1]
        mid = 0.5 * (prof[np.argmin(np.abs(s + 1.5))] + prof[np.argmin(np.abs(s - 1.5))])  # levels 1.5 px either side
        k = np.flatnonzero((prof[:-1] >= mid) & (prof[1:] < mid))[0]
        errs.append(s[k] + (mid - prof[k]) / (prof[k + 1] - prof[k]) * 0.05)
    assert abs(np.mean(errs)) < 0.05 and np.max(np.abs(errs)) < 0.2  # floor texture moves single profiles


@pytest.mark.parametrize("variant", VARIANTS)
def test_variants_render_seeded(variant):
    s = _scene(variant, seed=3)
    a = render_bed_image(s, CAM)
    assert a.image.shape == (360, 480, 3) and a.image.dtype == np.uint8
    if variant == "scrap":
        b = render_bed_image(s, CAM)
        np.testing.assert_array_equal(a.image, b.image)
        assert len(a.scrap_polygons_mm) >= 3
        sheet = Polygon(a.corners_bed_mm)
        assert all(Polygon(q).distance(sheet) > 0.2 for q in a.scrap_polygons_mm)
    if variant == "bright":
        inside = a.image[int(a.corners_px[:, 1].mean()), int(a.corners_px[:, 0].mean())].mean()
        assert inside > 190 and np.median(a.image) > 140  # bright sheet, bright bed


def test_sheet_outside_the_image_is_refused():
    with pytest.raises(ValueError, match="sheet corner outside the image"):
        render_bed_image(_scene(sheet_xy_mm=(100.0, 100.0)), CAM)


def test_drift_sequence_moves_the_sheet_and_drops_frames():
    seq = drift_sequence(_scene(), CAM, [(0, 0, 0), (2.0, -1.0, 0.0), (0, 0, 0), (1, 1, 0.5)], missing=(2,), unreadable=(3,))
    assert seq.frames[2] is None and seq.truths[2] is None
    assert isinstance(seq.frames[3], bytes)
    assert cv2.imdecode(np.frombuffer(seq.frames[3], np.uint8), cv2.IMREAD_COLOR) is None
    moved = seq.truths[1].corners_bed_mm - seq.truths[0].corners_bed_mm
    np.testing.assert_allclose(moved, np.tile([2.0, -1.0], (4, 1)), atol=1e-9)
    assert not np.array_equal(seq.frames[0], seq.frames[1])


def test_coverage_integrates_to_the_polygon_area():
    """Anti-aliased coverage of a turned rectangle on an affine pixel -> mm map sums to its area."""
    from app.synth.bed_images import _convex_coverage, _jacobian

    v, u = np.mgrid[0:200, 0:300].astype(np.float64)
    xy = np.stack([0.5 * u + 0.1 * v + 10.0, -0.05 * u + 0.5 * v + 5.0], axis=-1)  # mm
    a = np.radians(17.0)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    poly = np.array([[0, 0], [60, 0], [60, 40], [0, 40]]) @ R.T + [60.0, 20.0]
    cov = _convex_coverage(xy.astype(np.float32), _jacobian(xy), poly)
    px_area_mm2 = abs(0.5 * 0.5 - 0.1 * -0.05)
    assert cov.sum() * px_area_mm2 == pytest.approx(60 * 40, rel=1e-3)
