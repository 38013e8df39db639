"""A vise that the plate it holds hides from the camera, as an operator meets it: the setup names the
plate and the vise; over the whole table the vise is not found, the plate floats on "an unknown
support", and the service looks for the vise under the plate, finds it and its jaw, and puts the
plate on the vise's seat between them (real HTTP, database and the service's own worker). The scene
is devset setup_021, read from ../shared/data/devset (never copied here)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.support.devset_setup import DEVSET, vise_setup, workpiece_error

pytestmark = pytest.mark.slow
if not (DEVSET / "manifest.json").exists():
    pytest.skip(f"the devset is not beside the repository ({DEVSET})", allow_module_level=True)


def test_a_vise_hidden_under_its_plate_is_found_under_it(client):
    setup, gt, body_name = vise_setup(client, "setup_021", "Look-under", "wp_plate_slots.stl")
    said = [(s["name"], s["ok"], s["message"]) for s in setup["stages"]]
    look = next((s for s in setup["stages"] if s["name"] == "look under the parts"), None)
    assert look is not None and look["ok"], said
    assert f"{body_name} found under Look-under part" in look["message"], look["message"]
    # the first pass's stages stay on record, the second pass's follow the look
    names = [s["name"] for s in setup["stages"]]
    assert names.count(f"locate {body_name}") == 2 and names.index("look under the parts") < len(names) - 1, names
    result = setup["result"]
    assert {body_name, "Look-under vise jaw"} <= {o["name"] for o in result["objects"]}
    wp = next(o for o in result["objects"] if o["kind"] == "workpiece")
    assert f"{body_name} seat" in wp["chain"] and wp["chain"][-1] == "table", wp["chain"]
    err, within = workpiece_error(wp, gt, "wp_plate_slots.stl")
    assert np.linalg.norm(err[:3]) < 0.3 and np.abs(err[3:]).max() < 0.1, err
    assert within, (err, wp["sigma"])
