"""The probing program with the detour as a controller subroutine, over real HTTP (issue 16, part 3):
every dialect is fetched, parsed back and run by the small interpreters of
tests/planning/detour_interp.py; the points reached are the plan's travel and touches; the travel is
one subroutine call per move; bad choices are 422 with the reason."""

from __future__ import annotations

import re

import numpy as np
import pytest

from app.geometry.transforms import inv, transform_points
from app.planning.detour_emit import DETOUR_DIALECTS, SUB_NAME, SUFFIX
from app.synth.scene import place_on_table
from tests.api.test_planning import _program_frame
from tests.api.test_probing_gates import _confirmed
from tests.planning.detour_interp import corners, run
from tests.support.factories import make_machine
from tests.support.scenes import library_mesh

URL = "/api/v1/setups/{sid}/probing-program"


@pytest.fixture(scope="module")
def confirmed(server):
    with server.client() as c:
        m = make_machine(c, None)
    return _confirmed(server, m["id"], place_on_table(library_mesh("bracket_140"), 300.0, 150.0, 10.0))


@pytest.mark.parametrize("dialect", DETOUR_DIALECTS)
def test_subroutine_program_runs_the_plans_path(server, confirmed, dialect):
    sid = confirmed
    with server.client("operator") as c:
        dry = c.get(URL.format(sid=sid), params={"dialect": dialect, "detour": "subroutine", "dry_run": "true"})
        real = c.get(URL.format(sid=sid), params={"dialect": dialect, "detour": "subroutine"})
        plan = c.get(f"/api/v1/setups/{sid}/probing-plan", params={"dialect": dialect, "detour": "subroutine"})
        straight = c.get(URL.format(sid=sid), params={"dry_run": "true"})
        T_prog_table = _program_frame(c, sid)
    for r in (dry, real, plan, straight):
        assert r.status_code == 200, r.text
    assert dry.headers["content-disposition"].endswith(f'-probe{SUFFIX[dialect]}"')
    plan = plan.json()
    assert plan["detour"] == "subroutine" and "detour=subroutine" in plan["program_url"]
    n_touch = len(plan["touches"])
    assert n_touch == 4 and len(plan["travel_mm"]) == n_touch + 1
    # one subroutine, one call per move: the program stays short
    text = dry.text
    calls = {"linuxcnc": f"{SUB_NAME['linuxcnc']} call", "heidenhain": "CALL LBL 100", "fanuc": "G65 P9100",
             "siemens": "SC_DETOUR("}[dialect]
    blocks = [re.sub(r"^\d+ ", "", ln) for ln in text.splitlines()]  # HEIDENHAIN block numbers dropped
    assert sum(1 for ln in blocks if ln.startswith(calls)) == n_touch + 1
    # parse it back and run it: from above the start, every point the travel reaches is the plan's
    moves = run(dialect, text, (0.0, 0.0, 500.0))
    pts_table = transform_points(inv(T_prog_table), np.array([p for _, p in moves]))
    got = corners([(k, tuple(p)) for (k, _), p in zip(moves, pts_table)], tol_mm=0.02)
    want = []
    for k, travel in enumerate(plan["travel_mm"]):
        want += [tuple(p) for p in travel]
        if k < n_touch:  # dry run: feed to the nominal contact and back to the approach point
            want += [tuple(plan["touches"][k]["contact_mm"]), tuple(plan["touches"][k]["approach_tip_mm"])]
    want = corners([("", p) for p in want], tol_mm=0.02)  # the plan gives 2 decimals
    # got starts with the retract and the start above the part; the plan's travel starts at that start
    start = next(i for i, p in enumerate(got) if np.allclose(p, want[0], atol=0.01))
    got = got[start:]
    assert len(got) == len(want), (got, want)
    contact_tips = [np.asarray(t["contact_tip_prog_mm"]) for t in plan["touches"]]
    for g, w in zip(got, want):
        if np.allclose(g, w, atol=0.011):
            continue
        # the plan lists the contact point on the face; the program goes to the ball's tip there
        assert any(np.allclose(transform_points(T_prog_table, [g])[0], c, atol=0.011) for c in contact_tips), (g, w)
    # the real program probes once per touch
    probes = [k for k, _ in run(dialect, real.text, (0.0, 0.0, 500.0)) if k == "probe"]
    assert len(probes) == (n_touch if dialect != "heidenhain" else 0)
    if dialect == "heidenhain":
        assert real.text.count("TCH PROBE 4.0 MEASURING IN 3-D") == n_touch
    assert len(text.splitlines()) < len(straight.text.splitlines()) + 80 + 12 * len(plan["obstacles"])


@pytest.mark.parametrize("params, code, words", [
    ({"detour": "teleport"}, "unknown_detour", "straight, subroutine"),
    ({"detour": "subroutine", "dialect": "mazak"}, "unknown_dialect", "heidenhain"),
    ({"dialect": "fanuc"}, "dialect_not_supported", "detour=subroutine"),
    ({"detour": "subroutine", "dialect": "siemens", "wcs": "G59"}, "wcs_not_a_slot", "G57"),
])
def test_bad_detour_choices_are_refused_with_the_reason(server, confirmed, params, code, words):
    with server.client("operator") as c:
        for url in (URL.format(sid=confirmed), f"/api/v1/setups/{confirmed}/probing-plan"):
            r = c.get(url, params=params)
            assert r.status_code == 422, r.text
            assert r.json()["code"] == code and words in r.json()["detail"], r.json()


@pytest.mark.parametrize("dialect", DETOUR_DIALECTS)
def test_no_parameter_carries_code_into_a_subroutine_program(server, confirmed, dialect):
    """Every parameter of a subroutine program is checked against its closed set, in every dialect."""
    from tests.api.test_probing_gates import PAYLOADS

    with server.client("operator") as c:
        for param in ("wcs", "clearance_mm", "no_go", "detour"):
            for payload in PAYLOADS:
                r = c.get(URL.format(sid=confirmed), params={"dialect": dialect, "detour": "subroutine", param: payload})
                assert r.status_code == 422, (param, payload, r.text)
                assert r.json()["code"] in ("invalid_parameter", "wcs_not_a_slot", "clearance_out_of_range",
                                            "no_go_invalid", "unknown_detour"), (param, payload, r.json())


def test_options_offer_the_subroutine(server, confirmed):
    with server.client("operator") as c:
        opts = c.get(f"/api/v1/setups/{confirmed}/probing-options").json()
    assert opts["detours"] == ["straight", "subroutine"]
    assert sorted(opts["subroutine_dialects"]) == sorted(DETOUR_DIALECTS)
