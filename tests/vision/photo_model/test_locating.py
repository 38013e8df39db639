"""Locating a repeat placement (app/vision/photo_model/locating.py) on drawn pictures
(tests/vision/photo_model/drawn.py): another place, turn and camera pose, with and without distortion."""

from __future__ import annotations

import numpy as np
import pytest

from app.vision import photo_model as pm
from tests.vision.photo_model.drawn import (
    CAM_A,
    CAM_B,
    DIST,
    K,
    draw,
    placed,
    plate_top,
)


@pytest.mark.parametrize("where, cam, dist", [((300.0, 160.0, 47.0), CAM_B, DIST), ((470.0, 230.0, -120.0), CAM_A, None)])
def test_repeat_placement_is_located_to_a_tenth(taught, where, cam, dist) -> None:
    """Another place, turn and camera pose (with distortion): x, y within 0.1 mm, turn within 0.03°,
    and the error within 3 sigma; the result has the CAD engine's shape."""
    model, T_teach = taught
    T_rep = placed(*where)
    view = pm.View(draw(cam, T_rep, plate_top()[1], dist=dist, seed=5), K, dist if dist is not None else np.zeros(5), cam)
    p = pm.locate(view, model, "plate")
    assert p, p.reason
    truth = T_rep @ np.linalg.inv(T_teach) @ model.T_table_obj_teach
    err = p.T_table_obj[:2, 3] - truth[:2, 3]
    dc = np.degrees(np.arctan2(p.T_table_obj[1, 0], p.T_table_obj[0, 0]) - np.arctan2(truth[1, 0], truth[0, 0]))
    assert np.hypot(*err) < 0.1 and abs((dc + 180) % 360 - 180) < 0.03, (err, dc)
    assert abs(err[0]) < 3 * p.sigma["x_mm"] + 0.02 and abs(err[1]) < 3 * p.sigma["y_mm"] + 0.02
    assert p.uncertainty_ok and p.score > 0.9 and p.T_table_obj[2, 3] == 0.0
    d = p.to_dict()
    assert {"T_cam_obj", "T_table_obj", "sigma", "cov6", "score", "margin", "flags", "photo"} <= set(d)
    np.testing.assert_allclose(p.T_cam_obj, cam @ p.T_table_obj)
