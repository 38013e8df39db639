"""The typed setup result keeps the stored JSON as it is: unknown keys round-trip, defaults are not added,
a cleared probing FAIL leaves the JSON, and every T_cam_obj follows its T_table_obj."""

from __future__ import annotations

import numpy as np

from app.geometry.transforms import pose_from_xyz_euler
from app.services.setup_result import LocatedObject, SetupResult

T_CAM_TABLE = pose_from_xyz_euler(-400, -200, 900, 180, 0, 0)
STORED = {"ok": True, "reason": "", "table": {"T_cam_table": T_CAM_TABLE.tolist(), "rms_px": 0.4},
          "objects": [{"name": "block", "kind": "workpiece", "T_table_obj": np.eye(4).tolist(),
                       "sigma": {"x_mm": 0.02, "rz_deg": None}, "chain": ["table"], "cov6": None},
                      {"name": "vise", "kind": "clamp", "model_id": 3, "revision": 1,
                       "T_table_obj": pose_from_xyz_euler(10, 0, 0).tolist(), "probe_fail": "old"}],
          "not_found": [], "timings_ms": {"total": 812.5}, "stages": [{"name": "table markers", "ok": True}]}


def test_a_stored_result_round_trips_unchanged():
    assert SetupResult.load(STORED).dump() == STORED


def test_workpiece_place_and_probe_fail():
    r = SetupResult.load(STORED)
    assert r.workpiece_index() == 0 and r.workpiece().name == "block"
    vise = r.objects[1].moved_to(pose_from_xyz_euler(20, 5, 0, c_deg=30))
    vise.clear_probe_fail()
    r = r.replace(1, vise)
    r.place()
    out = r.dump()
    assert "probe_fail" not in out["objects"][1] and STORED["objects"][1]["probe_fail"] == "old"
    for o in out["objects"]:
        assert np.allclose(o["T_cam_obj"], T_CAM_TABLE @ np.asarray(o["T_table_obj"]))


def test_datum_candidates_and_undecided():
    o = LocatedObject(name="plate", T_table_obj=np.eye(4).tolist(), datum_ambiguous=True,
                      equivalent_poses=[pose_from_xyz_euler(c_deg=180).tolist()])
    assert o.datum_undecided() and len(o.datum_candidates()) == 2
    assert not o.model_copy(update={"equivalent_poses": []}).datum_undecided()
    assert np.array_equal(o.datum, np.eye(4))
