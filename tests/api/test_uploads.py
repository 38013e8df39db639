"""Every upload route refuses an oversize file (413) and a form field that is not JSON (422) with the
reason, before any work starts (app/api/uploads.py)."""

from __future__ import annotations

import pytest

BIG = b"\0" * 5_100_000        # the test server's limit is 5 MB


@pytest.mark.parametrize("path, data, files", [
    ("/api/v1/setups", {"machine_id": "1"}, {"image": ("big.jpg", BIG, "image/jpeg")}),
    ("/api/v1/rotary/runs", {"camera_id": "1", "angles_deg": "0"}, [("images", ("big.jpg", BIG, "image/jpeg"))]),
    ("/api/v1/cameras/1/calibrations", {"board": '{"kind": "chessboard", "cols": 9, "rows": 6, "square_mm": 25}'},
     [("images", ("big.jpg", BIG, "image/jpeg"))]),
])
def test_oversize_uploads_are_refused_with_the_limit(server, path, data, files):
    with server.client("admin") as c:
        r = c.post(path, data=data, files=files)
    assert r.status_code == 413, r.text
    assert "is over 5 MB" in r.json()["detail"]


@pytest.mark.parametrize("path, data, name", [
    ("/api/v1/rotary/runs", {"camera_id": "1", "angles_deg": "0", "target": "{groups: 1"}, "target"),
    ("/api/v1/cameras/1/calibrations", {"board": "chessboard 9x6"}, "board"),
])
def test_form_fields_that_are_not_json_are_refused_with_the_field(server, path, data, name):
    with server.client("admin") as c:
        r = c.post(path, data=data, files=[("images", ("a.jpg", b"\xff\xd8\xff", "image/jpeg"))])
    assert r.status_code == 422, r.text
    assert r.json()["detail"].startswith(f"{name}: not valid JSON")
