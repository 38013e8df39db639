"""The probing program over real HTTP (issue 18): parameters are data from closed sets, the export's
gates, objects asked for but not located, retract height and travel, the frame in the header."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app.geometry.transforms import pose_from_xyz_euler, transform_points
from app.machine import WorkOffset
from app.machine.nc_files import DIALECTS
from app.planning.probing import gcode_positions
from app.synth.scene import place_on_table
from app.store.db import session_scope
from app.store.models import Setup
from tests.support.factories import located_setup, make_machine
from tests.support.scenes import library_entry, library_mesh

# what a program line may be: nothing else can reach the controller
LINE = re.compile(r"^(%|\([^()\n]*\)|G21 G90 G17 G94 G40 G5[4-9](\.[1-3])?|M2"
                  r"|G0 Z-?\d+\.\d{4}( \([^()]*\))?|G0 X-?\d+\.\d{4} Y-?\d+\.\d{4}|G1 Z-?\d+\.\d{4} F\d+"
                  r"|(G1|G38\.2) X-?\d+\.\d{4} Y-?\d+\.\d{4} Z-?\d+\.\d{4} F\d+)$")

PAYLOADS = ["G54\nG0 Z-500", "G54\rG0 Z-500", "M3 S20000", "foo", "G54 (x)", "G54)\nM3 (", "G54;M3", "G54 ",
            "", "G10 L2 P1 X0", "%", "nan", "inf", "-inf", "1e309", "-5", "1000", "5\nM3", "true\nM3",
            "linuxcnc\nG0 Z-500", "G54\u2028G0 Z-500", "G54\x00M3", "%0AG0 Z-500"]
PARAMS = ("wcs", "dialect", "dry_run", "clearance_mm", "no_go", "detour")


def _bracket(c):
    return next(x for x in c.get("/api/v1/models", params={"kind": "workpiece"}).json()["data"]
                if x["key"] == "bracket_140")


def _confirmed(server, machine_id, T, **kw) -> int:
    with server.client() as c:
        wp = _bracket(c)
    sid = located_setup(server, machine_id, T, T_obj_datum=np.asarray(library_entry("bracket_140").T_obj_datum),
                        model=(wp["id"], wp["current_revision"]), **kw)
    with server.client("operator") as c:
        r = c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1})
        assert r.status_code == 200, r.text
    return sid


@pytest.fixture(scope="module")
def machine(server):
    with server.client() as c:
        return make_machine(c, None)


@pytest.fixture(scope="module")
def good_setup(server, machine):
    T = place_on_table(library_mesh("bracket_140"), 300.0, 150.0, 10.0)
    return _confirmed(server, machine["id"], T), T


def _get(server, sid, params):
    with server.client("operator") as c:
        return c.get(f"/api/v1/setups/{sid}/probing-program", params=params)


def _program_is_plain(text: str) -> None:
    for ln in text.splitlines():
        assert LINE.match(ln), repr(ln)
    assert "M3" not in text and "Z-500" not in text and "G53" not in text and "G10" not in text


def test_valid_parameters_give_a_plain_program(server, good_setup):
    sid, _ = good_setup
    for params in ({}, {"dialect": "linuxcnc"}, {"wcs": "g55", "dry_run": "true"}, {"wcs": "G59.3", "clearance_mm": "8"},
                   {"dialect": "LinuxCNC", "wcs": "G54", "dry_run": "false", "clearance_mm": "1"}):
        r = _get(server, sid, params)
        assert r.status_code == 200, (params, r.text)
        _program_is_plain(r.text)
        slot = params.get("wcs", "G54").upper()
        assert f"G21 G90 G17 G94 G40 {slot}" in r.text.splitlines()


@pytest.mark.parametrize("dialect", DIALECTS)
@pytest.mark.parametrize("param", PARAMS)
def test_injection_through_every_parameter_and_dialect(server, good_setup, param, dialect):
    sid, _ = good_setup
    for payload in PAYLOADS:
        params = {"dialect": dialect, param: payload}
        r = _get(server, sid, params)
        assert r.status_code == 422, (params, r.status_code, r.text)
        body = r.json()
        assert body.get("code") in ("invalid_parameter", "unknown_dialect", "dialect_not_supported", "wcs_not_a_slot",
                                    "clearance_out_of_range", "no_go_invalid", "unknown_detour"), (params, body)
        if param != "dialect" and dialect != "linuxcnc":
            assert body["code"] in ("dialect_not_supported", "invalid_parameter", "clearance_out_of_range",
                                    "wcs_not_a_slot", "no_go_invalid", "unknown_detour"), body


def test_unknown_and_repeated_parameters_are_refused(server, good_setup):
    sid, _ = good_setup
    with server.client("operator") as c:
        url = f"/api/v1/setups/{sid}/probing-program"
        r = c.get(url, params={"title": "x)\nM3 (", "wcs": "G54"})
        assert r.status_code == 422 and r.json()["code"] == "unknown_parameter", r.text
        r = c.get(url + "?wcs=G54&wcs=G0%20Z-500")
        assert r.status_code == 422 and r.json()["code"] == "repeated_parameter", r.text
        r = c.get(url + "?wcs=G54&wcs=G54")
        assert r.status_code == 422 and r.json()["code"] == "repeated_parameter", r.text


@pytest.mark.parametrize("controller, params, code", [
    ({"kind": "file", "dialect": "fanuc", "folder": "/tmp/setupcam-test-fanuc"}, {"wcs": "G59.1"}, "dialect_mismatch"),
    ({"kind": "file", "dialect": "linuxcnc", "folder": "/tmp/setupcam-test-lcnc"}, {"wcs": "G59.4"}, "wcs_not_a_slot"),
    ({"kind": "opcua", "endpoint": "opc.tcp://127.0.0.1:4840", "slot": "G55",
      "nodes": {"x": "ns=2;s=X", "y": "ns=2;s=Y", "z": "ns=2;s=Z"}}, {"wcs": "G54"}, "wcs_not_a_slot"),
])
def test_wcs_is_one_of_the_controllers_slots(server, controller, params, code):
    with server.client() as c:
        m = make_machine(c, controller)
    sid = _confirmed(server, m["id"], place_on_table(library_mesh("bracket_140"), 300.0, 150.0, 10.0))
    r = _get(server, sid, params)
    assert r.status_code == 422 and r.json()["code"] == code, r.text


def test_header_names_the_frame_and_the_obstacles_and_retracts_inside_the_travel(server, good_setup, machine):
    sid, T = good_setup
    text = _get(server, sid, {"dry_run": "true", "wcs": "G55"}).text
    lines = text.splitlines()
    assert lines[1].startswith("(frame: G55 = datum of block, setup") and "not read back here" in lines[1], lines[1]
    assert lines[2] == "(obstacles assumed: located 1, assumed 0, drawn 0)"
    assert lines[3].startswith("(obstacle located: block, top ")
    # retract: a program-frame Z that is above the part by the clearance and inside the machine's travel
    with server.client("operator") as c:
        off = c.get(f"/api/v1/setups/{sid}").json()["result"]["offset"]
    z = [float(ln.split()[1][1:]) for ln in lines if ln.startswith("G0 Z")]
    assert len(z) == 2 and z[0] == z[-1]
    z_machine = off["z_mm"] + z[0]
    top_machine = machine["T_machine_table"][2][3] + float(transform_points(T, library_mesh("bracket_140").vertices)[:, 2].max())
    assert top_machine + 5.0 <= z_machine <= machine["travel_mm"]["z"][1]


def test_the_exports_gates(server, machine):
    mesh = library_mesh("bracket_140")
    cases = {
        "uncertainty_fail": dict(T=place_on_table(mesh, 300.0, 150.0, 10.0), sigma_mm=3.0),
        "tilt": dict(T=pose_from_xyz_euler(300, 150, 40, 6.0, 0, 10)),
        # 1072 mm off, beyond the table and the travel (the case)
        "outside_travel": dict(T=place_on_table(mesh, 1372.0, 150.0, 10.0)),
    }
    for code, kw in cases.items():
        T = kw.pop("T")
        sid = _confirmed(server, machine["id"], T, **kw)
        for dry in ("false", "true"):
            r = _get(server, sid, {"dry_run": dry})
            assert r.status_code == 422 and r.json()["code"] == code, (code, r.text)
            assert "probing program refused" in r.json()["detail"]


def test_every_move_inside_the_travel(server):
    """The datum is inside the travel, but the touches beyond its faces are not."""
    mesh = library_mesh("bracket_140")
    T = place_on_table(mesh, 300.0, 150.0, 10.0)
    with server.client() as c:
        probe = make_machine(c, None)
    sid = _confirmed(server, probe["id"], T)
    with server.client("operator") as c:
        off = c.get(f"/api/v1/setups/{sid}").json()["result"]["offset"]
        prog = np.array([p for _, p in gcode_positions(_get(server, sid, {}).text) if not np.isnan(p).any()])
        xs = transform_points(WorkOffset(off["x_mm"], off["y_mm"], off["z_mm"], off["c_deg"]).to_pose(), prog)[:, 0]
    with server.client() as c:
        tight = make_machine(c, None, travel={"x": [off["x_mm"] - 2.0, 500], "y": [-300, 300], "z": [-400, 0]})
    assert min(xs) < off["x_mm"] - 2.0  # the program does go there
    sid2 = _confirmed(server, tight["id"], T)
    r = _get(server, sid2, {})
    assert r.status_code == 422 and r.json()["code"] == "outside_travel" and "moves end outside" in r.json()["detail"], r.text


def test_retract_must_fit_under_the_travel(server):
    mesh = library_mesh("bracket_140")
    T = place_on_table(mesh, 300.0, 150.0, 10.0)
    top = float(transform_points(T, mesh.vertices)[:, 2].max())
    datum_z = float((T @ np.asarray(library_entry("bracket_140").T_obj_datum))[2, 3])
    with server.client() as c:  # the datum fits, the tallest point plus the clearance does not
        m = make_machine(c, None, travel={"x": [-500, 500], "y": [-300, 300], "z": [-400, -300 + max(datum_z, top - 2.0)]})
    sid = _confirmed(server, m["id"], T)
    r = _get(server, sid, {})
    assert r.status_code == 422 and r.json()["code"] == "retract_above_travel", r.text


def test_objects_asked_for_but_not_located_refuse_with_their_names(server, good_setup, machine):
    _, T = good_setup
    sid = _confirmed(server, machine["id"], T)
    with server.client() as c:
        clamp = next(x for x in c.get("/api/v1/models", params={"kind": "clamp"}).json()["data"]
                     if x["key"] == "strap_clamp_125")
        wp = _bracket(c)
    with session_scope(server.app.state.engine) as session:
        s = session.get(Setup, sid)
        s.models = [{"model_id": wp["id"], "revision": wp["current_revision"]},
                    {"model_id": clamp["id"], "revision": clamp["current_revision"]}]
        s.result = {**s.result, "not_found": [{"name": clamp["name"], "model_id": clamp["id"],
                                               "reason": "edges not found", "kind": "not_found"}]}
        session.add(s)
    for dry in ("false", "true"):
        r = _get(server, sid, {"dry_run": dry})
        assert r.status_code == 422, r.text
        body = r.json()
        assert body["code"] == "obstacle_not_located" and clamp["name"] in body["detail"], body
    # the operator draws where the clamp is (away from the part): the program plans around that zone
    zone = "-380,100,-250,190,40"  # the test table model is centred on the table frame: x, y in +-400, +-200
    r = _get(server, sid, {"no_go": zone})
    assert r.status_code == 200, r.text
    head = r.text.splitlines()
    assert head[2] == "(obstacles assumed: located 1, assumed 1, drawn 1)"
    assert any(ln.startswith(f"(obstacle assumed: {clamp['name']}") and "inside the drawn zones" in ln for ln in head)
    assert any(ln.startswith("(obstacle drawn: drawn zone 1") for ln in head)
    _program_is_plain(r.text)
    # a zone over the part's faces blocks the touches, with its name
    r = _get(server, sid, {"no_go": "240,100,360,200,30"})
    assert r.status_code == 422 and r.json()["code"] == "obstacle_not_located" and "drawn zone 1" in r.json()["detail"]
    for bad in ("1,2,3", "0,0,0,10,5", "0,0,10,10,-1", "0,0,10,10,1e3", "0,0,900,10,5", "0,0,10,10,5;" * 21, "0x10,0,1,1,1"):
        r = _get(server, sid, {"no_go": bad})
        assert r.status_code == 422 and r.json()["code"] == "no_go_invalid", (bad, r.text)


@pytest.mark.linuxcnc
@pytest.mark.integration
def test_frame_must_be_exported_and_held_by_the_controller(server, lcnc):
    """With a live controller the program is offered only for a slot holding this revision's datum:
    exported and verified, and read back now."""
    with server.client() as c:
        m = make_machine(c, lcnc.settings)
    sid = _confirmed(server, m["id"], place_on_table(library_mesh("bracket_140"), 300.0, 150.0, 10.0))
    r = _get(server, sid, {"wcs": "G56"})
    assert r.status_code == 409 and r.json()["code"] == "frame_not_exported", r.text
    with server.client("operator") as c:
        e = c.post(f"/api/v1/setups/{sid}/export", json={"slot": "G56", "acknowledge_change": True})
        assert e.status_code == 200 and e.json()["status"] == "written", e.text
    r = _get(server, sid, {"wcs": "G56", "dry_run": "true"})
    assert r.status_code == 200, r.text
    head = r.text.splitlines()[1]
    assert head.startswith("(frame: G56 = datum of block") and f"verified export {e.json()['id']}, read back now" in head
    assert "G21 G90 G17 G94 G40 G56" in r.text.splitlines()
    lcnc.mdi("G10 L2 P3 X0 Y0 Z0 R0")  # someone changes G56 on the machine afterwards
    r = _get(server, sid, {"wcs": "G56"})
    assert r.status_code == 409 and r.json()["code"] == "frame_mismatch", r.text


def test_the_3d_view_draws_the_gated_plan(server, good_setup, machine):
    """The viewer draws the same plan (table frame) for a confirmed setup, and says why not otherwise."""
    from app.viewer.data import probing_paths

    sid, T = good_setup
    with session_scope(server.app.state.engine) as session:
        paths, why = probing_paths(session, server.app.state.files, session.get(Setup, sid), None, server.settings)
    assert why == "" and [p.name for p in paths if p.name.startswith("touch_")] == ["touch_x", "touch_y1", "touch_y2",
                                                                                      "touch_z"]
    top = float(transform_points(T, library_mesh("bracket_140").vertices)[:, 2].max())
    assert max(float(p.points_mm[:, 2].max()) for p in paths) >= top + 5.0  # table frame: over the part
    bad = _confirmed(server, machine["id"], place_on_table(library_mesh("bracket_140"), 300.0, 150.0, 10.0), sigma_mm=3.0)
    with session_scope(server.app.state.engine) as session:
        paths, why = probing_paths(session, server.app.state.files, session.get(Setup, bad), None, server.settings)
    assert paths == () and "uncertainty too large" in why
