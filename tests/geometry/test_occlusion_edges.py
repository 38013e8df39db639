"""Visible edge samples when the part lies outside the image (used to crash the z-buffer)."""

from __future__ import annotations

import numpy as np
import trimesh

from app.geometry.model_edges import prepare_model, visible_edge_samples
from app.geometry.transforms import make_pose


def test_part_outside_the_image_with_an_occluder_gives_no_samples_and_no_error():
    model = prepare_model(trimesh.creation.box(bounds=[[0, 0, 0], [50, 40, 30]]), "block")
    K = np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]])
    occ = trimesh.creation.box(bounds=[[0, 0, 0], [20, 20, 20]])
    for x in (-3000.0, 3000.0):            # far left and far right of the 640 x 480 view
        T_cam_obj = make_pose(None, [x, 0.0, 600.0])
        es = visible_edge_samples(model, T_cam_obj, K, np.zeros(5), 640, 480,
                                  occluders=((occ, make_pose(None, [x, 0.0, 500.0])),))
        assert len(es.index) == 0


def test_points_beyond_the_distortion_fold_are_not_seen():
    """With strong barrel distortion the polynomial folds back: a box far outside the field of view
    (pinhole radius 1.2) lands near the image centre (r_d = 0.34). It must not count as visible."""
    model = prepare_model(trimesh.creation.box(bounds=[[-10, -10, -10], [10, 10, 10]]), "cube")
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    dist = np.array([-0.5, 0.0, 0.0, 0.0, 0.0])
    T_far = make_pose(None, [1.2 * 600.0, 0.0, 600.0])
    occ = trimesh.creation.box(bounds=[[-5, -5, -5], [5, 5, 5]])
    es = visible_edge_samples(model, T_far, K, dist, 640, 480, occluders=((occ, make_pose(None, [700.0, 0, 560.0])),))
    assert len(es.index) == 0
    T_near = make_pose(None, [0.0, 0.0, 600.0])                        # same box in the middle: seen
    assert len(visible_edge_samples(model, T_near, K, dist, 640, 480).index) > 20
