"""Photo models over real HTTP (issue 16): teach a plate from uploaded pictures (POST /api/v1/models/photo),
then locate a repeat placement through the normal setup flow and get the right pose, sigma and PASS."""

from __future__ import annotations

import numpy as np
import pytest

from tests.support.photo_pictures import (
    jpeg,
    other_camera_pose,
    photo_machine,
    pictures,
)
from tests.support.sample_setup import wait_for

pytestmark = [pytest.mark.slow, pytest.mark.integration]


def test_teach_from_pictures_then_locate_a_repeat_placement(client) -> None:
    teach1, teach2, repeat = pictures()
    mid = photo_machine(client)
    files = [("pictures", (f"teach{i}.jpg", jpeg(s.image), "image/jpeg")) for i, s in enumerate((teach1, teach2))]
    # the datum clicked on the teach picture: the plate's front-left top corner, in table coordinates
    corner = teach1.T_table_obj @ np.array([0.0, 0.0, 12.0, 1.0])
    r = client.post("/api/v1/models/photo", files=files, data={
        "machine_id": str(mid), "name": "Plate A (taught)", "kind": "workpiece", "height_mm": "12",
        "datum_xy_mm": f"[{corner[0]:.3f}, {corner[1]:.3f}]"})
    assert r.status_code == 201, r.text
    model = r.json()
    assert model["source"] == "photo" and model["kind"] == "workpiece"
    photo = model["revision"]["photo"]
    assert photo["height_mm"] == 12.0 and photo["n_views"] == 2 and photo["holes"] == 2
    # the template's edges: the notched outline (about 440 mm) and two holes (about 100 mm)
    assert 400 < photo["edge_length_mm"] < 700
    pic = client.get(photo["teach_picture_url"])
    assert pic.status_code == 200 and pic.content[:4] == b"\x89PNG"
    assert client.get(model["thumbnail_url"]).status_code == 200
    assert model["revision"]["summary"]["extents_mm"][2] == pytest.approx(12.0, abs=0.01)

    # the repeat placement through the normal setup flow
    r = client.post("/api/v1/setups", data={"machine_id": str(mid), "model_ids": str(model["id"])},
                    files={"image": ("repeat.jpg", jpeg(repeat.image), "image/jpeg")})
    assert r.status_code == 202, r.text
    setup = wait_for(client, r.json()["url"], lambda b: b["status"] in ("located", "failed"), 240, "setup")
    assert setup["status"] == "located", setup.get("reason")
    (obj,) = setup["result"]["objects"]
    assert obj["name"] == "Plate A (taught)" and obj["model_id"] == model["id"]
    T = np.asarray(obj["T_table_obj"])
    T_teach = np.asarray(photo["T_table_obj_teach"])
    truth = repeat.T_table_obj @ np.linalg.inv(teach1.T_table_obj) @ T_teach
    err = np.hypot(*(T[:2, 3] - truth[:2, 3]))
    derr = np.degrees(np.arctan2(T[1, 0], T[0, 0]) - np.arctan2(truth[1, 0], truth[0, 0]))
    assert err < 0.2 and abs((derr + 180) % 360 - 180) < 0.05, (err, derr)
    assert obj["uncertainty_pass"], obj["uncertainty_reason"]
    # two markers in view: the error their sides share is in the table's sigma (0.076 -> 0.102 mm in x)
    assert obj["sigma"]["x_mm"] < 0.15 and obj["sigma"]["rz_deg"] < 0.05
    # the sigma carries the table pose's error (the markers' covariance) and the edge bias
    parts = obj["photo"]["cov_parts"]
    assert np.sqrt(parts["table"][0][0]) > 0.003 and parts["edge_bias_mm2"] > 0.05
    # "refine from here" finds the same pose with the same sigma (the table's covariance again)
    r = client.post(f"/api/v1/setups/{setup['id']}/refine", json={"object_index": 0})
    assert r.status_code == 200, r.text
    (ref,) = r.json()["result"]["objects"]
    assert np.allclose(np.asarray(ref["T_table_obj"])[:2, 3], T[:2, 3], atol=0.02)
    assert ref["sigma"]["x_mm"] == pytest.approx(obj["sigma"]["x_mm"], rel=0.1)
    assert np.asarray(ref["photo"]["cov_parts"]["table"]) == pytest.approx(np.asarray(parts["table"]), rel=0.1)
    # the offset is the clicked datum: the plate's corner where the repeat put it, in machine coordinates
    off = setup["result"]["offset"]
    corner_rep = repeat.T_table_obj @ np.array([0.0, 0.0, 12.0, 1.0])
    assert off["x_mm"] == pytest.approx(corner_rep[0] - 450, abs=0.3)
    assert off["y_mm"] == pytest.approx(corner_rep[1] - 250, abs=0.3)
    assert off["z_mm"] == pytest.approx(12 - 320, abs=0.3)


def test_teach_refusals_say_why(server, client) -> None:
    teach1, _, _ = pictures()
    mid = photo_machine(client)
    pic = [("pictures", ("t.jpg", jpeg(teach1.image), "image/jpeg"))]
    r = client.post("/api/v1/models/photo", data={"machine_id": str(mid), "name": "x", "height_mm": "12"})
    assert r.status_code == 422 and "no picture" in r.json()["detail"]
    r = client.post("/api/v1/models/photo", files=pic, data={"machine_id": str(mid), "name": "x", "kind": "support",
                                                              "height_mm": "12"})
    assert r.status_code == 422 and "workpiece or a clamp" in r.json()["detail"]
    r = client.post("/api/v1/models/photo", files=pic, data={"machine_id": str(mid), "name": "x"})
    assert r.status_code == 422 and r.json()["code"] == "height_needed"
    r = client.post("/api/v1/models/photo", files=pic, data={"machine_id": str(mid), "name": "x", "height_mm": "12",
                                                              "region_mm": "[1, 2]"})
    assert r.status_code == 422 and "region_mm" in r.json()["detail"]
    blank = np.full((800, 1280), 120, np.uint8)
    r = client.post("/api/v1/models/photo", files=[("pictures", ("b.jpg", jpeg(blank), "image/jpeg"))],
                    data={"machine_id": str(mid), "name": "x", "height_mm": "12"})
    assert r.status_code == 422 and r.json()["code"] == "table_not_found" and "picture 1" in r.json()["detail"]
    with server.client("operator") as op:      # teaching is the admin's
        r = op.post("/api/v1/models/photo", files=pic, data={"machine_id": str(mid), "name": "x", "height_mm": "12"})
    assert r.status_code == 403, r.text
    r = client.post("/api/v1/models/photo", files=pic, data={"machine_id": str(mid), "name": "x", "height_mm": "12"})
    assert r.status_code == 201, r.text
    # a photo model's geometry comes from its pictures, not from a file
    r = client.post(f"/api/v1/models/{r.json()['id']}/revisions",
                    files={"file": ("x.stl", b"solid x\nendsolid x\n", "application/octet-stream")})
    assert r.status_code == 422 and r.json()["code"] == "photo_model_geometry"


def test_height_measured_from_two_camera_poses(client) -> None:
    """No height given: two pictures of the unmoved plate from two camera poses measure it (12 mm)."""
    teach1, _, _ = pictures()
    mid = photo_machine(client)
    files = [("pictures", (f"v{i}.jpg", jpeg(s.image), "image/jpeg")) for i, s in enumerate((teach1, other_camera_pose()))]
    r = client.post("/api/v1/models/photo", files=files, data={"machine_id": str(mid), "name": "Plate A (measured)",
                                                                "kind": "clamp"})
    assert r.status_code == 201, r.text
    photo = r.json()["revision"]["photo"]
    assert photo["height_source"] == "measured" and photo["height_mm"] == pytest.approx(12.0, abs=0.5)
    assert r.json()["kind"] == "clamp"
