"""Audit everything security-relevant (issue 17, item 7), as far as this issue's changes reach: role
refusals, confirm, adjust, account, key, machine and camera changes land in the log with who and
from where; an admin reads it as JSON and exports it as CSV."""

from __future__ import annotations

import csv
import io

from app.geometry.transforms import pose_from_xyz_euler
from tests.support.factories import located_setup, make_machine


def test_security_relevant_actions_are_audited_and_exported(server):
    with server.client("admin") as c:
        m = make_machine(c, None)
        assert c.patch(f"/api/v1/machines/{m['id']}", json={"name": "mill 3b"}).status_code == 200
        assert c.patch(f"/api/v1/cameras/{m['camera_ids'][0]}", json={"name": "cam 3b"}).status_code == 200
    sid = located_setup(server, m["id"], pose_from_xyz_euler(100, 50, 0))
    with server.client("operator") as c:
        assert c.post(f"/api/v1/setups/{sid}/adjust", json={"object_index": 0, "nudge": {"dx_mm": 5}}).status_code == 200
        assert c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 2}).status_code == 200
        assert c.patch(f"/api/v1/machines/{m['id']}", json={"name": "x"}).status_code == 403   # refused
        r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54"})   # no controller: refused
        assert r.status_code == 422
    with server.client("mes") as c:
        assert c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 2}).status_code == 403
    with server.client("admin") as c:
        entries = c.get("/api/v1/audit", params={"limit": 1000}).json()
        setup_entries = c.get("/api/v1/audit", params={"setup_id": sid}).json()
        refusals = c.get("/api/v1/audit", params={"action": "access."}).json()
        exported = c.get("/api/v1/audit/export.csv", params={"action": "machine."})
    actions = {e["action"] for e in entries}
    assert {"machine.create", "machine.update", "camera.update", "setup.adjust", "setup.confirm",
            "access.refused"} <= actions
    adjust = next(e for e in setup_entries if e["action"] == "setup.adjust")
    assert adjust["actor"] == "test-operator (operator)" and adjust["detail"]["nudge"]["dx_mm"] == 5
    assert adjust["detail"]["uncertainty_pass"] is False and "moved +5.00 mm" in adjust["detail"]["reason"]
    assert [e["action"] for e in setup_entries][:3] == ["export.refused", "setup.confirm", "setup.adjust"]
    assert "no controller configured" in setup_entries[0]["detail"]["reason"]
    who = {(e["actor"], e["detail"]["request"]) for e in refusals}
    assert ("test-operator (operator)", f"PATCH /api/v1/machines/{m['id']}") in who
    assert ("test mes (mes key)", f"POST /api/v1/setups/{sid}/confirm") in who
    assert all(e["detail"]["address"] == "127.0.0.1" for e in refusals)
    assert exported.status_code == 200 and exported.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(exported.text)))
    assert rows and {r["action"] for r in rows} <= {"machine.create", "machine.update", "machine.delete"}
    assert any(r["action"] == "machine.update" and '"name"' in r["detail"] for r in rows)
