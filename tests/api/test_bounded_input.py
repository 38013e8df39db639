"""Bounded input before work (issue 17, item 2): image headers are read before anything decodes them,
the caller is checked and the body bounded before it is read, JSON depth is bounded; a 109 KB PNG of
30000 x 30000 px costs a running service less than 100 MB."""

from __future__ import annotations

import http.client
import json
import os
import re
import struct
import subprocess
import sys
import time
import zlib

import cv2
import httpx
import numpy as np
import pytest

from tests.support.factories import make_machine
from tests.support.live_server import free_ports


def png_bomb(width: int = 30000, height: int = 30000) -> bytes:
    """A valid 1-bit PNG of width x height px, all black: about 109 KB for 30000 x 30000 (it decodes to
    2.7 GB as BGR). Compressed row by row, so making it costs no memory either."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    z = zlib.compressobj(9)
    row = b"\0" * (1 + (width + 7) // 8)  # filter byte + packed bits
    idat = b"".join(z.compress(row) for _ in range(height)) + z.flush()
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0))
            + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


BOMB = png_bomb()
SMALL_PNG = cv2.imencode(".png", np.zeros((20, 30, 3), np.uint8))[1].tobytes()

# (who, path, form fields, file field): every route that takes an image
UPLOAD_ROUTES = [
    ("mes", "/api/v1/setups", {"machine_id": "1"}, "image"),
    ("admin", "/api/v1/cameras/1/calibrations", {"board": '{"kind": "chessboard", "inner_corners": [9, 6], '
                                                          '"square_mm": 25}'}, "images"),
    ("mes", "/api/v1/rotary/runs", {"camera_id": "1", "angles_deg": "0,10"}, "images"),
    ("mes", "/api/v1/sheet/alignments", {"machine_id": "1", "camera_id": "1", "thickness_mm": "2"}, "image"),
    ("operator", "/api/v1/sheet/monitors/1/frames", {}, "frame"),
]


def test_the_bomb_is_109_kb_and_says_30000_px():
    assert 100_000 < len(BOMB) < 120_000
    assert struct.unpack(">II", BOMB[16:24]) == (30000, 30000)


@pytest.mark.parametrize("who, path, data, field", UPLOAD_ROUTES, ids=[r[1] for r in UPLOAD_ROUTES])
def test_image_over_the_pixel_limit_is_refused_unread(server, who, path, data, field):
    with server.client(who) as c:
        r = c.post(path, data=data, files=[(field, ("bomb.png", BOMB, "image/png"))])
    assert r.status_code == 413, r.text
    assert "30000 x 30000" in r.json()["detail"] or "900 MP" in r.json()["detail"]
    assert "the limit is 50 MP" in r.json()["detail"]


@pytest.mark.parametrize("who, path, data, field", UPLOAD_ROUTES[:4], ids=[r[1] for r in UPLOAD_ROUTES[:4]])
def test_bytes_without_an_image_header_are_refused(server, who, path, data, field):
    with server.client(who) as c:
        r = c.post(path, data=data, files=[(field, ("x.png", b"GIF89a" + b"\0" * 100, "image/png"))])
    assert r.status_code == 422, r.text
    assert "not a readable image" in r.json()["detail"]


def test_pixel_limit_is_a_setting(tmp_path):
    from tests.support.live_server import live_server

    with live_server(tmp_path, max_image_pixels=500) as srv, srv.client("mes") as c:
        r = c.post("/api/v1/setups", data={"machine_id": "1"}, files={"image": ("a.png", SMALL_PNG, "image/png")})
        assert r.status_code == 413 and "20 x 30 px" not in r.text and "30 x 20 px" in r.json()["detail"], r.text
        r = c.post("/api/v1/setups", data={"machine_id": "999"},
                   files={"image": ("a.png", cv2.imencode(".png", np.zeros((10, 10, 3), np.uint8))[1].tobytes())})
        assert r.status_code == 404, r.text  # within the limit: on to the next check


def test_images_of_one_request_are_bounded_together(tmp_path):
    from tests.support.live_server import live_server

    with live_server(tmp_path, max_request_pixels=1000, load_example_library=False) as srv, srv.client("mes") as c:
        r = c.post("/api/v1/rotary/runs", data={"camera_id": "1", "angles_deg": "0,10"},
                   files=[("images", ("a.png", SMALL_PNG, "image/png")), ("images", ("b.png", SMALL_PNG, "image/png"))])
    assert r.status_code == 413 and "the 2 images up to image 'b.png' have 1,200 px together; one request takes at most 1,000 px" in r.json()["detail"], r.text


def _raw(server, method: str, path: str, headers: dict, body: bytes | None = None) -> tuple[int, dict]:
    """Send the headers (and ``body`` if given) and read the answer: a declared body need not follow."""
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=10)
    try:
        conn.putrequest(method, path)
        for k, v in headers.items():
            conn.putheader(k, v)
        conn.endheaders(body)
        r = conn.getresponse()
        return r.status, json.loads(r.read() or b"{}")
    finally:
        conn.close()


def test_anonymous_upload_is_refused_before_its_body(server):
    """A caller without a key hears 401 although it declared 10 GB and sent none of it."""
    t0 = time.monotonic()
    status, body = _raw(server, "POST", "/api/v1/setups",
                        {"Content-Type": "multipart/form-data; boundary=x", "Content-Length": "10000000000"})
    assert status == 401 and "sign in" in body["detail"]
    assert time.monotonic() - t0 < 5


def test_wrong_role_is_refused_before_the_body(server):
    status, body = _raw(server, "POST", "/api/v1/models",
                        {"Authorization": f"Bearer {server.tokens['mes']}", "Content-Length": "10000000000",
                         "Content-Type": "multipart/form-data; boundary=x"})
    assert status == 403 and "an admin must do this" in body["detail"]


def test_declared_oversize_body_is_413_before_reading(server):
    status, body = _raw(server, "POST", "/api/v1/setups",
                        {"Authorization": f"Bearer {server.tokens['mes']}", "Content-Length": "10000000000",
                         "Content-Type": "multipart/form-data; boundary=x"})
    assert status == 413 and "at most 256 MB" in body["detail"]
    status, body = _raw(server, "POST", "/api/v1/planning/paths",
                        {"Authorization": f"Bearer {server.tokens['mes']}", "Content-Length": "2000000",
                         "Content-Type": "application/json"})
    assert status == 413 and "at most 1024 KB" in body["detail"]


def test_chunked_body_is_cut_off_at_the_limit(server):
    """Without Content-Length the body is counted as it streams; past the limit: 413."""
    def chunks():
        for _ in range(40):
            yield b"[" + b"0," * 50_000 + b"0]"

    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
    try:
        conn.request("POST", "/api/v1/planning/paths", body=chunks(), encode_chunked=True,
                     headers={"Authorization": f"Bearer {server.tokens['mes']}", "Content-Type": "text/plain"})
        r = conn.getresponse()
        assert r.status == 413, r.read()
        assert "over 1024 KB" in json.loads(r.read())["detail"]
    finally:
        conn.close()


def test_json_body_over_the_limit_and_too_deep(server):
    with server.client("admin") as c:
        r = c.post("/api/v1/planning/paths", content=b'{"points": [' + b"[1, 2, 3]," * 200_000 + b"[0, 0, 0]]}",
                   headers={"Content-Type": "application/json"})
        assert r.status_code == 413, r.text
        deep = "[" * 100_000 + "]" * 100_000
        r = c.post("/api/v1/planning/paths", content=deep, headers={"Content-Type": "application/json"})
        assert r.status_code == 422 and "nested 100000 deep" in r.json()["detail"]
        nested: object = 1
        for _ in range(40):
            nested = {"a": [nested]}
        r = c.patch("/api/v1/cameras/1", json={"source": nested})
        assert r.status_code == 422 and "at most 32 levels" in r.json()["detail"]


# ----------------------------------------------------------------------------- memory of a running service
def _peak_rss_mb(pid: int) -> float:
    text = open(f"/proc/{pid}/status").read()
    return int(re.search(r"VmHWM:\s+(\d+) kB", text).group(1)) / 1024


@pytest.mark.slow
@pytest.mark.integration
def test_bomb_costs_a_running_service_under_100_mb(tmp_path):
    """``setupcam serve`` in its own process; its peak RSS (VmHWM) before and after the bomb is posted to
    every upload route, with an MES key (calibration with an admin key)."""
    port, viser_port = free_ports(2)
    env = {**os.environ, "SETUPCAM_DATA_DIR": str(tmp_path), "SETUPCAM_LOAD_EXAMPLES": "false",
           "SETUPCAM_VISER_PORT": str(viser_port)}
    env.pop("DATABASE_URL", None)
    keys = {}
    for scope in ("mes", "admin"):
        out = subprocess.run([sys.executable, "-m", "app.cli", "apikey", "create", "--scope", scope], env=env,
                             capture_output=True, text=True, check=True).stdout
        keys[scope] = out.rsplit("key (shown once): ", 1)[1].strip()
    proc = subprocess.Popen([sys.executable, "-m", "app.cli", "serve", "--port", str(port)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(600):
            try:
                if httpx.get(f"{base}/api/v1/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.1)
        else:
            raise AssertionError("serve did not come up")
        headers = {s: {"Authorization": f"Bearer {k}"} for s, k in keys.items()}
        # a machine and a camera with intrinsics: without the header check every route would decode the bomb
        with httpx.Client(base_url=base, headers=headers["admin"], timeout=60) as admin:
            machine = make_machine(admin, None)
        assert machine["id"] == 1 and machine["camera_ids"] == [1]
        # warm up: the same routes with a small image (imports, first allocations)
        for who, path, data, field in UPLOAD_ROUTES[:4]:
            httpx.post(base + path, data=data, files=[(field, ("a.png", SMALL_PNG, "image/png"))],
                       headers=headers["admin" if who == "admin" else "mes"], timeout=60)
        before = _peak_rss_mb(proc.pid)
        answers = []
        for who, path, data, field in UPLOAD_ROUTES[:4]:
            r = httpx.post(base + path, data=data, files=[(field, ("bomb.png", BOMB, "image/png"))],
                           headers=headers["admin" if who == "admin" else "mes"], timeout=60)
            answers.append(r.status_code)
        after = _peak_rss_mb(proc.pid)
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    print(f"peak RSS before {before:.0f} MB, after the bomb on {len(answers)} routes {after:.0f} MB")
    assert all(s in (413, 422) for s in answers), answers
    assert after - before < 100, f"peak RSS grew by {after - before:.0f} MB"
