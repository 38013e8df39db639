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
