"""The plate taught once from a drawn picture, shared by the photo model's tests."""

from __future__ import annotations

import numpy as np
import pytest

from app.vision import photo_model as pm
from tests.vision.photo_model.drawn import CAM_A, HEIGHT, K, draw, placed, plate_top


@pytest.fixture(scope="session")
def taught() -> tuple[pm.PhotoModel, np.ndarray]:
    """(the model taught from one picture of the plate, T_table_plate of that picture)."""
    T_teach = placed(380.0, 200.0, 10.0)
    view = pm.View(draw(CAM_A, T_teach, plate_top()[1], seed=1), K, np.zeros(5), CAM_A)
    model, _pic = pm.teach([view], HEIGHT)
    return model, T_teach
