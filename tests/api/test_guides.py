"""A fixture's guide (a vise's moving jaw on its body) over real HTTP (SQLite and PostgreSQL): create,
read back, revise, remove with 'null', every rejection with its reason."""

from __future__ import annotations

import json

import pytest
import trimesh

T70 = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 70.0], [0.0, 0.0, 0.0, 1.0]]
GUIDE = {"carrier": "Test vise body", "T_carrier_obj": T70, "axis": [1.0, 0.0, 0.0], "travel_mm": [-95.0, 100.0]}


def jaw_stl() -> bytes:
    """A moving jaw 55 x 120 x 43: clamping face at x 0, z up."""
    return trimesh.creation.box(bounds=[[-55, -60, -8], [0, 60, 35]]).export(file_type="stl")


def upload(client, kind="clamp", name="Test moving jaw", **form):
    return client.post("/api/v1/models", files={"file": ("jaw.stl", jaw_stl())},
                       data={"kind": kind, "name": name, "units": "mm", **form})


def test_a_guided_jaw_round_trip(client):
    r = upload(client, guide=json.dumps({**GUIDE, "axis": [2, 0, 0], "travel_mm": [-95, 100]}))
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["revision"]["guide"] == GUIDE          # axis made unit, numbers as floats
    mid = body["id"]
    assert client.get(f"/api/v1/models/{mid}").json()["revision"]["guide"] == GUIDE
    assert client.get(f"/api/v1/models/{mid}/revisions").json()[0]["guide"] == GUIDE
    # left out: it stands free
    r = upload(client, name="Free jaw")
    assert r.status_code == 201 and r.json()["revision"]["guide"] is None, r.text


def test_revisions_change_and_remove_the_guide(client):
    mid = upload(client, name="Revised jaw", guide=json.dumps(GUIDE)).json()["id"]
    shorter = {**GUIDE, "travel_mm": [0.0, 50.0]}
    r2 = client.post(f"/api/v1/models/{mid}/revisions", data={"guide": json.dumps(shorter), "note": "shorter"})
    assert r2.status_code == 201 and r2.json()["revision"]["guide"] == shorter, r2.text
    assert client.get(f"/api/v1/models/{mid}", params={"revision": 1}).json()["revision"]["guide"] == GUIDE
    # a datum change keeps the guide
    r3 = client.post(f"/api/v1/models/{mid}/revisions", data={"T_obj_datum": json.dumps(T70)})
    assert r3.status_code == 201 and r3.json()["revision"]["guide"] == shorter, r3.text
    # 'null' removes it: the jaw stands free again
    r4 = client.post(f"/api/v1/models/{mid}/revisions", data={"guide": "null"})
    assert r4.status_code == 201 and r4.json()["revision"]["guide"] is None, r4.text
    # a bad revision is refused with the reason and changes nothing
    bad = client.post(f"/api/v1/models/{mid}/revisions", data={"guide": json.dumps({**GUIDE, "axis": [0, 0, 0]})})
    assert bad.status_code == 422 and "guide.axis: axis is zero" in bad.json()["detail"], bad.text
    assert client.get(f"/api/v1/models/{mid}").json()["current_revision"] == 4


BAD = [
    ("not json", "{carrier:", "guide: not valid JSON"),
    ("a list", "[1, 2]", "guide: expected an object"),
    ("no axis", json.dumps({k: v for k, v in GUIDE.items() if k != "axis"}), "guide.axis: Field required"),
    ("bad pose shape", json.dumps({**GUIDE, "T_carrier_obj": [[1, 0, 0, 0]]}), "expected shape (4, 4)"),
    ("not rigid", json.dumps({**GUIDE, "T_carrier_obj": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}),
     "rotation not orthonormal"),
    ("zero axis", json.dumps({**GUIDE, "axis": [0, 0, 0]}), "guide.axis: axis is zero"),
    ("lo >= hi", json.dumps({**GUIDE, "travel_mm": [100, 100]}), "guide.travel_mm: [100, 100]: lo must be less than hi"),
    ("itself", json.dumps({**GUIDE, "carrier": "Jaw on itself"}), "guide.carrier 'Jaw on itself' names the model itself"),
]


@pytest.mark.parametrize("text, detail", [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_a_bad_guide_is_refused_with_the_reason(client, text, detail):
    r = upload(client, name="Jaw on itself", guide=text)
    assert r.status_code == 422, r.text
    assert detail in r.json()["detail"], r.json()["detail"]


def test_only_fixtures_are_guided(client):
    r = upload(client, kind="workpiece", name="guided workpiece", guide=json.dumps(GUIDE))
    assert r.status_code == 422
    assert r.json()["detail"] == "guide: a workpiece is not guided; only clamp and support models ride on a carrier"
    wp = upload(client, kind="workpiece", name="workpiece to revise").json()
    r = client.post(f"/api/v1/models/{wp['id']}/revisions", data={"guide": json.dumps(GUIDE)})
    assert r.status_code == 422 and "a workpiece is not guided" in r.json()["detail"]
