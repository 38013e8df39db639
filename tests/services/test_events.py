"""MES events: signed webhooks with retries against a real HTTP server, MQTT through the local Mosquitto."""

from __future__ import annotations

import http.server
import json
import queue
import socket
import threading
import time
import uuid

import pytest

from app.services.events import EventBus, sign

pytestmark = pytest.mark.integration


@pytest.fixture()
def hook_server():
    """Answers 500 to the first delivery, 200 afterwards; records (headers, body)."""
    got: queue.Queue = queue.Queue()
    calls = {"n": 0}

    class H(http.server.BaseHTTPRequestHandler):
        def do_POST(self):  # noqa: N802
            body = self.rfile.read(int(self.headers["Content-Length"]))
            calls["n"] += 1
            if calls["n"] == 1:
                self.send_response(500)
                self.end_headers()
                return
            got.put((dict(self.headers), body))
            self.send_response(204)
            self.end_headers()

        def log_message(self, *a):
            pass

    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), H)
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{srv.server_address[1]}/hook", got, calls
    srv.shutdown()


def test_webhook_is_signed_and_retried(hook_server):
    url, got, calls = hook_server
    bus = EventBus(webhooks=[{"url": url, "secret": "s3cret"}], retry_delays_s=(0.2, 0.4))
    try:
        t0 = time.monotonic()
        event = bus.publish("offset.exported", {"setup_id": 7})
        assert time.monotonic() - t0 < 0.1, "publishing never blocks the operator"
        headers, body = got.get(timeout=10)
    finally:
        bus.close()
    assert calls["n"] == 2, "the first (failed) delivery was retried"
    assert headers["X-Setupcam-Event"] == "offset.exported"
    assert headers["X-Setupcam-Signature"] == sign(body, "s3cret")
    assert json.loads(body)["id"] == event["id"] and json.loads(body)["data"] == {"setup_id": 7}


def _mosquitto_up() -> bool:
    try:
        with socket.create_connection(("127.0.0.1", 1883), timeout=2):
            return True
    except OSError:
        return False


def test_mqtt_event_reaches_a_subscriber():
    if not _mosquitto_up():
        pytest.skip("no MQTT broker on 127.0.0.1:1883; MQTT event test skipped")
    import paho.mqtt.client as mqtt

    prefix = f"setupcam-test-{uuid.uuid4().hex[:6]}"
    got: queue.Queue = queue.Queue()
    sub = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    sub.on_message = lambda c, u, msg: got.put((msg.topic, msg.payload))
    subscribed = threading.Event()
    sub.on_subscribe = lambda *a: subscribed.set()
    sub.connect("127.0.0.1", 1883)
    sub.subscribe(f"{prefix}/#", qos=1)
    sub.loop_start()
    assert subscribed.wait(5)
    bus = EventBus(mqtt_url="mqtt://127.0.0.1:1883", topic_prefix=prefix)
    try:
        bus.publish("setup.confirmed", {"setup_id": 3})
        topic, payload = got.get(timeout=10)
    finally:
        bus.close()
        sub.loop_stop()
        sub.disconnect()
    assert topic == f"{prefix}/setup.confirmed" and json.loads(payload)["data"] == {"setup_id": 3}
