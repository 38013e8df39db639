"""Bed-plane mapping, bed pose from points, and the two scale methods on a measured plate."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.geometry.transforms import pose_to_rvec_tvec
from app.synth.bed_images import bed_camera
from app.vision.bed_scale import (
    BedPlane, bed_plane_scale, bed_pose_from_points, compare_scales, reference_scale,
)

CAM = bed_camera(1600, 1200, 0.5, target_bed_mm=(650, 420), tilt_deg=15.0)
RNG = np.random.default_rng(0)


def _project(xyz):
    rvec, tvec = pose_to_rvec_tvec(CAM.T_cam_bed)
    px, _ = cv2.projectPoints(np.asarray(xyz, float), rvec, tvec, CAM.K, CAM.dist)
    return px.reshape(-1, 2)


def test_plane_mapping_round_trip_and_height():
    plane = BedPlane.create(CAM.K, CAM.dist, CAM.T_cam_bed, 6.0)
    xy = RNG.uniform([450, 280], [850, 560], (50, 2))
    np.testing.assert_allclose(plane.bed_to_px(xy), _project(np.c_[xy, np.full(50, 6.0)]), atol=1e-9)
    np.testing.assert_allclose(plane.px_to_bed(plane.bed_to_px(xy)), xy, atol=1e-6)
    # the same pixel lands elsewhere on the slat tips than on the sheet's top
    on_tips = plane.at_height(0.0).px_to_bed(plane.bed_to_px(xy))
    assert np.min(np.linalg.norm(on_tips - xy, axis=1)) > 0.3


def test_local_scale_is_the_design_scale_at_the_target():
    plane = BedPlane.create(CAM.K, CAM.dist, CAM.T_cam_bed, 0.0)
    target_px = plane.bed_to_px([[650.0, 420.0]])
    assert plane.mm_per_px(target_px)[0] == pytest.approx(0.5, rel=0.03)


def test_plane_below_the_camera_is_required():
    with pytest.raises(ValueError, match="camera is .* above the bed"):
        BedPlane.create(CAM.K, CAM.dist, CAM.T_cam_bed @ np.diag([1.0, -1.0, -1.0, 1.0]), 0.0)
    with pytest.raises(ValueError, match="outside 0..200 mm"):
        BedPlane.create(CAM.K, CAM.dist, CAM.T_cam_bed, -3.0)


def test_bed_pose_from_board_points():
    grid = np.array([[x, y] for x in range(450, 851, 100) for y in range(280, 561, 70)], float)
    uv = _project(np.c_[grid, np.zeros(len(grid))]) + RNG.normal(0, 0.05, (len(grid), 2))
    pose = bed_pose_from_points(uv, grid, CAM.K, CAM.dist)
    assert pose.rms_px < 0.1
    assert np.abs(pose.T_cam_bed[:3, 3] - CAM.T_cam_bed[:3, 3]).max() < 1.0
    assert np.abs(pose.T_cam_bed[:3, :3] - CAM.T_cam_bed[:3, :3]).max() < 1e-3
    with pytest.raises(ValueError, match="need >= 4"):
        bed_pose_from_points(uv[:3], grid[:3], CAM.K, CAM.dist)


def _plate_images(n, a=300.0, b=200.0, t=4.0):
    out = []
    for k in range(n):
        ang = np.radians(RNG.uniform(-20, 20))
        R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        c = np.array([[0, 0], [a, 0], [a, b], [0, b]]) @ R.T + RNG.uniform([300, 200], [700, 420])
        out.append(_project(np.c_[c, np.full(4, t)]))
    return np.array(out)


def test_reference_scale_vs_bed_plane_on_a_plate():
    imgs = _plate_images(5)
    plane = BedPlane.create(CAM.K, CAM.dist, CAM.T_cam_bed, 4.0)
    cmp = compare_scales(imgs, 300.0, 200.0, plane, (1600, 1200))
    assert cmp.bed_plane.rms_mm < 1e-3  # exact corners: the plane model reproduces the plate
    assert cmp.reference.rms_mm > 0.3  # one factor cannot absorb tilt, perspective and distortion
    assert cmp.reference.mm_per_px == pytest.approx(0.5, rel=0.05)
    assert cmp.mm_per_px_max / cmp.mm_per_px_min > 1.05  # the scale varies over the image
    d = cmp.as_dict()
    assert set(d) == {"reference", "bed_plane", "bed_plane_mm_per_px_range"}
    # at the wrong height the proper method is off too: the plate's thickness matters
    assert bed_plane_scale(imgs, 300.0, 200.0, plane.at_height(0.0)).rms_mm > 0.1


def test_reference_scale_needs_three_to_ten_images():
    with pytest.raises(ValueError, match="3 to 10 images"):
        reference_scale(_plate_images(2), 300.0, 200.0)
    with pytest.raises(ValueError, match="3 to 10 images"):
        reference_scale(_plate_images(11), 300.0, 200.0)
