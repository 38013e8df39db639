"""Events for the MES: signed webhooks (retried with backoff) and MQTT messages. Never blocking.

Event types: ``setup.located``, ``setup.failed``, ``setup.confirmed``, ``offset.exported``,
``offset.export_failed`` (and the monitoring events of the sheet module). Body::

    {"id": "<uuid>", "type": "offset.exported", "at": "2026-...Z", "data": {...}}

Webhook requests carry ``X-Setupcam-Event`` and ``X-Setupcam-Signature: sha256=<hex>``, the
HMAC-SHA256 of the raw body with the hook's secret. Delivery runs on a background thread with
retries (1, 2, 4, 8, 16 s); a failed delivery is logged, never raised to the operator.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import logging
import queue
import threading
import time
import uuid
from datetime import datetime, timezone
from urllib.parse import urlparse

import httpx
import paho.mqtt.client as mqtt

log = logging.getLogger(__name__)

RETRY_DELAYS_S = (1, 2, 4, 8, 16)


def sign(body: bytes, secret: str) -> str:
    return "sha256=" + hmac.new(secret.encode(), body, hashlib.sha256).hexdigest()


class EventBus:
    def __init__(self, webhooks: list[dict] | None = None, mqtt_url: str = "", topic_prefix: str = "setupcam",
                 retry_delays_s: tuple[float, ...] = RETRY_DELAYS_S):
        self.webhooks = [h for h in (webhooks or []) if h.get("url")]
        self.mqtt_url = mqtt_url
        self.topic_prefix = topic_prefix.rstrip("/")
        self.retry_delays_s = retry_delays_s
        self._queue: queue.Queue = queue.Queue()
        self._mqtt = None
        self._thread = threading.Thread(target=self._run, name="setupcam-events", daemon=True)
        self._stop = threading.Event()
        if self.webhooks or self.mqtt_url:
            self._thread.start()

    # ---------------------------------------------------------------- public
    def publish(self, event_type: str, data: dict) -> dict:
        """Queue an event for delivery and return it (immediately)."""
        event = {"id": str(uuid.uuid4()), "type": event_type,
                 "at": datetime.now(timezone.utc).isoformat(timespec="milliseconds"), "data": data}
        log.info("event", extra={"event": event_type, "event_id": event["id"]})
        if self._thread.is_alive():
            self._queue.put(event)
        return event

    def close(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        self._queue.put(None)
        if self._thread.is_alive():
            self._thread.join(timeout=timeout_s)
        if self._mqtt is not None:
            self._mqtt.loop_stop()
            self._mqtt.disconnect()

    # ---------------------------------------------------------------- delivery
    def _run(self) -> None:
        while not self._stop.is_set():
            event = self._queue.get()
            if event is None:
                return
            body = json.dumps(event, separators=(",", ":")).encode()
            if self.mqtt_url:
                self._send_mqtt(event["type"], body)
            for hook in self.webhooks:
                threading.Thread(target=self._send_webhook, args=(hook, event["type"], body), daemon=True).start()

    def _send_webhook(self, hook: dict, event_type: str, body: bytes) -> None:
        headers = {"Content-Type": "application/json", "X-Setupcam-Event": event_type,
                   "X-Setupcam-Signature": sign(body, hook.get("secret", ""))}
        for attempt, delay in enumerate((0, *self.retry_delays_s)):
            if delay:
                if self._stop.wait(delay):
                    return
            try:
                r = httpx.post(hook["url"], content=body, headers=headers, timeout=5)
                if r.status_code < 300:
                    return
                why = f"answered {r.status_code}"
            except httpx.HTTPError as exc:
                why = f"{exc.__class__.__name__}: {exc}"
            log.warning("webhook delivery failed", extra={"url": hook["url"], "attempt": attempt + 1, "why": why})
        log.error("webhook given up", extra={"url": hook["url"], "event": event_type})

    def _send_mqtt(self, event_type: str, body: bytes) -> None:
        try:
            if self._mqtt is None:
                u = urlparse(self.mqtt_url)
                client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"setupcam-{uuid.uuid4().hex[:8]}")
                if u.username:
                    client.username_pw_set(u.username, u.password)
                client.connect(u.hostname or "127.0.0.1", u.port or 1883, keepalive=30)
                client.loop_start()
                self._mqtt = client
            info = self._mqtt.publish(f"{self.topic_prefix}/{event_type}", body, qos=1)
            info.wait_for_publish(timeout=5)
        except Exception as exc:  # noqa: BLE001 - delivery problems are logged, never raised
            log.error("MQTT publish failed", extra={"url": self.mqtt_url, "why": str(exc)})
            self._mqtt = None
            time.sleep(0.5)
