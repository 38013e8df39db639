"""No 500 on bad input (issue 17, item 5): each case a careless or hostile client sent answers a 4xx with
the reason, over real HTTP on SQLite and PostgreSQL."""

from __future__ import annotations

import json
from urllib.parse import unquote

import cv2
import numpy as np
import pytest
import trimesh

from app.geometry.transforms import pose_from_xyz_euler
from tests.support.factories import located_setup, make_machine


def _png(w: int, h: int) -> bytes:
    return cv2.imencode(".png", np.full((h, w, 3), 90, np.uint8))[1].tobytes()


@pytest.fixture(scope="module")
def machine(server):
    with server.client("admin") as c:
        return make_machine(c, None)


def test_rotary_images_of_another_size_than_the_calibration(server, machine):
    with server.client("mes") as c:
        r = c.post("/api/v1/rotary/runs", data={"camera_id": str(machine["camera_ids"][0]), "angles_deg": "0,10"},
                   files=[("images", ("a.png", _png(320, 200))), ("images", ("b.png", _png(640, 480)))])
    assert r.status_code == 422, r.text
    assert "'b.png' is 640 x 480 px but camera" in r.json()["detail"]


def test_sheet_camera_below_the_bed(server, machine):
    below = pose_from_xyz_euler(0, 0, 500).tolist()  # bed z points away from the camera: camera under the bed
    with server.client("mes") as c:
        r = c.post("/api/v1/sheet/alignments", files={"image": ("bed.png", _png(320, 200))},
                   data={"machine_id": str(machine["id"]), "camera_id": str(machine["camera_ids"][0]),
                         "thickness_mm": "2", "T_cam_bed": json.dumps(below)})
    assert r.status_code == 422, r.text
    assert "above the bed" in r.json()["detail"]


@pytest.mark.parametrize("field", ["thickness_mm", "margin_mm"])
def test_sheet_form_numbers_must_be_finite(server, machine, field):
    data = {"machine_id": str(machine["id"]), "camera_id": str(machine["camera_ids"][0]), "thickness_mm": "2",
            field: "nan"}
    with server.client("mes") as c:
        r = c.post("/api/v1/sheet/alignments", files={"image": ("bed.png", _png(320, 200))}, data=data)
    assert r.status_code == 422 and field in r.text, r.text


def test_non_latin1_and_path_file_names_are_sanitised_and_sent_rfc5987(server):
    stl = trimesh.creation.box(extents=(30, 20, 10)).export(file_type="stl")
    name = "../../etc/Spannvorrichtung-Ø40 治具.stl"
    with server.client("admin") as c:
        r = c.post("/api/v1/models", files={"file": (name, stl)}, data={"kind": "workpiece", "name": "fixture"})
        assert r.status_code == 201, r.text
        model = r.json()
        assert model["revision"]["source_filename"] == "Spannvorrichtung-Ø40 治具.stl"
        r = c.get(f"/api/v1/models/{model['id']}/source")
    assert r.status_code == 200 and r.content == stl
    cd = r.headers["content-disposition"]
    assert cd.startswith('inline; filename="Spannvorrichtung-_40 __.stl"'), cd
    encoded = cd.split("filename*=UTF-8''", 1)[1]
    assert unquote(encoded) == "Spannvorrichtung-Ø40 治具.stl"


def test_file_name_sanitising():
    from app.api.uploads import content_disposition, safe_filename

    assert safe_filename("C:\\parts\\a\x00b\x1f\x7f\"c;.stl") == "abc.stl"
    assert safe_filename("../..") == "upload" and safe_filename(None) == "upload"
    assert safe_filename("x" * 300 + ".step").endswith(".step") and len(safe_filename("x" * 300 + ".step")) == 200
    assert content_disposition("plain.csv") == 'inline; filename="plain.csv"'
    cd = content_disposition("tür\r\nSet-Cookie: x.csv", "attachment")
    assert "\r" not in cd and "\n" not in cd and cd.encode("latin-1")
    assert cd == "attachment; filename=\"t_rSet-Cookie: x.csv\"; filename*=UTF-8''t%C3%BCrSet-Cookie%3A%20x.csv"


HUGE_IDS = [2**31, 2**63, 10**30, -1, 0]
GETS = ["/api/v1/setups/{}", "/api/v1/cameras/{}", "/api/v1/machines/{}", "/api/v1/models/{}",
        "/api/v1/rotary/runs/{}", "/api/v1/sheet/alignments/{}", "/api/v1/sheet/monitors/{}",
        "/api/v1/setups/{}/exports", "/api/v1/cameras/1/calibrations/{}", "/api/v1/models/{}/mesh.glb"]


@pytest.mark.parametrize("ident", HUGE_IDS)
def test_ids_out_of_range_are_404(server, ident):
    with server.client("admin") as c:
        for path in GETS:
            r = c.get(path.format(ident))
            assert r.status_code == 404, (path, r.status_code, r.text)
            assert "not found" in r.json()["detail"]
        for path, body in (("/api/v1/setups/{}/confirm", {"result_revision": 1}),
                           ("/api/v1/apikeys/{}", None), ("/api/v1/cameras/{}", None)):
            r = c.request("DELETE" if body is None else "POST", path.format(ident), json=body)
            assert r.status_code == 404, (path, r.status_code, r.text)


def test_ids_out_of_range_in_bodies_and_queries_are_4xx(server, machine):
    with server.client("admin") as c:
        r = c.get("/api/v1/setups", params={"machine_id": 2**63})
        assert r.status_code in (200, 404), r.text
        r = c.get("/api/v1/audit", params={"setup_id": 2**40})
        assert r.status_code in (200, 404), r.text
        r = c.patch(f"/api/v1/machines/{machine['id']}", json={"camera_ids": [2**40]})
        assert 400 <= r.status_code < 500, r.text
        r = c.post("/api/v1/setups", data={"machine_id": str(2**63)}, files={"image": ("a.png", _png(320, 200))})
        assert r.status_code == 404, r.text


def test_patch_with_null_name_is_refused(server, machine):
    with server.client("admin") as c:
        r = c.patch(f"/api/v1/cameras/{machine['camera_ids'][0]}", json={"name": None})
        assert r.status_code == 422 and "name: must not be null" in r.json()["detail"], r.text
        for key in ("name", "travel_mm", "camera_ids", "T_machine_table", "table_model_id"):
            r = c.patch(f"/api/v1/machines/{machine['id']}", json={key: None})
            assert r.status_code == 422 and f"{key}: must not be null" in r.json()["detail"], r.text
        assert c.get(f"/api/v1/machines/{machine['id']}").json()["name"] == machine["name"]


@pytest.mark.parametrize("raw", ['{"object_index": 0, "nudge": {"dx_mm": NaN}}',
                                 '{"object_index": 0, "nudge": {"dc_deg": Infinity}}',
                                 '{"object_index": 0, "nudge": {"dy_mm": -1e999}}',
                                 '{"object_index": 0, "nudge": {"dz_mm": 1e6}}'])
def test_non_finite_or_huge_nudge_is_refused(server, machine, raw):
    setup_id = located_setup(server, machine["id"], pose_from_xyz_euler(100, 50, 0))
    with server.client("operator") as c:
        r = c.post(f"/api/v1/setups/{setup_id}/adjust", content=raw, headers={"Content-Type": "application/json"})
        assert r.status_code == 422, r.text
        assert c.get(f"/api/v1/setups/{setup_id}").json()["result_revision"] == 1, "nothing was changed"


@pytest.mark.parametrize("travel", ['{"x": [0, Infinity], "y": [0, 500], "z": [-500, 0]}',
                                    '{"x": [0, 1e999], "y": [0, 500], "z": [-500, 0]}',
                                    '{"x": [NaN, 10], "y": [0, 500], "z": [-500, 0]}'])
def test_infinite_travel_is_refused(server, machine, travel):
    with server.client("admin") as c:
        r = c.patch(f"/api/v1/machines/{machine['id']}", content=f'{{"travel_mm": {travel}}}',
                    headers={"Content-Type": "application/json"})
        assert r.status_code == 422 and "finite" in r.json()["detail"], r.text


def test_travel_beyond_any_machine_is_refused_by_the_service(server, machine):
    with server.client("admin") as c:
        r = c.patch(f"/api/v1/machines/{machine['id']}", json={"travel_mm": {"x": [0, 1e300], "y": [0, 5],
                                                                            "z": [-5, 0]}})
        assert r.status_code == 422 and "finite numbers within" in r.json()["detail"], r.text


def test_rotary_angles_must_be_finite(server, machine):
    with server.client("mes") as c:
        r = c.post("/api/v1/rotary/runs", data={"camera_id": str(machine["camera_ids"][0]), "angles_deg": "0,inf"},
                   files=[("images", ("a.png", _png(320, 200))), ("images", ("b.png", _png(320, 200)))])
    assert r.status_code == 422 and "finite" in r.json()["detail"], r.text


def test_422_bodies_follow_the_openapi_schema(server):
    with server.client("admin") as c:
        schema = c.get("/openapi.json").json()
        problem = schema["components"]["schemas"]["HTTPValidationError"]
        assert problem["properties"]["detail"]["type"] == "string"
        assert schema["paths"]["/api/v1/cameras"]["post"]["responses"]["422"]["content"]["application/json"][
            "schema"] == {"$ref": "#/components/schemas/HTTPValidationError"}
        r = c.post("/api/v1/cameras", json={"name": ""})
        assert r.status_code == 422
        body = r.json()
        assert isinstance(body["detail"], str) and body["detail"].startswith("name:")
        assert all({"loc", "msg", "type"} <= set(e) for e in body["errors"])


def test_setup_image_is_answered_with_the_type_it_was_stored_with(server, machine):
    """The capture's media type is stored with the file (PNG, JPEG as uploaded) and answered as stored."""
    png = _png(320, 200)
    jpg = cv2.imencode(".jpg", np.full((200, 320, 3), 90, np.uint8))[1].tobytes()
    with server.client("admin") as c:
        for name, data, media in (("a.png", png, "image/png"), ("a.jpg", jpg, "image/jpeg")):
            r = c.post("/api/v1/setups", data={"machine_id": str(machine["id"])}, files={"image": (name, data)})
            assert r.status_code == 202, r.text
            got = c.get(f"/api/v1/setups/{r.json()['id']}/image")
            assert got.status_code == 200 and got.content == data and got.headers["content-type"] == media
