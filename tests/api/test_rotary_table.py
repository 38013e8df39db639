"""A machine whose table sits on a rotary axis, over real HTTP: the settings (validated, the table's pose
derived from the chain), the angle recorded with a picture (typed or refused with the reason), and the
offset computed at the export angle. Machines without a rotary axis answer as before."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import trimesh

from app.geometry.rotary_chain import RotaryChain
from app.geometry.transforms import pose_from_xyz_euler
from tests.support.factories import INTRINSICS, LAYOUT, located_setup

TRAVEL = {"x": [-600, 600], "y": [-400, 400], "z": [-500, 0]}
T_MACHINE_AXIS = pose_from_xyz_euler(10.0, -20.0, -320.0, c_deg=0.3)
T_AXIS_TABLE = pose_from_xyz_euler(-400.0, -200.0, 0.0)


def _rotary(**kw) -> dict:
    return {"name": "C", "T_machine_axis": T_MACHINE_AXIS.tolist(), "T_axis_table": T_AXIS_TABLE.tolist(),
            "angle_from": "operator", "export_at_deg": 0.0, **kw}


@pytest.fixture(scope="module")
def parts(server):
    with server.client() as c:
        stl = trimesh.creation.box(extents=(800, 400, 60)).export(file_type="stl")
        table = c.post("/api/v1/models", files={"file": ("rt.stl", stl)},
                       data={"kind": "table", "name": "rotary table", "fiducials": json.dumps(LAYOUT)}).json()
        cam = c.post("/api/v1/cameras", json={"name": "rotary cam", "intrinsics": INTRINSICS}).json()
        block = c.post("/api/v1/models", files={"file": ("b.stl", trimesh.creation.box(extents=(60, 40, 20))
                                                         .export(file_type="stl"))},
                       data={"kind": "workpiece", "name": "rotary block"}).json()
        return {"table_model_id": table["id"], "camera_ids": [cam["id"]], "travel_mm": TRAVEL}, block["id"]


def test_the_table_pose_follows_the_axis_and_bad_settings_are_refused(client, parts):
    base, _ = parts
    r = client.post("/api/v1/machines", json={"name": "Rotary 1", **base, "rotary_axis": _rotary(export_at_deg=90.0)})
    assert r.status_code == 201, r.text
    m = r.json()
    chain = RotaryChain("C", T_MACHINE_AXIS, T_AXIS_TABLE)
    assert np.allclose(m["T_machine_table"], chain.T_machine_table(90.0))
    assert m["rotary_axis"]["name"] == "C" and m["rotary_axis"]["export_at_deg"] == 90.0
    # a new export angle moves the table's pose with it
    r = client.patch(f"/api/v1/machines/{m['id']}", json={"rotary_axis": _rotary(export_at_deg=0.0)})
    assert r.status_code == 200, r.text
    assert np.allclose(r.json()["T_machine_table"], chain.T_machine_table(0.0))
    # the pose as read may be sent back (a page's whole form); another pose is refused with the reason
    r = client.patch(f"/api/v1/machines/{m['id']}", json={"name": "Rotary 1b", "T_machine_table": r.json()["T_machine_table"]})
    assert r.status_code == 200, r.text
    r = client.patch(f"/api/v1/machines/{m['id']}", json={"T_machine_table": pose_from_xyz_euler(1, 2, 3).tolist()})
    assert r.status_code == 422 and r.json()["code"] == "table_pose_follows_axis", r.text
    assert "follows the axis" in r.json()["detail"]
    # dropping the axis keeps the pose the chain gave; the machine is then a plain one again
    r = client.patch(f"/api/v1/machines/{m['id']}", json={"rotary_axis": None})
    assert r.status_code == 200 and r.json()["rotary_axis"] is None
    assert np.allclose(r.json()["T_machine_table"], chain.T_machine_table(0.0))

    scaled = (np.diag([1.0, 1.0, 1.0, 1.0]) * [1.2, 1, 1, 1]).tolist()
    cases = [
        (_rotary(name="D"), "name"),
        (_rotary(T_machine_axis=scaled), "T_machine_axis"),
        (_rotary(T_axis_table=[[1, 0, 0], [0, 1, 0], [0, 0, 1]]), "T_axis_table"),
        (_rotary(angle_from="guess"), "angle_from"),
        (_rotary(export_at_deg=1000), "export_at_deg"),
        (_rotary(T_machine_axis=pose_from_xyz_euler(1e300, 0, 0).tolist()), "more than 100 m"),
        ({**_rotary(), "speed": 3}, "speed"),
    ]
    for rotary, words in cases:
        r = client.post("/api/v1/machines", json={"name": "bad", **base, "rotary_axis": rotary})
        assert r.status_code == 422 and words in r.json()["detail"], (rotary, r.text)
    # reading the angle needs a controller that reports it
    r = client.post("/api/v1/machines", json={"name": "bad", **base, "rotary_axis": _rotary(angle_from="controller"),
                                              "controller": {"kind": "file", "dialect": "fanuc", "folder": "/tmp"}})
    assert r.status_code == 422 and r.json()["code"] == "angle_not_readable", r.text
    assert "use 'operator'" in r.json()["detail"]


def test_old_machines_answer_as_before(client, parts):
    base, _ = parts
    T = pose_from_xyz_euler(-450, -250, -320).tolist()
    r = client.post("/api/v1/machines", json={"name": "Plain", **base, "T_machine_table": T})
    assert r.status_code == 201 and r.json()["rotary_axis"] is None and r.json()["T_machine_table"] == T
    r = client.post("/api/v1/machines", json={"name": "Plain 2", **base})  # no pose: the identity, as before
    assert r.status_code == 201 and r.json()["T_machine_table"] == np.eye(4).tolist()
    r = client.get(f"/api/v1/machines/{r.json()['id']}/rotary-axis")
    assert r.status_code == 409 and r.json()["code"] == "no_rotary_axis"


def _image() -> bytes:
    return cv2.imencode(".png", np.full((INTRINSICS["height"], INTRINSICS["width"], 3), 90, np.uint8))[1].tobytes()


def test_the_operator_types_the_angle_with_the_picture(server, client, parts):
    base, block = parts
    m = client.post("/api/v1/machines", json={"name": "Rotary typed", **base, "rotary_axis": _rotary()}).json()
    plain = client.post("/api/v1/machines", json={"name": "Plain typed", **base}).json()
    files = {"image": ("shot.png", _image(), "image/png")}
    with server.client("operator") as op:
        r = op.post("/api/v1/setups", data={"machine_id": str(m["id"]), "model_ids": str(block)}, files=files)
        assert r.status_code == 422 and r.json()["code"] == "table_angle_required", r.text
        assert "type the C angle" in r.json()["detail"]
        r = op.post("/api/v1/setups", data={"machine_id": str(m["id"]), "model_ids": str(block),
                                            "table_angle_deg": "nan"}, files=files)
        assert r.status_code == 422, r.text
        r = op.post("/api/v1/setups", data={"machine_id": str(plain["id"]), "model_ids": str(block),
                                            "table_angle_deg": "37"}, files=files)
        assert r.status_code == 422 and r.json()["code"] == "no_rotary_axis", r.text
        r = op.post("/api/v1/setups", data={"machine_id": str(m["id"]), "model_ids": str(block),
                                            "table_angle_deg": "37.5"}, files=files)
        assert r.status_code == 202, r.text
        s = op.get(r.json()["url"]).json()
        assert s["table_angle_deg"] == 37.5 and s["table_angle_from"] == "operator"
        r = op.post("/api/v1/setups", data={"machine_id": str(plain["id"]), "model_ids": str(block)}, files=files)
        s = op.get(r.json()["url"]).json()
        assert s["table_angle_deg"] is None and s["table_angle_from"] is None


def test_the_offset_is_the_chain_at_the_export_angle(server, client, parts):
    base, _ = parts
    m = client.post("/api/v1/machines", json={"name": "Rotary export", **base,
                                              "rotary_axis": _rotary(export_at_deg=-90.0)}).json()
    T_table_obj = pose_from_xyz_euler(300, 120, 0, c_deg=20)
    sid = located_setup(server, m["id"], T_table_obj)
    off = client.get(f"/api/v1/setups/{sid}").json()["result"]["offset"]
    T = RotaryChain("C", T_MACHINE_AXIS, T_AXIS_TABLE).T_machine_table(-90.0) @ T_table_obj
    assert off["axis"] == "C" and off["at_axis_deg"] == -90.0
    assert np.allclose([off["x_mm"], off["y_mm"], off["z_mm"]], T[:3, 3], atol=1e-6)
    assert off["c_deg"] == pytest.approx(20.0 + 0.3 - 90.0)


def test_the_3d_view_shows_the_table_turned_as_at_the_picture(server, client, parts):
    from app.store.db import session_scope
    from app.store.models import Setup
    from app.viewer.data import MeshCache, load_setup_view

    base, block = parts
    m = client.post("/api/v1/machines", json={"name": "Rotary view", **base, "rotary_axis": _rotary()}).json()
    plain = client.post("/api/v1/machines", json={"name": "Plain view", **base}).json()
    T_table_obj = pose_from_xyz_euler(300, 120, 10)
    sid = located_setup(server, m["id"], T_table_obj, model=(block, 1))
    with session_scope(server.app.state.engine) as session:
        s = session.get(Setup, sid)
        s.table_angle_deg, s.table_angle_from = 37.0, "operator"
        session.add(s)
    engine, files = server.app.state.engine, server.app.state.files
    view = load_setup_view(engine, files, MeshCache(), sid)
    chain = RotaryChain("C", T_MACHINE_AXIS, T_AXIS_TABLE)
    assert np.allclose(view.T_world_table, chain.turn(0.0, 37.0))
    # the axis line passes through the table's centre (400, 200), which T_AXIS_TABLE puts on the axis
    a, b = view.axis_mm
    assert np.allclose(a[:2], (400, 200), atol=1e-6) and np.allclose(b[:2], (400, 200), atol=1e-6)
    assert np.allclose(view.world(view.objects[0].T_table_obj), chain.turn(0.0, 37.0) @ T_table_obj)
    plain_view = load_setup_view(engine, files, MeshCache(), located_setup(server, plain["id"], T_table_obj,
                                                                          model=(block, 1)))
    assert np.allclose(plain_view.T_world_table, np.eye(4)) and plain_view.axis_mm is None


def test_an_offset_for_an_old_export_angle_is_not_exported(server, client, parts, tmp_path):
    base, _ = parts
    folder = tmp_path / "nc"
    folder.mkdir()
    m = client.post("/api/v1/machines", json={"name": "Rotary gate", **base, "rotary_axis": _rotary(),
                                              "controller": {"kind": "file", "dialect": "linuxcnc",
                                                             "folder": str(folder)}}).json()
    sid = located_setup(server, m["id"], pose_from_xyz_euler(300, 120, 0, c_deg=20))
    with server.client("operator") as op:
        assert op.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1}).status_code == 200
    r = client.patch(f"/api/v1/machines/{m['id']}", json={"rotary_axis": _rotary(export_at_deg=90.0)})
    assert r.status_code == 200, r.text
    with server.client("operator") as op:
        r = op.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54", "acknowledge_change": True})
    assert r.status_code == 422 and r.json()["code"] == "rotary_axis_changed", r.text
    assert "computed for C = 0°" in r.json()["detail"] and "C = 90°" in r.json()["detail"]
    assert not list(folder.iterdir())  # nothing written
    client.patch(f"/api/v1/machines/{m['id']}", json={"rotary_axis": _rotary()})
    with server.client("operator") as op:  # back at the angle it was computed for: written
        r = op.post(f"/api/v1/setups/{sid}/export", json={"slot": "G54", "acknowledge_change": True})
    assert r.status_code == 200 and r.json()["status"] == "written", r.text


def test_the_detour_subroutine_is_refused_on_a_rotary_table(server, client, parts):
    """The subroutine form does not check the table's angle before it moves: refused with the reason,
    while the written-out program (which aborts unless the axis stands at the export angle) is served."""
    base, _ = parts
    from tests.api.test_probing_gates import _confirmed
    from app.synth.scene import place_on_table
    from tests.support.scenes import library_mesh

    m = client.post("/api/v1/machines", json={"name": "Rotary detour", **base, "rotary_axis": _rotary()}).json()
    sid = _confirmed(server, m["id"], place_on_table(library_mesh("bracket_140"), 300.0, 150.0, 10.0))
    with server.client("operator") as op:
        r = op.get(f"/api/v1/setups/{sid}/probing-program", params={"detour": "subroutine"})
        assert r.status_code == 422 and "rotary table" in r.json()["detail"], r.text
        r = op.get(f"/api/v1/setups/{sid}/probing-program")
        assert r.status_code == 200 and "#<setupcam_axis> = [#5425" in r.text, r.text
