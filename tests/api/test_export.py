"""Export to real controllers over real HTTP: the safety gate, write + read-back, retries, refusals.

LinuxCNC is the headless simulator (its own status is the independent read-back); OPC UA an asyncua
server in a child process. Setups here are inserted as 'located' (tests/support/factories.py); the
image -> located -> exported chain runs in tests/e2e/test_setup_to_controller.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.transforms import pose_from_xyz_euler
from tests.support.factories import located_setup, make_machine

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def lcnc_machine(server, lcnc):
    with server.client() as c:
        return make_machine(c, lcnc.settings)


def lcnc_g54(lcnc) -> tuple[list[float], float]:
    st = lcnc.read_slot("G54")
    return st["g5x_offset"], st["rotation_xy"]


@pytest.mark.linuxcnc
def test_unconfirmed_is_refused_and_controller_untouched(server, lcnc, lcnc_machine):
    before = lcnc_g54(lcnc)
    sid = located_setup(server, lcnc_machine["id"], pose_from_xyz_euler(100, 50, 0, 0, 0, 10))
    with server.client("operator") as c:
        r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54"})
        assert r.status_code == 409 and "is not confirmed" in r.json()["detail"]
        r = c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 2})
        assert r.status_code == 409 and "not the current one" in r.json()["detail"]
    with server.client("mes") as c:
        r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54"})
        assert r.status_code == 403
    assert lcnc_g54(lcnc) == before


@pytest.mark.linuxcnc
def test_confirmed_export_is_written_read_back_and_not_repeated(server, lcnc, lcnc_machine):
    T_table_obj = pose_from_xyz_euler(123.456, 78.9, 0, 0, 0, 12.5)
    datum = pose_from_xyz_euler(-20, -10, 25)
    sid = located_setup(server, lcnc_machine["id"], T_table_obj, T_obj_datum=datum)
    expected = np.asarray(lcnc_machine["T_machine_table"]) @ T_table_obj @ datum
    with server.client("operator") as c:
        setup = c.get(f"/api/v1/setups/{sid}").json()
        off = setup["result"]["offset"]
        assert off["x_mm"] == pytest.approx(expected[0, 3]) and off["c_deg"] == pytest.approx(12.5)
        assert c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1}).status_code == 200
        r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54", "acknowledge_change": True})
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["status"] == "written" and body["agree"] and body["actor"] == "test-operator (operator)"
        assert body["written"]["x_mm"] == pytest.approx(expected[0, 3])
        g5x, rot = lcnc_g54(lcnc)  # LinuxCNC's own status, read through its Python module
        assert np.allclose(g5x, expected[:3, 3], atol=1e-4), (g5x, expected[:3, 3])
        assert rot == pytest.approx(12.5, abs=1e-4)
        again = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54", "acknowledge_change": True}).json()
        assert again["id"] == body["id"], "a retried export is answered from the first one"
        assert len(c.get(f"/api/v1/setups/{sid}/exports").json()) == 1
    with server.client("admin") as c:
        actions = [e["action"] for e in c.get("/api/v1/audit", params={"setup_id": sid}).json()]
        assert actions == ["export.written", "export.write", "export.attempt", "setup.confirm"], \
            "one write, on record before and after"
    with server.client("operator") as c:
        assert c.get("/api/v1/audit").status_code == 403
        current = c.get(f"/api/v1/machines/{lcnc_machine['id']}/offsets/G54").json()
        assert current["x_mm"] == pytest.approx(expected[0, 3], abs=1e-4)


@pytest.mark.linuxcnc
@pytest.mark.parametrize("case, kwargs, status, detail", [
    ("outside travel", {"T_table_obj": pose_from_xyz_euler(5000, 0, 0)}, 422, "outside the machine's travel"),
    ("tilted", {"T_table_obj": pose_from_xyz_euler(100, 50, 0, 0.5, 0, 0)}, 422, "residual tilt"),
    ("uncertain", {"T_table_obj": pose_from_xyz_euler(100, 50, 0), "sigma_mm": 1.5}, 422, "uncertainty too large"),
])
def test_implausible_offsets_are_refused(server, lcnc, lcnc_machine, case, kwargs, status, detail):
    before = lcnc_g54(lcnc)
    kwargs = dict(kwargs)  # the parameter dict is shared between the SQLite and PostgreSQL runs
    T = kwargs.pop("T_table_obj")
    sid = located_setup(server, lcnc_machine["id"], T, **kwargs)
    with server.client("operator") as c:
        c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1})
        r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54", "acknowledge_change": True})
        assert r.status_code == status and detail in r.json()["detail"], r.text
    assert lcnc_g54(lcnc) == before


@pytest.mark.linuxcnc
def test_large_change_needs_acknowledgement(server, lcnc, lcnc_machine):
    sid = located_setup(server, lcnc_machine["id"], pose_from_xyz_euler(300, 300, 0, 0, 0, -40))
    before = lcnc_g54(lcnc)
    with server.client("operator") as c:
        c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1})
        r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54"})
        assert r.status_code == 409 and "acknowledge_change=true" in r.json()["detail"]
        assert lcnc_g54(lcnc) == before


@pytest.mark.linuxcnc
def test_adjusting_after_confirmation_needs_a_new_confirmation(server, lcnc, lcnc_machine):
    sid = located_setup(server, lcnc_machine["id"], pose_from_xyz_euler(100, 50, 0))
    with server.client("operator") as c:
        c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1})
        r = c.post(f"/api/v1/setups/{sid}/adjust", json={"object_index": 0, "nudge": {"dx_mm": 0.5}})
        assert r.status_code == 200 and r.json()["result_revision"] == 2
        assert r.json()["result"]["objects"][0]["T_table_obj"][0][3] == pytest.approx(100.5)
        r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G55", "acknowledge_change": True})
        assert r.status_code == 409 and "changed after confirmation" in r.json()["detail"]


def test_unreachable_controller(server):
    with server.client() as c:
        m = make_machine(c, {"kind": "linuxcnc", "host": "127.0.0.1", "port": 9, "timeout_s": 1})
    sid = located_setup(server, m["id"], pose_from_xyz_euler(100, 50, 0))
    with server.client("operator") as c:
        c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1})
        r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54", "acknowledge_change": True})
        assert r.status_code == 502 and "nothing was written" in r.json()["detail"], r.text


def test_opcua_export_and_controller_dying_mid_write(server):
    from tests.machine.test_opcua import OpcUaSim

    ok, dying = OpcUaSim(), OpcUaSim("--die-on-write")
    try:
        ok.wait_ready()
        dying.wait_ready()
        nodes = {a: f"ns=2;s={{slot}}.{a.upper()}" for a in "xyzc"}
        with server.client() as c:
            m_ok = make_machine(c, {"kind": "opcua", "endpoint": ok.endpoint, "nodes": nodes})
            m_dead = make_machine(c, {"kind": "opcua", "endpoint": dying.endpoint, "nodes": nodes, "timeout_s": 3})
        T = pose_from_xyz_euler(210, 120, 0, 0, 0, -3.25)
        expected = np.asarray(m_ok["T_machine_table"]) @ T
        sid = located_setup(server, m_ok["id"], T)
        with server.client("operator") as c:
            c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1})
            r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G55", "acknowledge_change": True})
            assert r.status_code == 200 and r.json()["agree"], r.text
        x, y, z, cdeg = ok.read(["ns=2;s=G55.X", "ns=2;s=G55.Y", "ns=2;s=G55.Z", "ns=2;s=G55.C"])
        assert np.allclose([x, y, z], expected[:3, 3], atol=1e-9) and cdeg == pytest.approx(-3.25)
        sid2 = located_setup(server, m_dead["id"], T)
        with server.client("operator") as c:
            c.post(f"/api/v1/setups/{sid2}/confirm", json={"result_revision": 1})
            r = c.post(f"/api/v1/setups/{sid2}/export", json={"slot": "G55", "acknowledge_change": True})
            assert r.status_code == 502 and "broke off" in r.json()["detail"], r.text
            exports = c.get(f"/api/v1/setups/{sid2}/exports").json()
            # the controller died mid-write: only reading it back could tell, and it cannot be read
            assert exports[0]["status"] == "unknown" and "read back again" in exports[0]["reason"]
    finally:
        ok.stop()
        dying.stop()


def test_file_controller_first_export_needs_acknowledgement_then_reads_back(server, tmp_path):
    """A file drop that was never written for a slot has no current offset: reading it is a 404 with the
    reason (not a 502), the first export asks for an acknowledgement, then writes and reads the file back."""
    folder = tmp_path / "nc"
    folder.mkdir()
    with server.client() as c:
        machine = make_machine(c, {"kind": "file", "dialect": "linuxcnc", "folder": str(folder)})
    sid = located_setup(server, machine["id"], pose_from_xyz_euler(100, 50, 0, 0, 0, 10))
    with server.client("operator") as c:
        r = c.get(f"/api/v1/machines/{machine['id']}/offsets/G55")
        assert r.status_code == 404 and "no" in r.json()["detail"] and "written yet for G55" in r.json()["detail"]
        assert c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1}).status_code == 200
        r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G55"})
        assert r.status_code == 409 and "no current G55 to compare the change with" in r.json()["detail"]
        assert list(folder.iterdir()) == [], "nothing written without the acknowledgement"
        r = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G55", "acknowledge_change": True})
        assert r.status_code == 200, r.text
        body = r.json()
        assert body["status"] == "written" and body["before"] is None
        assert body["read_back"]["x_mm"] == pytest.approx(body["written"]["x_mm"], abs=1e-3)
        current = c.get(f"/api/v1/machines/{machine['id']}/offsets/G55").json()
        assert current["c_deg"] == pytest.approx(10.0, abs=1e-3)
    assert [p.name for p in folder.iterdir() if not p.name.startswith(".")]
