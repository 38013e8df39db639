"""Drift monitor: the three threshold bands, redatum, latched stop, missing frames, lost corners."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.synth.bed_images import bed_camera, drift_sequence, scene_variant
from app.vision.bed_scale import BedPlane
from app.vision.drift import CORNER_NOT_FOUND, FRAME_MISSING, OK, REDATUM, STOP, DriftMonitor, draw_drift
from app.vision.sheet import find_sheet, work_origin

CAM = bed_camera(640, 480, 1.0, target_bed_mm=(560, 400))
SCENE = scene_variant("plain", sheet_size_mm=(300.0, 200.0), sheet_xy_mm=(420.0, 300.0), sheet_angle_deg=3.0, seed=11)
PLANE = BedPlane.create(CAM.K, CAM.dist, CAM.T_cam_bed, SCENE.thickness_mm)
SHIFTS = [(0, 0, 0), (0.15, 0.1, 0.0), (1.5, 0.5, 0.0), (1.55, 0.5, 0.0), (0, 0, 0), (0, 0, 0), (5.0, 2.0, 0.3)]


@pytest.fixture(scope="module")
def seq():
    return drift_sequence(SCENE, CAM, SHIFTS, missing=(4,), unreadable=(5,))


@pytest.fixture(scope="module")
def monitor_run(seq):
    sheet = find_sheet(seq.frames[0], PLANE)
    assert sheet, getattr(sheet, "reason", "")
    mon = DriftMonitor.from_sheet(sheet, PLANE, l1_mm=1.0, l2_mm=3.0, start_frame=seq.frames[0])
    covered = seq.frames[3].copy()
    c2 = np.round(seq.truths[3].corners_px[2]).astype(int)
    cv2.circle(covered, tuple(c2), 30, (20, 20, 20), -1)  # the head or sparks over corner 2
    frames = list(seq.frames[:4]) + [covered] + list(seq.frames[4:]) + [seq.frames[0]]
    return mon, [mon.update(f) for f in frames]


def test_decisions_follow_the_bands(monitor_run):
    _, d = monitor_run
    assert [x.decision for x in d] == [OK, OK, REDATUM, OK, CORNER_NOT_FOUND, FRAME_MISSING, FRAME_MISSING, STOP, STOP]
    assert d[0].max_error_mm < 0.1  # the start frame against itself
    assert d[1].max_error_mm < 1.0
    assert 1.0 <= d[2].max_error_mm < 3.0
    assert d[7].max_error_mm >= 3.0 and "L2 = 3 mm" in d[7].reason
    assert "stopped earlier" in d[8].reason  # latched, although the sheet looks back in place


def test_errors_track_the_true_shift(seq, monitor_run):
    _, d = monitor_run
    for i in (1, 2):
        truth = np.linalg.norm(seq.truths[i].corners_bed_mm - seq.truths[0].corners_bed_mm, axis=1)
        np.testing.assert_allclose(d[i].errors_from_start_mm, truth, atol=0.45)


def test_redatum_sends_the_new_origin_and_rebases(seq, monitor_run):
    _, d = monitor_run
    new = d[2].new_offset
    _, truth = work_origin(seq.truths[2].corners_bed_mm, 0.0)
    assert (new.x_mm, new.y_mm) == pytest.approx((truth.x_mm, truth.y_mm), abs=0.5)
    assert new.c_deg == pytest.approx(truth.c_deg, abs=0.1)
    assert "new origin" in d[2].reason
    assert d[3].max_error_mm < 0.5  # measured against the new datum
    assert d[3].errors_from_start_mm.min() > 1.0  # still far from the start


def test_missing_and_unreadable_frames_and_lost_corners_are_reported(monitor_run):
    _, d = monitor_run
    assert d[5].reason == "frame missing: the camera returned no image"
    assert d[6].reason.startswith("frame unreadable:")
    assert np.isnan(d[5].errors_mm).all()
    assert d[4].reason.startswith("corner 2 not found in its 100 x 100 px ROI")
    assert np.isnan(d[4].errors_mm[2]) and np.isfinite(d[4].errors_mm[[0, 1, 3]]).all()
    assert d[4].as_dict()["errors_mm"][2] is None


def test_draw_drift_marks_the_rois(seq, monitor_run):
    _, d = monitor_run
    pic = draw_drift(seq.frames[2], d[2])
    assert pic.shape == seq.frames[2].shape
    assert np.count_nonzero(np.any(pic != seq.frames[2], axis=2)) > 500
    assert draw_drift(np.zeros((480, 640, 3), np.uint8), d[5]).any()  # a missing frame still gets its reason


def test_blank_frame_and_reset(seq):
    mon = DriftMonitor(find_sheet(seq.frames[0], PLANE).corners_px, PLANE, 1.0, 3.0)
    blank = mon.update(np.zeros((480, 640, 3), np.uint8))
    assert blank.decision == FRAME_MISSING and "blank image" in blank.reason
    assert mon.update(seq.frames[6]).decision == STOP and mon.stopped
    mon.reset()
    assert not mon.stopped and mon.update(seq.frames[0]).decision == OK


def test_bad_thresholds_are_refused():
    c = np.array([[100, 300], [400, 300], [400, 100], [100, 100]], float)
    with pytest.raises(ValueError, match="0 < L1 < L2"):
        DriftMonitor(c, PLANE, 3.0, 1.0)
    with pytest.raises(ValueError, match="outside 0..20 mm"):
        DriftMonitor(c, PLANE, 1.0, 3.0, margin_mm=30.0)
