"""Look-alikes (app/vision/photo_model/lookalikes.py and the checks of verify.py) on drawn pictures
(tests/vision/photo_model/drawn.py): a plate with a third hole against one without."""

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


@pytest.mark.slow
def test_a_look_alike_is_refused_and_told_apart(taught) -> None:
    """Plate B has a third hole. Asked for A in a picture of B: refused (edges inside the outline that A
    lacks); asked for B in a picture of A: refused (B's hole is not there); both located in one
    picture: the picture's own plate wins."""
    model_a, _ = taught
    extra = plate_top()[1] + [(50.0, 62.0, 8.0)]
    T_b = placed(380.0, 200.0, 10.0)
    model_b, _ = pm.teach([pm.View(draw(CAM_A, T_b, extra, seed=2), K, np.zeros(5), CAM_A)], HEIGHT)
    T_rep = placed(330.0, 180.0, 75.0)
    pic_a = pm.View(draw(CAM_B, T_rep, plate_top()[1], seed=7), K, np.zeros(5), CAM_B)
    pic_b = pm.View(draw(CAM_B, T_rep, extra, seed=8), K, np.zeros(5), CAM_B)
    wrong = pm.locate(pic_b, model_a, "A")
    assert not wrong and "inside its outline" in wrong.reason
    wrong = pm.locate(pic_a, model_b, "B")
    assert not wrong and "not in the picture" in wrong.reason
    # the two located without the checks (as recognition sees them), then decided
    for pic, right in ((pic_a, "A"), (pic_b, "B")):
        both = [(n, m, pm.locate(pic, m, n, max_unexplained_mm=1e9, min_score=0.5)) for n, m in
                (("A", model_a), ("B", model_b))]
        both = [b for b in both if b[2]]
        accepted, refused = pm.decide_lookalikes(pic, both)
        assert [both[i][0] for i in accepted] == [right], refused
