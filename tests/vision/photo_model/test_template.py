"""Teaching (app/vision/photo_model/template.py) on drawn pictures (tests/vision/photo_model/drawn.py):
the top face in mm, the obj frame, holes, the template's serialisation, and the refusals."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.vision import photo_model as pm
from tests.vision.photo_model.drawn import CAM_A, HEIGHT, K, draw, placed, plate_top


def test_teach_finds_the_top_face_in_mm(taught) -> None:
    model, T_teach = taught
    outline, holes = plate_top()
    # the obj frame's origin is the outline's centroid on the table, axes as the table's
    centre_true = (T_teach @ np.array([*_centroid(outline), 0.0, 1.0]))[:2]
    np.testing.assert_allclose(model.T_table_obj_teach[:2, 3], centre_true, atol=0.3)
    area = cv2.contourArea(model.outline_mm.astype(np.float32))
    assert abs(area - cv2.contourArea(outline.astype(np.float32))) < 0.03 * area
    assert len(model.holes_mm) == 2
    assert model.symmetry_deg == ()
    # the template's edges: outline and hole rims, about 0.5 mm apart
    perimeter = cv2.arcLength(outline.astype(np.float32), True) + sum(2 * np.pi * r for *_, r in holes)
    assert 0.8 * perimeter < model.edge_length_mm < 1.2 * perimeter
    again = pm.PhotoModel.from_dict(model.to_dict())
    np.testing.assert_allclose(again.points_mm, model.points_mm, atol=1e-4)
    assert again.teach_grid == model.teach_grid


def _centroid(poly: np.ndarray) -> np.ndarray:
    m = cv2.moments(poly.astype(np.float32))
    return np.array([m["m10"] / m["m00"], m["m01"] / m["m00"]])


def test_teach_refuses_a_picture_without_object_and_a_bad_height() -> None:
    empty = pm.View(draw(CAM_A, placed(2000.0, 2000.0, 0.0), []), K, np.zeros(5), CAM_A)
    with pytest.raises(pm.TeachError, match="no object"):
        pm.teach([empty], HEIGHT)
    with pytest.raises(pm.TeachError, match="height"):
        pm.teach([empty], -3.0)
