"""Generator of rotary-target images: exact ground truth and unbiased anti-aliased edges."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.geometry.transforms import rotation_angle_deg
from app.synth.rotary_images import (ErrorCurve, RotaryScene, generate_run, iso_bidirectional_angles,
                                     scaled_scene, true_errors_arcsec)
from app.vision.intrinsics import parse_intrinsics
from app.vision.rotary import measure_image
from app.vision.rotary_target import default_target


def test_error_curve_terms():
    c = ErrorCurve(amp1_arcsec=0, amp2_arcsec=0, slope_arcsec_per_deg=0.1, reversal_arcsec=4.0)
    e = c.error_arcsec(np.array([0.0, 100.0, 100.0]), np.array([1, 1, -1]))
    np.testing.assert_allclose(e, [2.0, 12.0, 8.0])


def test_iso_cycle_goes_up_then_down():
    a, d = iso_bidirectional_angles([0, 10, 20], repeats=2)
    assert a == [0, 10, 20, 20, 10, 0] * 2
    assert d == [1, 1, 1, -1, -1, -1] * 2


def test_ground_truth_poses_and_errors_agree():
    """The true poses rotate about one axis by exactly the actual increments."""
    scene = scaled_scene(RotaryScene(camera_tilt_deg=25.0, supersample=1), 320, 240)
    shots = generate_run(default_target(), [0.0, 40.0, 130.0], scene=scene, seed=1)
    e = true_errors_arcsec(shots)
    inj = np.array([s.injected_error_arcsec for s in shots])
    np.testing.assert_allclose(e, -(inj - inj[0]), atol=1e-9)
    for s in shots[1:]:
        ang = rotation_angle_deg(shots[0].T_cam_tgt, s.T_cam_tgt)
        assert ang == pytest.approx(s.actual_deg - shots[0].actual_deg, abs=1e-9)


@pytest.mark.slow
def test_frontal_circles_render_without_centre_bias():
    """Fronto-parallel target, no distortion/noise/gamma: fitted ellipse centres sit on the true
    projections of the circle centres to 0.01 px (anti-aliasing and blur are unbiased)."""
    scene = RotaryScene(camera_tilt_deg=0.0, mount_tilt_deg=0.0, dist=(0, 0, 0, 0, 0), noise_sigma=0.0,
                        gamma=1.0, illumination_gradient=0.0)
    target = default_target()
    shot = generate_run(target, [0.0], scene=scene)[0]
    res = measure_image(shot.image, parse_intrinsics(scene.intrinsics_dict()), target)
    assert res.ok, res.reason
    R, t = shot.T_cam_tgt[:3, :3], shot.T_cam_tgt[:3, 3]
    truth, _ = cv2.projectPoints(np.c_[target.centers_mm, np.zeros(4)], cv2.Rodrigues(R)[0], t,
                                 scene.K_array, scene.dist_array)
    truth = truth.reshape(-1, 2)
    for g in res.groups:
        assert np.linalg.norm(np.subtract(g.ellipse_center_uv_px, truth[g.group_index])) < 0.01
