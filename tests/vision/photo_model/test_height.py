"""The top face's height from two camera poses (app/vision/photo_model/height.py) on drawn pictures
(tests/vision/photo_model/drawn.py)."""

from __future__ import annotations

import numpy as np
import pytest

from app.vision import photo_model as pm
from tests.vision.photo_model.drawn import (
    CAM_A,
    CAM_B,
    HEIGHT,
    K,
    draw,
    placed,
    plate_top,
)


def test_height_from_two_views() -> None:
    T = placed(380.0, 200.0, 10.0)
    views = [pm.View(draw(cam, T, plate_top()[1], seed=s), K, np.zeros(5), cam) for cam, s in ((CAM_A, 1), (CAM_B, 2))]
    h, agree = pm.measure_height(views, (300.0, 460.0, 130.0, 270.0), z_range_mm=(2.0, 40.0))
    assert abs(h - HEIGHT) <= 0.3 and agree > 0.5
    with pytest.raises(pm.TeachError, match="moved only"):
        pm.measure_height([views[0], views[0]], (300.0, 460.0, 130.0, 270.0))
