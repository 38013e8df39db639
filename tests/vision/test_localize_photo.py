"""Photo models among the candidates of :func:`app.vision.localize.localize` (issue 16): recognition over
CAD and photo models alike picks the plate in the picture (not its look-alike with a third hole, not a
CAD block), and a photo model asked for by name is located with the CAD engine's result shape."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.parts import taught_prism
from app.synth.photo_scenes import plate_b, shot
from app.synth.scene import default_table
from app.vision import photo_model as pm
from app.vision.fiducials import locate_table
from app.vision.localize import Candidate, localize, marker_labels_table
from tests.support.photo_pictures import DIST, K, pictures

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def setting():
    mesh, layout = default_table()
    table = Candidate("table", mesh, kind="table")

    def view(s) -> pm.View:
        T = locate_table(s.image, K, DIST, layout).T_cam_table
        return pm.View(s.image, K, DIST, T, pm.known_edge_mask(s.image.shape, K, DIST, T, [(table.prepare(), np.eye(4))],
                                                               marker_labels_table(layout)))

    teach1, teach2, repeat = pictures()
    model_a, _ = pm.teach([view(teach1), view(teach2)], 12.0)
    b = shot(plate_b(), 380, 200, 10, seed=21, intrinsics=(K, DIST))
    model_b, _ = pm.teach([view(b)], 12.0)

    def cand(name, m):
        return Candidate(name, taught_prism(m.outline_mm, list(m.holes_mm), m.height_mm), kind="workpiece",
                         model_id=1 if name == "A" else 2, revision=1, photo=m)

    block = trimesh.creation.box(extents=(60.0, 40.0, 30.0))
    block.apply_translation((30.0, 20.0, 15.0))
    return {"layout": layout, "table": table, "A": cand("A", model_a), "B": cand("B", model_b),
            "block": Candidate("block", block, kind="workpiece", model_id=3, revision=1),
            "repeat": repeat, "truth": repeat.T_table_obj @ np.linalg.inv(teach1.T_table_obj) @ model_a.T_table_obj_teach}


def test_recognition_picks_the_taught_plate_among_photo_and_cad_models(setting) -> None:
    s = setting
    res = localize(s["repeat"].image, K, DIST, s["layout"], [s["B"], s["block"], s["A"]], recognise=True,
                   table_model=s["table"])
    assert res.ok, res.reason
    assert [o["name"] for o in res.objects] == ["A"]
    T = np.asarray(res.objects[0]["T_table_obj"])
    assert np.hypot(*(T[:2, 3] - s["truth"][:2, 3])) < 0.2
    ranked = {r["model"]: r for r in next(st for st in res.stages if st.name == "recognition").data["ranked"]}
    assert not ranked["B"]["ok"] and "B not found" in ranked["B"]["reason"]


def test_a_photo_model_asked_for_has_the_engines_result_shape(setting) -> None:
    s = setting
    res = localize(s["repeat"].image, K, DIST, s["layout"], [s["A"]], table_model=s["table"], chain=True)
    assert res.ok, res.reason
    (o,) = res.objects
    assert o["chain"] == ["table"] and o["model_id"] == 1 and o["photo"]["edge_iou"] > 0.8
    for key in ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"):
        assert o["sigma"][key] is not None
    T = np.asarray(o["T_table_obj"])
    assert np.hypot(*(T[:2, 3] - s["truth"][:2, 3])) < 0.2
    wrong = localize(s["repeat"].image, K, DIST, s["layout"], [s["B"]], table_model=s["table"], chain=True)
    assert not wrong.ok and "B" in wrong.reason
