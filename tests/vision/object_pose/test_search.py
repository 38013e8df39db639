"""Starts for the fine fit (app.vision.object_pose.search): a start a few mm and degrees off is
settled back onto the part."""

from __future__ import annotations

import numpy as np

from app.geometry import parts
from app.geometry.model_edges import prepare_model
from app.geometry.transforms import make_pose
from app.synth.scene import SceneObject, place_on_table
from app.vision.object_pose import prepare_image
from app.vision.object_pose.planar_fit import planar_fit, sample_subset
from app.vision.object_pose.search import Hyp, _state_of, settle_start
from tests.vision.object_pose.test_locate import DIST, K, _errors, _render


def test_a_start_off_by_a_coarse_cell_is_settled_onto_the_part():
    model = prepare_model(parts.bracket_140(), "bracket_140")
    T_true = place_on_table(model.mesh, 400.0, 200.0, 25.0)
    scene, r = _render([SceneObject("bracket_140", model.mesh, T_true, albedo=0.65)],
                       [150.0, -250.0, 600.0], [400.0, 200.0, 0.0])
    eimg = prepare_image(r.image, gamma=scene.gamma)
    c = T_true[:3, 3]
    turn = make_pose(np.array([[np.cos(0.12), -np.sin(0.12), 0], [np.sin(0.12), np.cos(0.12), 0], [0, 0, 1]]))
    T0 = make_pose(None, [13.0, -9.0, 0.0]) @ make_pose(None, c) @ turn @ make_pose(None, -c) @ T_true  # 15.8 mm, 6.9 deg
    state = _state_of(model, T_true)
    start = Hyp(state=state, T_table_obj=T0)
    px_per_mm = K[0, 0] / 700.0
    aligned = planar_fit(eimg, model, Hyp(state=state, T_table_obj=T0.copy()), scene.T_cam_table, K, DIST,
                         sample_subset(model, px_per_mm, 4.0, 400))
    settled = settle_start(model, start, scene.T_cam_table, K, DIST, eimg, capture_mm=20.0, capture_deg=8.0)
    dxy, _, drz = _errors(settled.T_table_obj, T_true)
    assert dxy < 1.5 and drz < 0.5, (dxy, drz)
    assert settled.score > aligned.score         # the aligned start alone stays further off
    # a start that is already right is kept (nothing better around it)
    right = planar_fit(eimg, model, Hyp(state=state, T_table_obj=T_true.copy()), scene.T_cam_table, K, DIST,
                       sample_subset(model, px_per_mm, 4.0, 400))
    again = settle_start(model, right, scene.T_cam_table, K, DIST, eimg, capture_mm=20.0, capture_deg=8.0)
    assert _errors(again.T_table_obj, T_true)[0] < 1.0
