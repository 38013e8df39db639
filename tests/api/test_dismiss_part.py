"""A workpiece recognised in error is taken out by the operator (POST /setups/{id}/dismiss): a new
revision without it, the offset then the next workpiece's, the dismissed pose on the audit log;
clamps, the last workpiece and other roles are refused with the reason."""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.transforms import pose_from_xyz_euler
from tests.support.factories import located_setup, make_machine


def test_a_part_recognised_in_error_is_dismissed_and_the_offset_moves_to_the_real_one(server):
    with server.client("admin") as c:
        m = make_machine(c, None)
    T_machine_table = np.asarray(m["T_machine_table"])
    wrong, right = pose_from_xyz_euler(253, 391, 0), pose_from_xyz_euler(208, 219, 0)
    # as recognition ranks them: the pin block on clutter first, the real part second, then the vise
    sid = located_setup(server, m["id"], wrong, more=(
        {"name": "plate_slots", "kind": "workpiece", "T_table_obj": right},
        {"name": "vise_body", "kind": "clamp", "T_table_obj": pose_from_xyz_euler(400, 200, 0)}))
    with server.client("operator") as c:
        s = c.get(f"/api/v1/setups/{sid}").json()
        assert s["result"]["offset"]["object"] == "block"
        for body, why in (({"object_index": 2}, "vise_body is a clamp: only a workpiece can be dismissed"),
                          ({"object_index": 3}, "object_index 3 out of range")):
            r = c.post(f"/api/v1/setups/{sid}/dismiss", json=body)
            assert r.status_code == 422 and why in r.json()["detail"], r.text
        assert c.post(f"/api/v1/setups/{sid}/dismiss", json={"object_index": -1}).status_code == 422
        r = c.post(f"/api/v1/setups/{sid}/dismiss", json={"object_index": 0})
        assert r.status_code == 200, r.text
        s = r.json()
        assert s["result_revision"] == 2 and s["confirmed_revision"] is None
        assert [o["name"] for o in s["result"]["objects"]] == ["plate_slots", "vise_body"]
        off = s["result"]["offset"]
        assert off["object"] == "plate_slots"
        assert off["x_mm"] == pytest.approx((T_machine_table @ right)[0, 3], abs=1e-6)
        assert off["y_mm"] == pytest.approx((T_machine_table @ right)[1, 3], abs=1e-6)
        # the last workpiece stays: without it there is no offset to propose
        r = c.post(f"/api/v1/setups/{sid}/dismiss", json={"object_index": 0})
        assert r.status_code == 422 and "the only workpiece located" in r.json()["detail"], r.text
        # the revision the operator saw before is no longer the one to confirm
        assert c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1}).status_code == 409
        assert c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 2}).status_code == 200
    with server.client("mes") as c:
        assert c.post(f"/api/v1/setups/{sid}/dismiss", json={"object_index": 0}).status_code == 403
    with server.client("admin") as c:
        entries = c.get("/api/v1/audit", params={"setup_id": sid}).json()
    dismissed = next(e for e in entries if e["action"] == "setup.dismiss")
    assert dismissed["actor"] == "test-operator (operator)" and dismissed["detail"]["name"] == "block"
    assert np.allclose(dismissed["detail"]["T_table_obj"], wrong) and dismissed["detail"]["result_revision"] == 2
