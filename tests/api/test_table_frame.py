"""T_machine_table without maths, over real HTTP: read the machine's position from its controller
(LinuxCNC sim, a file drop, none) and work the table's pose out of jogged points, with its picture."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from tests.api.test_machines_health import LAYOUT, TRAVEL, table_id  # noqa: F401 - the module's table fixture

CORNER = (-450.0, -250.0, -320.0)


def _edge_point(c_deg: float, along_deg: float, span: float, dz: float = 0.0) -> dict:
    a = math.radians(c_deg + along_deg)
    return {"x_mm": CORNER[0] + span * math.cos(a), "y_mm": CORNER[1] + span * math.sin(a), "z_mm": CORNER[2] + dz}


def _corner() -> dict:
    return dict(zip(("x_mm", "y_mm", "z_mm"), CORNER))


def test_three_points_give_the_pose_and_a_picture_of_the_table(client, table_id):  # noqa: F811
    r = client.post("/api/v1/machines/table-frame", json={
        "table_model_id": table_id, "corner": _corner(), "x_edge": _edge_point(7.5, 0, 600, dz=-0.03),
        "y_edge": _edge_point(7.5, 90, 300)})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["c_deg"] == pytest.approx(7.5, abs=1e-9)
    T = np.asarray(body["T_machine_table"])
    assert T[:3, 3] == pytest.approx(CORNER)
    c, s = math.cos(math.radians(7.5)), math.sin(math.radians(7.5))
    assert np.allclose(T[:3, :3], [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-12)
    assert body["edge_disagreement_deg"] == pytest.approx(0.0, abs=1e-9)
    assert body["c_sensitivity_deg_per_mm"] == pytest.approx(math.degrees(1 / math.hypot(600, 300)))
    assert any("-0.030 mm above the corner" in n for n in body["notes"]), body["notes"]
    svg = body["svg"]
    assert svg.startswith("<svg") and 'class="table-outline"' in svg
    assert svg.count('class="marker"') == len(LAYOUT["markers"])
    jogged = dict((p, (float(x), float(y))) for p, x, y in
                  re.findall(r'data-point="(\d)" data-x-mm="([-\d.]+)" data-y-mm="([-\d.]+)"', svg))
    assert jogged["1"] == pytest.approx(CORNER[:2]) and set(jogged) == {"1", "2", "3"}
    assert "C 7.5000°" in svg


def test_bad_points_are_refused_with_the_reason(client, table_id):  # noqa: F811
    cases = [
        ({"x_edge": _edge_point(0, 0, 30)}, "is 30.0 mm from the corner"),
        ({"x_edge": _edge_point(0, 0, 500), "y_edge": _edge_point(4, 90, 300)}, "apart. Is point 3 on the left edge"),
        ({"corner": {"x_mm": 1, "y_mm": 2}}, "give X, Y and Z"),
        ({"table_model_id": 999999}, "not found"),
        ({"corner": {"x_mm": 1e300, "y_mm": 0, "z_mm": 0}}, "less than or equal to 100000"),
    ]
    for change, why in cases:
        body = {"table_model_id": table_id, "corner": _corner(), **change}
        r = client.post("/api/v1/machines/table-frame", json=body)
        assert r.status_code in (404, 422) and why in r.text, (change, r.status_code, r.text)


def _machine(client, table_id, controller) -> int:  # noqa: F811
    r = client.post("/api/v1/machines", json={"name": "frame test", "table_model_id": table_id, "travel_mm": TRAVEL,
                                              "controller": controller})
    assert r.status_code == 201, r.text
    return r.json()["id"]


def test_position_from_a_controller_that_cannot_tell_is_a_409_with_the_reason(client, table_id, tmp_path):  # noqa: F811
    r = client.get(f"/api/v1/machines/{_machine(client, table_id, None)}/position")
    assert r.status_code == 409 and r.json()["code"] == "no_controller", r.text
    mid = _machine(client, table_id, {"kind": "file", "dialect": "linuxcnc", "folder": str(tmp_path)})
    r = client.get(f"/api/v1/machines/{mid}/position")
    assert r.status_code == 409 and r.json()["code"] == "position_unavailable", r.text
    assert "type the position the controller shows" in r.json()["detail"]


@pytest.mark.linuxcnc
@pytest.mark.integration
def test_position_is_read_from_the_linuxcnc_sim(client, table_id, lcnc):  # noqa: F811
    mid = _machine(client, table_id, lcnc.settings)
    lcnc.mdi("G53 G0 X-412.5 Y-233.125 Z-287.25")
    r = client.get(f"/api/v1/machines/{mid}/position")
    assert r.status_code == 200, r.text
    got = r.json()
    assert [got["x_mm"], got["y_mm"], got["z_mm"]] == pytest.approx(lcnc.status()["position"], abs=1e-4)
    assert [got["x_mm"], got["y_mm"], got["z_mm"]] == pytest.approx([-412.5, -233.125, -287.25], abs=1e-4)
    lcnc.mdi("G53 G0 X0 Y0 Z0")
