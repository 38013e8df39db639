"""A table that two markers leave tilted, levelled by the vise that stands on it, as an operator meets
it: the shop's table model declares only the two markers the camera sees, the setup names the part
and the vise, and the result says the table was levelled (real HTTP, database and the service's own
worker). The scene is devset setup_039, read from ../shared/data/devset (never copied here)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.support.devset_setup import DEVSET, vise_setup, workpiece_error

pytestmark = pytest.mark.slow
if not (DEVSET / "manifest.json").exists():
    pytest.skip(f"the devset is not beside the repository ({DEVSET})", allow_module_level=True)

SEEN = (88, 90)         # the two markers nearest the part


def test_a_setup_seen_through_two_markers_is_levelled_by_its_vise(client):
    setup, gt, body_name = vise_setup(client, "setup_039", "Levelling", "wp_flange.stl", marker_ids=SEEN)
    stage = next((s for s in setup["stages"] if s["name"] == "table levelled"), None)
    assert stage is not None and stage["ok"], [(s["name"], s["ok"], s["message"]) for s in setup["stages"]]
    assert stage["data"]["levelled_by"] == body_name and stage["data"]["correction"][0] > 0.03, stage["message"]
    assert "table levelled by" in stage["message"]
    result = setup["result"]
    # the result is given in the levelled frame, which the table's own entry states
    assert result["table"]["T_cam_table"] == stage["data"]["T_cam_table"]
    assert any(w.startswith("table levelled by") for w in result["table"]["warnings"])
    names = {o["name"] for o in result["objects"]}
    assert {body_name, "Levelling vise jaw"} <= names, names
    wp = next(o for o in result["objects"] if o["kind"] == "workpiece")
    err, within = workpiece_error(wp, gt, "wp_flange.stl")
    assert np.linalg.norm(err[:3]) < 1.0 and np.abs(err[3:]).max() < 0.3, err
    assert within, (err, wp["sigma"])
