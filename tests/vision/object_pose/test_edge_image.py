"""The image side prepared once (app.vision.object_pose.edge_image): the per-image caches give the
numbers the uncached path gives."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.geometry import parts
from app.geometry.model_edges import prepare_model
from app.geometry.transforms import make_pose
from app.vision.object_pose.edge_image import mask_known_edges, mask_table_regions, nearest_edge_maps, prepare_image
from tests.vision.object_pose.test_locate import DIST, K


def _picture() -> np.ndarray:
    img = np.full((240, 320), 60, np.uint8)
    cv2.rectangle(img, (40, 50), (150, 170), 200, -1)
    cv2.circle(img, (230, 120), 45, 140, -1)
    cv2.line(img, (10, 220), (310, 190), 230, 3)
    return img


def test_nearest_edge_maps_are_the_lookups_they_replace():
    eimg = prepare_image(_picture())
    d, cos_a, sin_a = nearest_edge_maps(eimg)
    a = eimg.edge_angle[eimg.nearest]                   # (H, W): direction of the nearest edge pixel
    assert np.array_equal(d, eimg.dist_px.ravel())
    assert np.array_equal(cos_a, np.cos(a).ravel()) and np.array_equal(sin_a, np.sin(a).ravel())
    assert nearest_edge_maps(eimg)[1] is cos_a         # made once per image


def test_known_edges_masked_with_the_cached_mask_as_without():
    model = prepare_model(parts.parallel(150.0, 25.0, 8.0), "parallel")
    img = np.full((604, 956), 70, np.uint8)
    cv2.rectangle(img, (300, 250), (700, 330), 190, -1)
    T_a = make_pose(np.diag([1.0, -1.0, -1.0]), [-40.0, -10.0, 420.0])
    T_b = make_pose(np.diag([1.0, -1.0, -1.0]), [10.0, 15.0, 400.0])
    shared = prepare_image(img)
    for known in ([(model, T_a)], [(model, T_b)], [(model, T_a), (model, T_b)]):
        cached = mask_known_edges(shared, known, K, DIST)     # later calls reuse the masks made before
        fresh = mask_known_edges(prepare_image(img), known, K, DIST)
        assert np.array_equal(cached.edges, fresh.edges)
        assert np.array_equal(cached.dist_px, fresh.dist_px)
    assert (fresh.edges > 0).sum() < (shared.edges > 0).sum()   # the poses do mask edges


def test_clipped_pixels_are_marked_in_any_channel_and_kept_by_the_masked_copies():
    """A face at the sensor's top in one colour channel only is clipped too (its grey is not 255),
    and the copies with known edges or regions masked keep the mark."""
    img = np.full((240, 320, 3), 90, np.uint8)
    img[50:120, 40:150] = (255, 255, 255)          # white, over the top
    img[140:200, 180:300] = (120, 130, 255)        # red face (BGR), saturated in red only
    img[20:40, 200:300] = (200, 200, 200)          # bright, under the top
    eimg = prepare_image(img)
    grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    assert eimg.clipped[60, 60] and eimg.clipped[150, 200] and grey[150, 200] < 200
    assert not eimg.clipped[30, 250] and not eimg.clipped[5, 5]
    assert eimg.clipped.sum() == 70 * 110 + 60 * 120
    masked = mask_known_edges(eimg, [(prepare_model(parts.parallel(150.0, 25.0, 8.0), "parallel"),
                                      make_pose(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 400.0]))], K, DIST)
    assert masked.clipped is eimg.clipped
    assert prepare_image(img[..., 0]).clipped.sum() == 70 * 110  # grey input: only the white face


def test_the_distance_map_is_made_on_first_use_only(monkeypatch):
    """The edge maps masked in turn (the table's edges, then its labels) are never searched on their
    own: their distance transforms (30 ms each at 1920 x 1200) are made only for the map used."""
    calls = []
    real = cv2.distanceTransformWithLabels
    monkeypatch.setattr(cv2, "distanceTransformWithLabels", lambda *a, **k: calls.append(1) or real(*a, **k))
    model = prepare_model(parts.parallel(150.0, 25.0, 8.0), "parallel")
    img = _picture()
    eimg = mask_table_regions(mask_known_edges(prepare_image(img), [(model, make_pose(np.diag([1.0, -1.0, -1.0]),
                                                                                       [0.0, 0.0, 400.0]))], K, DIST),
                              [np.array([[-20.0, -20, 0], [20, -20, 0], [20, 20, 0], [-20, 20, 0]])],
                              make_pose(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 500.0]), K, DIST)
    assert calls == []
    d = eimg.dist_px
    assert eimg.dist_px is d and eimg.nearest is eimg.nearest and calls == [1]      # made once
    H, W = d.shape
    vv, uu = np.mgrid[0:H, 0:W]
    q = eimg.edge_uv[eimg.nearest]                                     # the nearest edge pixel's place
    # OpenCV's 5x5 mask: within 3 % of the true distance
    assert np.all(np.abs(np.hypot(q[..., 0] - uu, q[..., 1] - vv) - d) <= 0.03 * d + 0.1)
    assert d[eimg.edges > 0].max() == 0.0


@pytest.mark.parametrize("gamma", [1.0, 1.8, 2.2, 2.6])
def test_the_decoded_image_is_each_grey_level_decoded(gamma):
    """The decode by table gives the numbers decoding every pixel gives, at every grey level."""
    grey = np.tile(np.arange(256, dtype=np.uint8), (4, 1))
    eimg = prepare_image(grey, gamma=gamma)
    assert eimg.linear.dtype == np.float32
    assert np.array_equal(eimg.linear, ((grey.astype(np.float32) / 255.0) ** float(gamma)).astype(np.float32))
