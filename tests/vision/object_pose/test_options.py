"""One frozen options object for the engine (app.vision.object_pose.options)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from app.geometry.model_edges import prepare_model
from app.vision.object_pose import LocateOptions, locate_object
from app.vision.object_pose.uncertainty import SIGMA_SCALE


def test_options_are_frozen_and_changed_by_copy():
    o = LocateOptions()
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.min_score = 0.9                                    # type: ignore[misc]
    o2 = o.with_(min_score=0.7, height_offsets_mm=[0.0, 20.0], resting_states=[0])
    assert (o.min_score, o2.min_score) == (0.5, 0.7)
    assert o2.height_offsets_mm == (0.0, 20.0) and o2.resting_states == (0,)   # hashable, immutable
    assert o.sigma_scale == SIGMA_SCALE


def test_an_unknown_option_is_refused_by_name():
    with pytest.raises(TypeError, match="min_scroe.*known: .*min_score"):
        LocateOptions().with_(min_scroe=0.7)


def test_locate_takes_options_or_single_names_alike():
    """The same search given as an options object or as names gives the same answer (here: the
    reason why a blank image holds no part)."""
    model = prepare_model(trimesh.creation.box(bounds=[[0, 0, 0], [60, 40, 20]]), "block")
    K = np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]])
    T_cam_table = np.eye(4)
    T_cam_table[2, 3] = 600.0
    img = np.full((480, 640), 128, np.uint8)
    a = locate_object(img, K, None, T_cam_table, model, options=LocateOptions(min_score=0.6))
    b = locate_object(img, K, None, T_cam_table, model, min_score=0.6)
    assert not a and not b and a.reason == b.reason and "almost no edges" in a.reason
    with pytest.raises(TypeError, match="unknown locate option"):
        locate_object(img, K, None, T_cam_table, model, min_scroe=0.6)
