"""The probing page's data over real HTTP (issue 18, items 4 and 6): the plan as JSON goes through the
program's own gates (same refusals, same codes), names the frame and the obstacles with their source,
and its touches are the program's; the options are the controller's closed sets."""

from __future__ import annotations

import numpy as np

from app.planning.probing import gcode_positions
from app.planning.probing_safety import comment
from app.synth.scene import place_on_table
from tests.api.test_probing_gates import _confirmed
from tests.support.factories import make_machine
from tests.support.scenes import library_mesh


def _plan(server, sid, params=None):
    with server.client("operator") as c:
        return c.get(f"/api/v1/setups/{sid}/probing-plan", params=params or {})


def test_the_plan_is_the_program_as_data(server):
    with server.client() as c:
        m = make_machine(c, None)
    sid = _confirmed(server, m["id"], place_on_table(library_mesh("bracket_140"), 300.0, 150.0, 10.0))
    r = _plan(server, sid, {"wcs": "G55", "clearance_mm": "6"})
    assert r.status_code == 200, r.text
    plan = r.json()
    assert plan["slot"] == "G55" and plan["frame"].startswith("G55 = datum of block, setup")
    assert "not read back here" in plan["frame"]
    assert [(o["name"], o["source"]) for o in plan["obstacles"]] == [("block", "located")]
    assert [t["name"] for t in plan["touches"]] == ["x", "y1", "y2", "z"]
    assert len(plan["travel_mm"]) == 5 and plan["table_xy_mm"] == [-400.0, -200.0, 400.0, 200.0]
    # the program behind the page's download link touches exactly where the plan says
    with server.client("operator") as c:
        prog = c.get(plan["program_url"])
    assert prog.status_code == 200 and prog.headers["content-disposition"].endswith('-probe.ngc"')
    assert prog.text.splitlines()[1] == comment(f"frame: {plan['frame']}")  # the header's line, cut to fit
    g38 = [p for w, p in gcode_positions(prog.text) if w == "G38.2"]
    assert len(g38) == 4
    for t, end in zip(plan["touches"], g38):  # G38.2 ends overtravel beyond the contact, along the normal
        c_prog = np.asarray(t["contact_tip_prog_mm"])
        assert np.linalg.norm(end - c_prog) > 1.0
        assert np.linalg.norm(np.cross(end - c_prog, np.asarray(t["normal"]))[:2]) < 0.05
    with server.client("operator") as c:
        opts = c.get(f"/api/v1/setups/{sid}/probing-options").json()
    assert opts["dialects"] == ["linuxcnc"] and "G59.3" in opts["slots"] and opts["exported_slot"] is None
    assert opts["reads_back"] is False


def test_the_plan_refuses_like_the_program(server):
    """Same code and reason as the program: the frame a live controller does not hold (no verified
    export: refused before anything is read), a parameter outside its closed set, unknown parameters."""
    with server.client() as c:
        m = make_machine(c, {"kind": "opcua", "endpoint": "opc.tcp://127.0.0.1:9", "slot": "G54",
                             "nodes": {"x": "ns=2;s=X", "y": "ns=2;s=Y", "z": "ns=2;s=Z"}})
    sid = _confirmed(server, m["id"], place_on_table(library_mesh("bracket_140"), 300.0, 150.0, 10.0))
    with server.client("operator") as c:
        for params in ({}, {"wcs": "G55"}, {"wcs": "G54\nM3"}, {"clearance_mm": "50"}, {"title": "x"}):
            page = _plan(server, sid, params)
            prog = c.get(f"/api/v1/setups/{sid}/probing-program", params=params)
            assert page.status_code == prog.status_code and page.status_code in (409, 422), (params, page.text)
            assert page.json()["code"] == prog.json()["code"], (params, page.json(), prog.json())
        assert _plan(server, sid).json()["code"] == "frame_not_exported"
        assert _plan(server, sid, {"dry_run": "true"}).json()["code"] == "unknown_parameter"  # the page never runs dry
        opts = c.get(f"/api/v1/setups/{sid}/probing-options").json()
    assert opts["slots"] == ["G54"] and opts["reads_back"] is True
