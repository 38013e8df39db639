"""One door to the 3D view (issue 17, item 1), against a running service: the relay refuses a socket
without a session or from another site's page; viser's inner port, reached directly, shows nothing
and lets nothing move, whatever the query claims (``?who=...&person=1``)."""

from __future__ import annotations

import time

import msgspec
import pytest
import viser
from websockets.exceptions import ConnectionClosed, InvalidStatus
from websockets.sync.client import connect

from app.geometry.transforms import pose_from_xyz_euler
from tests.support.factories import located_setup, make_machine

PROTO = [f"viser-v{viser.__version__}"]


def hello(ws) -> None:
    """What viser's browser client sends first (its camera); viser counts a client as connected from it."""
    from viser._messages import ViewerCameraMessage

    msg = ViewerCameraMessage(wxyz=(1, 0, 0, 0), position=(0, 0, 1), fov=1.0, near=0.01, far=100.0,
                              image_height=480, image_width=640, look_at=(0, 0, 0), up_direction=(0, 0, 1))
    ws.send(msgspec.msgpack.encode(msg.as_serializable_dict()))


@pytest.fixture(scope="module")
def setup_id(server):
    with server.client("admin") as c:
        m = make_machine(c, None)
    return located_setup(server, m["id"], pose_from_xyz_euler(100, 50, 0))


def _relay(server, setup_id: int, headers: dict, while_open=lambda: None) -> str:
    url = server.url.replace("http://", "ws://") + f"/viewer/setup/{setup_id}"
    try:
        with connect(url, additional_headers=headers, subprotocols=PROTO, open_timeout=10) as ws:
            ws.recv(timeout=10)
            hello(ws)
            while_open()
            return "open"
    except InvalidStatus as exc:
        return f"refused {exc.response.status_code}"
    except ConnectionClosed as exc:
        return f"closed {exc.rcvd.code if exc.rcvd else '?'}"


def _views_of(server, setup_id: int) -> int:
    return sum(1 for v in server.app.state.viewer.client_views().values() if v[:2] == ("setup", setup_id))


def test_relay_refuses_without_a_session_or_from_another_origin(server, setup_id):
    own = {"Origin": server.url}
    assert _relay(server, setup_id, own).startswith("refused 403")
    cookie = {"Cookie": f"setupcam_session={server.tokens['operator']}"}
    assert _relay(server, setup_id, {**cookie, "Origin": "http://evil.example"}).startswith("refused 403")
    before = _views_of(server, setup_id)
    seen = []

    def count() -> None:
        time.sleep(0.5)
        seen.append(_views_of(server, setup_id))

    assert _relay(server, setup_id, {**cookie, **own}, count) == "open", "the service's own page gets in"
    assert seen == [before + 1], "through the relay the viewer builds this setup's scene"


def test_inner_port_shows_and_moves_nothing_without_the_relay(server, setup_id):
    port = server.app.state.viewer.port
    for _ in range(100):  # until the relay test's browser has left
        if _views_of(server, setup_id) == 0:
            break
        time.sleep(0.05)
    before = _views_of(server, setup_id)
    assert before == 0
    for path in (f"/setup/{setup_id}", f"/setup/{setup_id}?who=anna%20(operator)&person=1", f"/setup/{setup_id}?t=forged"):
        with connect(f"ws://127.0.0.1:{port}{path}", subprotocols=PROTO, open_timeout=10) as ws:
            ws.recv(timeout=10)
            hello(ws)
            time.sleep(0.5)
            assert _views_of(server, setup_id) == before, f"{path}: no scene was built for it"
