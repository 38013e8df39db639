"""Support models and declared support surfaces over real HTTP (SQLite and PostgreSQL): create, read
back, revise, every rejection with its reason; the example library's fixtures; setups accept them."""

from __future__ import annotations

import json
import time

import cv2
import numpy as np
import pytest
import trimesh

from tests.support.factories import make_machine

TOP_25 = [{"name": "top", "z_mm": 25.0, "outline_xy": [[-75.0, -4.0], [75.0, -4.0], [75.0, 4.0], [-75.0, 4.0]]}]


def parallel_stl(height: float = 25.0) -> bytes:
    """A parallel 150 x 8 x ``height``: base centre at the origin, x along the length, z up."""
    return trimesh.creation.box(bounds=[[-75, -4, 0], [75, 4, height]]).export(file_type="stl")


def upload(client, data: bytes, kind="support", name="parallel", **form):
    return client.post("/api/v1/models", files={"file": ("p.stl", data)},
                       data={"kind": kind, "name": name, "units": "mm", **form})


def test_support_model_with_surfaces_round_trip(client):
    r = upload(client, parallel_stl(), name="Round-trip parallel 25", support_surfaces=json.dumps(TOP_25))
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["kind"] == "support" and body["revision"]["support_surfaces"] == TOP_25
    mid = body["id"]
    assert client.get(f"/api/v1/models/{mid}").json()["revision"]["support_surfaces"] == TOP_25
    assert client.get(f"/api/v1/models/{mid}/revisions").json()[0]["support_surfaces"] == TOP_25
    listed = client.get("/api/v1/models", params={"kind": "support", "name": "round-trip parallel"}).json()
    assert listed["count"] == 1 and listed["data"][0]["revision"]["support_surfaces"] == TOP_25
    # integers are stored as floats; names are trimmed
    r = upload(client, parallel_stl(), name="Int parallel", support_surfaces=json.dumps(
        [{"name": " top ", "z_mm": 25, "outline_xy": [[-75, -4], [75, -4], [75, 4], [-75, 4]]}]))
    assert r.status_code == 201 and r.json()["revision"]["support_surfaces"] == TOP_25, r.text
    # left out: derived from the mesh (null); [] : carries nothing; both are kept apart
    r = upload(client, parallel_stl(), name="Plain parallel")
    assert r.status_code == 201 and r.json()["revision"]["support_surfaces"] is None, r.text
    r = upload(client, parallel_stl(), name="Empty parallel", support_surfaces="[]")
    assert r.status_code == 201 and r.json()["revision"]["support_surfaces"] == [], r.text
    # the other kinds still answer support_surfaces (null)
    r = upload(client, parallel_stl(), kind="workpiece", name="A bar workpiece")
    assert r.status_code == 201 and r.json()["revision"]["support_surfaces"] is None


def test_example_library_fixtures_carry_their_declared_surfaces(client):
    """The example library is loaded at start on a fresh database (migrations included): the vises'
    seats and the parallels' top faces are declared."""
    models = {m["key"]: m for m in client.get("/api/v1/models", params={"limit": 500}).json()["data"] if m["key"]}
    seat = models["vise_150"]["revision"]["support_surfaces"]
    assert seat == [{"name": "seat", "z_mm": 70.0, "outline_xy": [[0.0, -55.0], [80.0, -55.0], [80.0, 55.0], [0.0, 55.0]]}]
    assert models["vise_125"]["kind"] == "clamp"
    assert models["vise_125"]["revision"]["support_surfaces"][0]["z_mm"] == 55.0
    for key, h in (("parallel_150x25x8", 25.0), ("parallel_150x32x8", 32.0)):
        m = models[key]
        assert m["kind"] == "support" and m["revision"]["support_surfaces"][0]["z_mm"] == h
        assert np.allclose(m["revision"]["summary"]["extents_mm"], [150, 8, h])
    assert models["strap_clamp_125"]["revision"]["support_surfaces"] is None
    supports = client.get("/api/v1/models", params={"kind": "support"}).json()["data"]
    assert {"parallel_150x25x8", "parallel_150x32x8"} <= {m["key"] for m in supports}


def _surface(**kw):
    return [{"name": "top", "z_mm": 25, "outline_xy": [[-75, -4], [75, -4], [75, 4], [-75, 4]], **kw}]


BAD_SURFACES = [
    ("not-json", "[{name: top}]", "support_surfaces: not valid JSON"),
    ("not-a-list", json.dumps({"name": "top"}), "support_surfaces: expected a list of surfaces (or null), got dict"),
    ("two-points", json.dumps(_surface(outline_xy=[[0, 0], [10, 0]])),
     "support_surfaces[0].outline_xy: List should have at least 3 items"),
    ("point-xyz", json.dumps(_surface(outline_xy=[[0, 0], [10, 0, 5], [0, 4]])),
     "support_surfaces[0].outline_xy: point 1 must be [x, y]"),
    ("nan", '[{"name": "top", "z_mm": NaN, "outline_xy": [[0, 0], [10, 0], [0, 4]]}]',
     "support_surfaces[0].z_mm: Input should be a finite number"),
    ("infinite-x", '[{"name": "top", "z_mm": 25, "outline_xy": [[0, 0], [Infinity, 0], [0, 4]]}]',
     "support_surfaces[0].outline_xy[1][0]: Input should be a finite number"),
    ("text-height", json.dumps(_surface(z_mm="25")), "support_surfaces[0].z_mm: Input should be a valid number"),
    ("collinear", json.dumps(_surface(outline_xy=[[-75, 0], [0, 0], [75, 0]])), "encloses 0 mm²"),
    ("no-name", json.dumps([{"z_mm": 25, "outline_xy": [[0, 0], [10, 0], [0, 4]]}]),
     "support_surfaces[0].name: Field required"),
    ("blank-name", json.dumps(_surface(name="  ")), "support_surfaces[0].name: name must not be empty"),
    ("unknown-field", json.dumps(_surface(height=3)), "support_surfaces[0].height: Extra inputs are not permitted"),
    ("twice", json.dumps(_surface() + _surface()), "support_surfaces: name 'top' appears twice"),
    ("too-many", json.dumps([_surface(name=f"s{i}")[0] for i in range(17)]), "support_surfaces: 17 surfaces; at most 16"),
    ("above-the-model", json.dumps(_surface(z_mm=250)), "support surface 'top' at z 250 mm is outside the model"),
    ("beside-the-model", json.dumps(_surface(outline_xy=[[0, 0], [300, 0], [300, 4]])),
     "support surface 'top': outline_xy reaches outside the model"),
]


@pytest.mark.parametrize("text, detail", [b[1:] for b in BAD_SURFACES], ids=[b[0] for b in BAD_SURFACES])
def test_bad_support_surfaces_are_refused_with_the_reason(client, text, detail):
    r = upload(client, parallel_stl(), name="bad surfaces", support_surfaces=text)
    assert r.status_code == 422, r.text
    assert detail in r.json()["detail"], r.json()["detail"]


def test_only_fixtures_declare_support_surfaces(client):
    r = upload(client, parallel_stl(), kind="workpiece", name="bad workpiece", support_surfaces=json.dumps(TOP_25))
    assert r.status_code == 422
    assert r.json()["detail"] == ("support_surfaces: a workpiece carries no parts; only clamp and support models "
                                  "declare support surfaces")
    # a clamp may (a vise's seat)
    r = upload(client, parallel_stl(), kind="clamp", name="clamp with a seat", support_surfaces=json.dumps(TOP_25))
    assert r.status_code == 201, r.text


def test_revisions_change_the_surfaces(client):
    r = upload(client, parallel_stl(), name="Revised parallel", support_surfaces=json.dumps(TOP_25))
    mid, sha1 = r.json()["id"], r.json()["revision"]["glb_sha256"]
    half = [{"name": "left half", "z_mm": 25.0, "outline_xy": [[-75.0, -4.0], [0.0, -4.0], [0.0, 4.0], [-75.0, 4.0]]}]

    r2 = client.post(f"/api/v1/models/{mid}/revisions", data={"support_surfaces": json.dumps(half), "note": "half"})
    assert r2.status_code == 201, r2.text
    assert r2.json()["current_revision"] == 2 and r2.json()["revision"]["support_surfaces"] == half
    assert r2.json()["revision"]["glb_sha256"] == sha1, "surfaces changed, geometry did not"
    assert client.get(f"/api/v1/models/{mid}", params={"revision": 1}).json()["revision"]["support_surfaces"] == TOP_25

    # a datum change keeps the surfaces
    datum = np.eye(4)
    datum[2, 3] = 25.0
    r3 = client.post(f"/api/v1/models/{mid}/revisions", data={"T_obj_datum": json.dumps(datum.tolist())})
    assert r3.status_code == 201 and r3.json()["revision"]["support_surfaces"] == half, r3.text

    # [] : carries nothing; 'null' : derived from the mesh again
    r4 = client.post(f"/api/v1/models/{mid}/revisions", data={"support_surfaces": "[]"})
    assert r4.status_code == 201 and r4.json()["revision"]["support_surfaces"] == [], r4.text
    r5 = client.post(f"/api/v1/models/{mid}/revisions", data={"support_surfaces": "null"})
    assert r5.status_code == 201 and r5.json()["revision"]["support_surfaces"] is None, r5.text

    # a bad revision is refused with the reason and changes nothing
    bad = client.post(f"/api/v1/models/{mid}/revisions", data={"support_surfaces": json.dumps(_surface(z_mm="x"))})
    assert bad.status_code == 422 and "support_surfaces[0].z_mm" in bad.json()["detail"], bad.text
    assert client.get(f"/api/v1/models/{mid}").json()["current_revision"] == 5

    # new geometry must still carry the surfaces it keeps: a lower parallel does not reach z 25
    client.post(f"/api/v1/models/{mid}/revisions", data={"support_surfaces": json.dumps(TOP_25)})
    low = client.post(f"/api/v1/models/{mid}/revisions", files={"file": ("low.stl", parallel_stl(10.0))})
    assert low.status_code == 422, low.text
    assert "support surface 'top' at z 25 mm is outside the model" in low.json()["detail"]
    top10 = [{**TOP_25[0], "z_mm": 10.0}]
    ok = client.post(f"/api/v1/models/{mid}/revisions", files={"file": ("low.stl", parallel_stl(10.0))},
                     data={"support_surfaces": json.dumps(top10)})
    assert ok.status_code == 201 and ok.json()["revision"]["support_surfaces"] == top10, ok.text
    assert [x["revision"] for x in client.get(f"/api/v1/models/{mid}/revisions").json()] == [1, 2, 3, 4, 5, 6, 7]

    # a workpiece's revision may not declare any
    wp = upload(client, parallel_stl(), kind="workpiece", name="bar to revise").json()
    r = client.post(f"/api/v1/models/{wp['id']}/revisions", data={"support_surfaces": json.dumps(TOP_25)})
    assert r.status_code == 422 and "a workpiece carries no parts" in r.json()["detail"]


def test_a_setup_may_ask_for_supports_but_not_for_a_table(server, client):
    """Supports are located like clamps (the support chain); a table is refused with the reason. The
    picture here has no markers, so the job ends at the table with its reason."""
    machine = make_machine(client, None)
    sup = upload(client, parallel_stl(), name="setup parallel", support_surfaces=json.dumps(TOP_25)).json()
    img = cv2.imencode(".png", np.full((200, 320, 3), 128, np.uint8))[1].tobytes()
    table_id = machine["table_model_id"]
    r = client.post("/api/v1/setups", data={"machine_id": str(machine["id"]), "model_ids": str(table_id)},
                    files={"image": ("a.png", img, "image/png")})
    assert r.status_code == 422
    assert "is a table; only workpieces, clamps and supports are located on the table" in r.json()["detail"]
    r = client.post("/api/v1/setups", data={"machine_id": str(machine["id"]), "model_ids": f"{sup['id']},{sup['id']}"},
                    files={"image": ("a.png", img, "image/png")})
    assert r.status_code == 202, r.text
    for _ in range(300):
        s = client.get(r.json()["url"]).json()
        if s["status"] in ("located", "failed"):
            break
        time.sleep(0.1)
    assert s["status"] == "failed" and s["reason"].startswith("table markers not found"), s
    assert [m["model_id"] for m in s["models"]] == [sup["id"], sup["id"]]
