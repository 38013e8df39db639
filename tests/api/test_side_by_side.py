"""Two services with different settings on one machine do not see each other's data."""

from __future__ import annotations

import trimesh

from tests.support.live_server import live_server


def test_two_services_side_by_side(tmp_path):
    stl = trimesh.creation.box().export(file_type="stl")
    with live_server(tmp_path / "a", load_example_library=False, viser_port=18081) as a, \
            live_server(tmp_path / "b", load_example_library=False, viser_port=18082) as b:
        assert a.port != b.port
        with a.client() as ca, b.client() as cb:
            r = ca.post("/api/v1/models", files={"file": ("only-in-a.stl", stl)}, data={"kind": "workpiece", "name": "only in a"})
            assert r.status_code == 201
            assert ca.get("/api/v1/models", params={"name": "only in a"}).json()["count"] == 1
            assert cb.get("/api/v1/models", params={"name": "only in a"}).json()["count"] == 0
        assert (tmp_path / "a" / "setupcam.db").exists() and (tmp_path / "b" / "setupcam.db").exists()
