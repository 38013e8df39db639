"""Overlay text is legible at full HD: label height measured in the drawn pixels, not from the formula."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import make_pose
from app.vision.localize import Candidate, draw_model_edges, draw_overlay
from app.vision.object_pose import ObjectFailure
from scipy.spatial.transform import Rotation


def _camera(width: int, height: int) -> np.ndarray:
    f = 0.8 * width
    return np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])


@pytest.fixture(scope="module")
def block() -> Candidate:
    return Candidate("block", trimesh.creation.box(extents=(120, 80, 40)))


def _text_rows(with_text: np.ndarray, without: np.ndarray) -> int:
    """Height (px) of what the label added to the picture."""
    rows = np.flatnonzero(np.any(with_text != without, axis=(1, 2)))
    return int(rows.max() - rows.min() + 1) if rows.size else 0


@pytest.mark.parametrize("size,lo,hi", [((1920, 1200), 22, 45), ((640, 400), 9, 20)])
def test_object_label_grows_with_the_picture(block, size, lo, hi):
    W, H = size
    K = _camera(W, H)
    T_cam_obj = make_pose(Rotation.from_euler("xyz", [-120, 0, 25], degrees=True).as_matrix(), [0, 0, 900])
    black = np.zeros((H, W, 3), np.uint8)
    plain = draw_model_edges(black, K, None, T_cam_obj, block.prepare(), (0, 220, 0))
    labelled = draw_model_edges(black, K, None, T_cam_obj, block.prepare(), (0, 220, 0), "block 97% x120.0 y40.0 C1.50")
    assert np.count_nonzero(plain) > 0
    height = _text_rows(labelled, plain)
    assert lo <= height <= hi, f"label {height} px tall on a {W} x {H} picture"


def test_a_failure_reason_reads_at_full_hd(block):
    W, H = 1920, 1200
    black = np.zeros((H, W, 3), np.uint8)
    failure = ObjectFailure(model_name="block", kind="not_found", reason="block not found: 12% of its edges",
                            best_score=0.12, candidates=(), timings_ms={})
    pic = draw_overlay(black, _camera(W, H), np.zeros(5), None, [(block, failure)])
    red_rows = np.flatnonzero(np.any(pic[:, :, 2] > 128, axis=1))
    assert red_rows.size and red_rows.max() - red_rows.min() + 1 >= 22
    assert pic[:, :, 2].any() and not pic[:, :, 1].any()   # red text only, nothing drawn in green
