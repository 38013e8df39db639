"""HTTP snapshot source against a real http.server on 127.0.0.1 (random port, background thread)."""

from __future__ import annotations

import base64
import socket
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

import cv2
import numpy as np
import pytest

from app.sources import SourceError, make_source

pytestmark = pytest.mark.integration

RNG = np.random.default_rng(0)
IMAGE = RNG.integers(0, 256, size=(48, 64, 3), dtype=np.uint8)
PNG = cv2.imencode(".png", IMAGE)[1].tobytes()
GRAY_JPEG = cv2.imencode(".jpg", np.full((30, 40), 128, np.uint8))[1].tobytes()
TOKEN = "Basic " + base64.b64encode(b"op:pw").decode()


class _Handler(BaseHTTPRequestHandler):
    def log_message(self, *args):  # keep the test output quiet
        pass

    def _send(self, code: int, body: bytes, ctype: str) -> None:
        self.send_response(code)
        self.send_header("Content-Type", ctype)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def do_GET(self):  # noqa: N802 (http.server API)
        if self.path == "/snap.png":
            self._send(200, PNG, "image/png")
        elif self.path == "/gray.jpg":
            self._send(200, GRAY_JPEG, "image/jpeg")
        elif self.path == "/moved":
            self.send_response(302)
            self.send_header("Location", "/snap.png")
            self.send_header("Content-Length", "0")
            self.end_headers()
        elif self.path == "/login.html":
            self._send(200, b"<html>please log in</html>", "text/html")
        elif self.path == "/auth.png":
            if self.headers.get("Authorization") == TOKEN:
                self._send(200, PNG, "image/png")
            else:
                self.send_response(401)
                self.send_header("WWW-Authenticate", 'Basic realm="cam"')
                self.send_header("Content-Length", "0")
                self.end_headers()
        elif self.path == "/slow.png":
            time.sleep(1.5)
            self._send(200, PNG, "image/png")
        elif self.path == "/big":
            self._send(200, b"\0" * 300_000, "multipart/x-mixed-replace")
        else:
            self._send(404, b"not here", "text/plain")


@pytest.fixture(scope="module")
def server_url():
    server = ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    server.daemon_threads = True
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_grabs_png_exactly(server_url):
    image = make_source({"kind": "http", "url": f"{server_url}/snap.png"}).grab()
    assert image.dtype == np.uint8 and image.shape == (48, 64, 3)
    assert np.array_equal(image, IMAGE)


def test_gray_jpeg_comes_back_bgr_and_redirects_are_followed(server_url):
    gray = make_source({"kind": "http", "url": f"{server_url}/gray.jpg"}).grab()
    assert gray.shape == (30, 40, 3) and abs(float(gray.mean()) - 128) < 2
    assert np.array_equal(make_source({"kind": "http", "url": f"{server_url}/moved"}).grab(), IMAGE)


def test_basic_auth(server_url):
    url = f"{server_url}/auth.png"
    with pytest.raises(SourceError) as info:
        make_source({"kind": "http", "url": url}).grab()
    assert str(info.value) == f"HTTP snapshot {url}: server answered 401 Unauthorized; check username and password"
    image = make_source({"kind": "http", "url": url, "username": "op", "password": "pw"}).grab()
    assert np.array_equal(image, IMAGE)


def test_404_is_named(server_url):
    url = f"{server_url}/nothing.jpg"
    with pytest.raises(SourceError) as info:
        make_source({"kind": "http", "url": url}).grab()
    assert str(info.value) == f"HTTP snapshot {url}: server answered 404 Not Found"


def test_html_answer_is_not_an_image(server_url):
    url = f"{server_url}/login.html"
    with pytest.raises(SourceError) as info:
        make_source({"kind": "http", "url": url}).grab()
    assert str(info.value) == f"HTTP snapshot {url}: answer is not an image (content-type text/html, 26 bytes)"


def test_timeout(server_url):
    url = f"{server_url}/slow.png"
    t0 = time.monotonic()
    with pytest.raises(SourceError) as info:
        make_source({"kind": "http", "url": url, "timeout_s": 0.3}).grab()
    assert str(info.value) == f"HTTP snapshot {url}: no answer within 0.3 s"
    assert time.monotonic() - t0 < 1.4


def test_stream_is_refused_by_size(server_url):
    url = f"{server_url}/big"
    with pytest.raises(SourceError, match=r"answer exceeds 0\.1 MB \(content-type multipart/x-mixed-replace\); "
                                          r"this looks like a video stream: use an opencv source"):
        make_source({"kind": "http", "url": url, "max_mb": 0.1}).grab()


def test_connection_refused():
    with socket.socket() as s:  # a port that was free a moment ago and has no listener now
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"http://127.0.0.1:{port}/snapshot.jpg"
    with pytest.raises(SourceError) as info:
        make_source({"kind": "http", "url": url, "username": "op", "password": "secret"}).grab()
    assert str(info.value) == (
        f"HTTP snapshot {url}: connection refused; check that the camera is on and the host and port are right"
    )
