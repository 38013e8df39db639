"""/api/v1/machines and /api/v1/health over real HTTP."""

from __future__ import annotations

import json

import pytest
import trimesh

from app.geometry.transforms import pose_from_xyz_euler

LAYOUT = {"dictionary": "DICT_5X5_100",
          "markers": [{"id": i, "size_mm": 40, "T_table_marker": pose_from_xyz_euler(50 + 100 * i, 30, 0).tolist()}
                      for i in range(4)]}
TRAVEL = {"x": [0, 1000], "y": [0, 500], "z": [-500, 0]}


@pytest.fixture(scope="module")
def table_id(server):
    with server.client() as c:
        data = trimesh.creation.box(extents=(800, 400, 60)).export(file_type="stl")
        r = c.post("/api/v1/models", files={"file": ("t.stl", data)},
                   data={"kind": "table", "name": "machine table", "fiducials": json.dumps(LAYOUT)})
        assert r.status_code == 201, r.text
        return r.json()["id"]


def test_health(client):
    r = client.get("/api/v1/health")
    assert r.status_code == 200
    body = r.json()
    assert body["status"] == "ok" and body["database"] == "ok"
    assert body["database_backend"] in ("sqlite", "postgresql")


def test_machine_crud(client, table_id):
    cam = client.post("/api/v1/cameras", json={"name": "m cam"}).json()
    T = pose_from_xyz_euler(100, 50, -400).tolist()
    r = client.post("/api/v1/machines", json={"name": "Mill 3", "table_model_id": table_id, "T_machine_table": T,
                                              "travel_mm": TRAVEL, "camera_ids": [cam["id"]],
                                              "controller": {"kind": "file", "dialect": "fanuc", "folder": "/tmp"}})
    assert r.status_code == 201, r.text
    m = r.json()
    assert m["table_revision"] == 1 and m["T_machine_table"] == T and m["camera_ids"] == [cam["id"]]
    r = client.patch(f"/api/v1/machines/{m['id']}", json={"travel_mm": {**TRAVEL, "x": [0, 1200]}})
    assert r.status_code == 200 and r.json()["travel_mm"]["x"] == [0, 1200]
    assert any(x["id"] == m["id"] for x in client.get("/api/v1/machines").json())
    assert client.delete(f"/api/v1/machines/{m['id']}").status_code == 204
    assert client.get(f"/api/v1/machines/{m['id']}").status_code == 404


def test_machine_rejections(client, server, table_id):
    part = client.post("/api/v1/models", files={"file": ("p.stl", trimesh.creation.box().export(file_type="stl"))},
                       data={"kind": "workpiece", "name": "not a table"}).json()
    bare = client.post("/api/v1/models", files={"file": ("t.stl", trimesh.creation.box(extents=(8, 4, 1)).export(file_type="stl"))},
                       data={"kind": "table", "name": "bare table"}).json()
    base = {"name": "m", "table_model_id": table_id, "travel_mm": TRAVEL}
    cases = [
        ({**base, "table_model_id": part["id"]}, "is a workpiece, not a table"),
        ({**base, "table_model_id": bare["id"]}, "has no fiducial layout"),
        ({**base, "table_model_id": 999999}, "model 999999 not found"),
        ({**base, "T_machine_table": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, "T_machine_table: expected shape (4, 4)"),
        ({**base, "travel_mm": {**TRAVEL, "z": [0, -500]}}, "travel_mm.z: min 0.0 must be below max -500.0"),
        ({**base, "camera_ids": [424242]}, "camera 424242 not found"),
        ({**base, "controller": {"kind": "telepathy"}}, "controller"),
    ]
    for body, detail in cases:
        r = client.post("/api/v1/machines", json=body)
        assert r.status_code in (404, 422) and detail in r.json()["detail"], (body, r.text)


def test_openapi_has_stable_operation_ids(client):
    spec = client.get("/openapi.json").json()
    ids = {op["operationId"] for path in spec["paths"].values() for op in path.values()}
    assert {"models-create_model", "cameras-calibrate", "machines-create_machine", "health-health"} <= ids


def test_editing_a_machine_keeps_its_masked_controller_password(client, server, table_id):
    """The machines page sends the controller back as it read it ("***" for secrets): the stored password
    stays, and a new one replaces it; a new controller kind starts without the old secrets."""
    from app.services.machines import get_machine
    from app.store.db import session_scope

    ctl = {"kind": "linuxcnc", "host": "10.0.0.5", "port": 5007, "connect_password": "s3cret"}
    m = client.post("/api/v1/machines", json={"name": "Mill 4", "table_model_id": table_id, "travel_mm": TRAVEL,
                                              "controller": ctl}).json()
    shown = m["controller"]
    assert shown["connect_password"] == "***" and "s3cret" not in str(m)

    def stored() -> dict:
        with session_scope(server.app.state.engine) as session:
            return dict(get_machine(session, m["id"]).controller)

    r = client.patch(f"/api/v1/machines/{m['id']}", json={"controller": {**shown, "host": "10.0.0.6"}})
    assert r.status_code == 200, r.text
    assert stored()["host"] == "10.0.0.6" and stored()["connect_password"] == "s3cret"
    client.patch(f"/api/v1/machines/{m['id']}", json={"controller": {**shown, "connect_password": "n3w"}})
    assert stored()["connect_password"] == "n3w"
    client.patch(f"/api/v1/machines/{m['id']}", json={"controller": {"kind": "file", "dialect": "fanuc",
                                                                     "folder": "/tmp"}})
    assert "connect_password" not in stored()


LIMITS = ("max_tilt_deg", "max_offset_change_mm", "max_offset_change_deg")


def test_machine_limits_are_its_own_or_the_global_settings(client, server, table_id):
    """A machine's max tilt and change limits: given on create, changed one at a time, null = back to the
    global setting; the page's placeholders come from /machines/default-limits."""
    defaults = client.get("/api/v1/machines/default-limits").json()
    assert defaults == {
        "max_tilt_deg": {"value": server.settings.max_tilt_deg, "setting": "SETUPCAM_MAX_TILT_DEG"},
        "max_offset_change_mm": {"value": server.settings.max_offset_change_mm,
                                 "setting": "SETUPCAM_MAX_OFFSET_CHANGE_MM"},
        "max_offset_change_deg": {"value": server.settings.max_offset_change_deg,
                                  "setting": "SETUPCAM_MAX_OFFSET_CHANGE_DEG"}}
    plain = client.post("/api/v1/machines", json={"name": "global", "table_model_id": table_id, "travel_mm": TRAVEL})
    assert plain.status_code == 201 and [plain.json()[k] for k in LIMITS] == [None, None, None], plain.text
    r = client.post("/api/v1/machines", json={"name": "own", "table_model_id": table_id, "travel_mm": TRAVEL,
                                              "max_tilt_deg": 0.5, "max_offset_change_mm": 1.5})
    assert r.status_code == 201, r.text
    mid = r.json()["id"]
    assert [r.json()[k] for k in LIMITS] == [0.5, 1.5, None]
    r = client.patch(f"/api/v1/machines/{mid}", json={"max_offset_change_deg": 0.25})
    assert r.status_code == 200 and [r.json()[k] for k in LIMITS] == [0.5, 1.5, 0.25], r.text
    r = client.patch(f"/api/v1/machines/{mid}", json={"max_tilt_deg": None, "name": "own, tilt global"})
    assert r.status_code == 200 and [r.json()[k] for k in LIMITS] == [None, 1.5, 0.25], r.text
    assert [client.get(f"/api/v1/machines/{mid}").json()[k] for k in LIMITS] == [None, 1.5, 0.25]
    with server.client("operator") as op:   # operators read them, never change them
        assert op.get(f"/api/v1/machines/{mid}").json()["max_offset_change_mm"] == 1.5
        assert op.patch(f"/api/v1/machines/{mid}", json={"max_offset_change_mm": 50}).status_code == 403
    with server.client("admin") as c:
        last = c.get("/api/v1/audit", params={"action": "machine.update"}).json()[0]
    assert last["detail"]["limits"] == {"max_tilt_deg": None, "max_offset_change_mm": 1.5,
                                        "max_offset_change_deg": 0.25}


@pytest.mark.parametrize("field, value, words", [
    ("max_tilt_deg", -0.1, "greater than or equal to 0"),
    ("max_tilt_deg", 11, "less than or equal to 10"),
    ("max_tilt_deg", "NaN", "must be finite"),
    ("max_offset_change_mm", 0, "greater than 0"),
    ("max_offset_change_mm", -5, "greater than 0"),
    ("max_offset_change_mm", "Infinity", "must be finite"),
    ("max_offset_change_mm", 1e6, "less than or equal to 1000"),
    ("max_offset_change_deg", 0, "greater than 0"),
    ("max_offset_change_deg", 181, "less than or equal to 180"),
    ("max_offset_change_deg", "a lot", "valid number"),
])
def test_machine_limits_out_of_bounds_are_refused_with_the_reason(client, table_id, field, value, words):
    """Bad limits are 422 with the field and why, on create and on edit, and change nothing."""
    m = client.post("/api/v1/machines", json={"name": f"bounds {field}", "table_model_id": table_id,
                                              "travel_mm": TRAVEL, "max_offset_change_mm": 2.0}).json()
    literal = value if value in ("NaN", "Infinity") else json.dumps(value)  # NaN/Infinity: what a sloppy client sends
    base = json.dumps({"name": "bad", "table_model_id": table_id, "travel_mm": TRAVEL})
    for method, url, body in (("POST", "/api/v1/machines", base[:-1] + f', "{field}": {literal}}}'),
                              ("PATCH", f"/api/v1/machines/{m['id']}", f'{{"{field}": {literal}}}')):
        r = client.request(method, url, content=body, headers={"Content-Type": "application/json"})
        assert r.status_code == 422, (method, r.text)
        if literal in ("NaN", "Infinity"):  # refused for the whole body before any field is looked at
            assert r.json()["code"] == "non_finite_number", r.text
        else:
            assert r.json()["code"] == "invalid_parameter" and r.json()["detail"].startswith(field), r.text
        assert words in r.json()["detail"], r.text
    after = client.get(f"/api/v1/machines/{m['id']}").json()
    assert after["name"] == f"bounds {field}" and after["max_offset_change_mm"] == 2.0
    assert not any(x["name"] == "bad" for x in client.get("/api/v1/machines").json())
