"""/api/v1/models over real HTTP: every upload format, revisions, downloads, every rejection."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import pose_from_xyz_euler


def box_bytes(fmt: str, extents=(60.0, 40.0, 20.0)) -> bytes:
    mesh = trimesh.creation.box(extents=extents)
    return mesh.export(file_type=fmt)


def upload(client, data: bytes, filename: str, kind="workpiece", name="part", units="mm", **form):
    return client.post("/api/v1/models", files={"file": (filename, data)},
                       data={"kind": kind, "name": name, "units": units, **form})


@pytest.mark.parametrize("fmt", ["stl", "obj", "ply", "glb"])
def test_upload_each_mesh_format(client, fmt):
    r = upload(client, box_bytes(fmt), f"box.{fmt}", name=f"box {fmt}")
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["kind"] == "workpiece" and body["current_revision"] == 1
    ext = body["revision"]["summary"]["extents_mm"]
    assert np.allclose(sorted(ext), [20, 40, 60], atol=1e-6)
    assert body["revision"]["resting_poses"], "a box has stable resting poses"
    glb = client.get(body["mesh_url"])
    assert glb.status_code == 200 and glb.headers["content-type"] == "model/gltf-binary"
    back = trimesh.load(io.BytesIO(glb.content), file_type="glb", force="mesh")
    assert np.allclose(sorted(back.extents), [20, 40, 60], atol=1e-6)
    png = client.get(body["thumbnail_url"])
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"


def test_real_step_file_in_inch_is_stored_in_mm(client, external_data):
    data = (external_data / "trimesh_models" / "featuretype.STEP").read_bytes()
    r = upload(client, data, "featuretype.STEP", name="featuretype", units="mm")
    assert r.status_code == 201, r.text
    ext = sorted(r.json()["revision"]["summary"]["extents_mm"])
    # The STEP file carries its own length unit (inch): the part is 5 x 2.5 x 1.375 in.
    assert np.allclose(ext, sorted([127.0, 63.5, 34.925]), atol=0.05), ext


def test_stl_in_inch_is_scaled_to_mm(client, external_data):
    data = (external_data / "trimesh_models" / "featuretype.STL").read_bytes()
    r = upload(client, data, "featuretype.STL", name="featuretype stl", units="inch")
    assert r.status_code == 201, r.text
    assert np.allclose(sorted(r.json()["revision"]["summary"]["extents_mm"]), sorted([127.0, 63.5, 34.925]), atol=0.01)
    src = client.get(f"/api/v1/models/{r.json()['id']}/source")
    assert src.content == data, "the original file is kept byte for byte"


def test_revisions_are_immutable_and_reproducible(client):
    r = upload(client, box_bytes("stl"), "block.stl", name="revision block")
    mid = r.json()["id"]
    sha1 = r.json()["revision"]["glb_sha256"]
    datum = pose_from_xyz_euler(-30, -20, 10).tolist()
    r2 = client.post(f"/api/v1/models/{mid}/revisions", data={"T_obj_datum": json.dumps(datum), "note": "datum"})
    assert r2.status_code == 201, r2.text
    assert r2.json()["current_revision"] == 2
    assert r2.json()["revision"]["T_obj_datum"] == datum
    assert r2.json()["revision"]["glb_sha256"] == sha1, "frames changed, geometry did not"
    r3 = client.post(f"/api/v1/models/{mid}/revisions", files={"file": ("bigger.stl", box_bytes("stl", (80, 40, 20)))})
    assert r3.json()["current_revision"] == 3 and r3.json()["revision"]["T_obj_datum"] == datum
    old = client.get(f"/api/v1/models/{mid}", params={"revision": 1}).json()
    assert old["revision"]["T_obj_datum"] is None and old["revision"]["glb_sha256"] == sha1
    assert client.get(old["mesh_url"]).content == client.get(f"/api/v1/models/{mid}/mesh.glb?revision=1").content
    revs = client.get(f"/api/v1/models/{mid}/revisions").json()
    assert [x["revision"] for x in revs] == [1, 2, 3]
    nothing = client.post(f"/api/v1/models/{mid}/revisions", data={"note": "x"})
    assert nothing.status_code == 422 and "nothing to change" in nothing.json()["detail"]


def test_list_filter_and_soft_delete(client):
    a = upload(client, box_bytes("stl"), "a.stl", kind="clamp", name="Filter Clamp Alpha").json()
    upload(client, box_bytes("stl"), "b.stl", kind="workpiece", name="Filter Part Beta")
    clamps = client.get("/api/v1/models", params={"kind": "clamp", "name": "filter clamp"}).json()
    assert [m["name"] for m in clamps["data"]] == ["Filter Clamp Alpha"] and clamps["count"] == 1
    assert client.delete(f"/api/v1/models/{a['id']}").status_code == 204
    assert client.get("/api/v1/models", params={"name": "Filter Clamp"}).json()["count"] == 0
    assert client.get("/api/v1/models", params={"name": "Filter Clamp", "include_deleted": True}).json()["count"] == 1
    # Deleted models still reproduce: their revisions can be read.
    assert client.get(f"/api/v1/models/{a['id']}/mesh.glb").status_code == 200
    assert client.delete(f"/api/v1/models/{a['id']}").status_code == 404


def test_table_with_fiducials(client):
    layout = {"dictionary": "DICT_5X5_100",
              "markers": [{"id": 1, "size_mm": 40, "T_table_marker": pose_from_xyz_euler(50, 50, 0).tolist()}]}
    r = upload(client, box_bytes("stl", (800, 400, 60)), "table.stl", kind="table", name="t",
               fiducials=json.dumps(layout))
    assert r.status_code == 201, r.text
    assert r.json()["revision"]["fiducials"]["markers"][0]["id"] == 1
    # how well the markers sit where the layout says is part of the layout, kept as stated
    r = upload(client, box_bytes("stl", (800, 400, 60)), "table.stl", kind="table", name="t2",
               fiducials=json.dumps({**layout, "placement_sigma": {"position_mm": 0.15, "scale_rel": 0.002}}))
    assert r.status_code == 201, r.text
    assert r.json()["revision"]["fiducials"]["placement_sigma"] == {"position_mm": 0.15, "rotation_deg": None,
                                                                     "scale_rel": 0.002}


@pytest.mark.parametrize(
    "data, filename, form, status, detail",
    [
        (b"garbage bytes, not a mesh " * 50, "junk.stl", {}, 422, "could not read STL"),
        (b"ISO-10303-21;\nnonsense\n" * 20, "junk.step", {}, 422, "could not read STEP"),
        (b"", "empty.stl", {}, 422, "file is empty"),
        (trimesh.Trimesh().export(file_type="stl") if False else b"solid empty\nendsolid empty\n", "nofaces.stl", {}, 422, "0 faces"),
        (trimesh.creation.box(extents=(10, 10, 0)).export(file_type="stl"), "flat.stl", {}, 422, "flat"),
        (b"x" * 10, "part.xyz", {}, 422, "unsupported file type .xyz"),
        (b"\0" * 6_000_000, "huge.stl", {}, 413, "limit is 5.0 MB"),
        (trimesh.creation.icosphere(subdivisions=6).export(file_type="stl"), "dense.stl", {}, 413, "faces"),
        (box_bytes("stl"), "box.stl", {"kind": "spindle"}, 422, "unknown kind 'spindle'"),
        (box_bytes("stl"), "box.stl", {"units": "furlong"}, 422, "unknown units 'furlong'"),
        (box_bytes("stl"), "box.stl", {"T_obj_datum": "[[1,0],[0,1]]"}, 422, "T_obj_datum: expected shape (4, 4)"),
        (box_bytes("stl"), "box.stl", {"fiducials": '{"dictionary": "DICT_5X5_100", "markers": []}'}, 422,
         "fiducial layout invalid"),
        (box_bytes("stl"), "box.stl", {"fiducials": json.dumps({"dictionary": "DICT_5X5_100", "markers": [
            {"id": 1, "size_mm": 40, "T_table_marker": np.eye(4).tolist()}], "placement_sigma": {"rotation_deg": -1}})},
         422, "placement_sigma.rotation_deg"),
    ],
    ids=["junk", "junk-step", "empty", "no-faces", "flat", "unknown-format", "too-big", "too-many-faces", "kind", "units",
         "datum", "layout", "placement-sigma"],
)
def test_rejections_say_why(client, data, filename, form, status, detail):
    body = {"kind": "workpiece", "name": "bad", "units": "mm", **form}
    r = client.post("/api/v1/models", files={"file": (filename, data)}, data=body)
    assert r.status_code == status, r.text
    assert detail in r.json()["detail"], r.json()["detail"]


def test_missing_model_is_404(client):
    r = client.get("/api/v1/models/999999")
    assert r.status_code == 404 and r.json()["detail"] == "model 999999 not found"
