"""Guided fixtures in the support chain (app/vision/localize.py): a carrier is searched before what it
guides, and a pose that left its guide is a failure that says how far."""

from __future__ import annotations

import numpy as np
import trimesh

from app.geometry.guides import pose_at_travel
from app.geometry.transforms import make_pose
from app.vision.localize import Candidate, _carriers_first, _kept_on_guide
from app.vision.object_pose import ObjectFailure, ObjectPose

JAW_GUIDE = {"carrier": "body", "T_carrier_obj": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 70], [0, 0, 0, 1]],
             "axis": [1.0, 0.0, 0.0], "travel_mm": [-95.0, 100.0]}


def _cand(name: str, guide: dict | None = None) -> Candidate:
    return Candidate(name, trimesh.creation.box(extents=[10, 10, 10]), kind="clamp", guide=guide)


def test_a_carrier_is_searched_before_what_it_guides():
    jaw, body, par = _cand("jaw", {**JAW_GUIDE, "carrier": "body"}), _cand("body"), _cand("parallel")
    stop = _cand("stop", {**JAW_GUIDE, "carrier": "jaw"})          # rides on the jaw: after it
    assert [c.name for c in _carriers_first([stop, jaw, par, body])] == ["parallel", "body", "jaw", "stop"]
    # order kept otherwise (biggest first, as given); a carrier not among them does not hold anything back
    lone = _cand("lone", {**JAW_GUIDE, "carrier": "absent"})
    assert [c.name for c in _carriers_first([lone, body, jaw])] == ["lone", "body", "jaw"]
    # a cycle keeps the given order rather than losing a fixture
    a, b = _cand("a", {**JAW_GUIDE, "carrier": "b"}), _cand("b", {**JAW_GUIDE, "carrier": "a"})
    assert [c.name for c in _carriers_first([a, b])] == ["a", "b"]


def _pose(T_table_obj: np.ndarray) -> ObjectPose:
    nan = float("nan")
    return ObjectPose(model_name="jaw", T_cam_obj=np.eye(4), T_table_obj=T_table_obj, resting_state=0, score=0.7,
                      inlier_edge_fraction=0.7, residual_px=0.5, visible_fraction=0.9, supported_edge_px=500.0,
                      unexplained_fraction=0.0, n_edge_samples=100, sigma={}, uncertainty_ok=True,
                      T_table_obj_6dof=T_table_obj, tilt_deg=0.0, tilt_sigma_deg=nan, height_offset_mm=0.0,
                      margin=0.2, runner_up_score=0.5, distinctiveness=0.2, equivalent_poses=(),
                      datum_ambiguous=False, datum_note="", flags=(), timings_ms={"total": 1.0})


def test_a_pose_off_its_guide_is_a_failure_that_says_how_far():
    jaw = _cand("jaw", JAW_GUIDE)
    c = np.cos(np.radians(30.0))
    s = np.sin(np.radians(30.0))
    T_table_body = make_pose([[c, -s, 0], [s, c, 0], [0, 0, 1]], [300.0, 150.0, 0.0])
    on = _pose(pose_at_travel(JAW_GUIDE, T_table_body, 40.0))
    assert _kept_on_guide(jaw, on, JAW_GUIDE, T_table_body) is on
    # 6.2 mm across the guide (the body's y), as the local search slid in devset setup_004
    off_T = make_pose(None, T_table_body[:3, :3] @ [0.0, 6.2, 0.0]) @ pose_at_travel(JAW_GUIDE, T_table_body, 95.2)
    off = _kept_on_guide(jaw, _pose(off_T), JAW_GUIDE, T_table_body)
    assert isinstance(off, ObjectFailure) and off.kind == "not_found"
    assert off.reason == ("jaw not found: the best fit (70% of its visible edges) left its guide on body: 6.2 mm "
                          "across it, at travel 95.2 mm (range -95 to 100), turned 0.0 deg (at most 3 mm and 2 deg)")
    assert off.candidates[0]["T_table_obj"] == off_T.tolist()       # drawn in red on the overlay
    beyond = _kept_on_guide(jaw, _pose(pose_at_travel(JAW_GUIDE, T_table_body, 120.0)), JAW_GUIDE, T_table_body)
    assert isinstance(beyond, ObjectFailure) and "at travel 120.0 mm (range -95 to 100)" in beyond.reason
