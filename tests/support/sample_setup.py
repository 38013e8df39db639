"""The README's sample (samples/bracket_on_table.jpg on the example T-slot table) as setups to queue:
a real localisation of about 20 s on two cores, long enough to kill a worker in the middle of it."""

from __future__ import annotations

import json
import time
from pathlib import Path

import httpx

SAMPLES = Path(__file__).resolve().parents[2] / "samples"


def sample_machine(client: httpx.Client) -> tuple[int, int]:
    """(machine id, bracket model id): the sample camera and a machine on the example table (as admin)."""
    cam = client.post("/api/v1/cameras", json={"name": "sample cam", "intrinsics": json.loads(
        (SAMPLES / "camera-intrinsics.json").read_text())})
    assert cam.status_code == 201, cam.text
    models = client.get("/api/v1/models", params={"limit": 200}).json()["data"]
    table = next(m["id"] for m in models if m["key"] == "tslot_table_800x400")
    bracket = next(m["id"] for m in models if m["key"] == "bracket_140")
    r = client.post("/api/v1/machines", json={
        "name": "sample mill", "table_model_id": table, "camera_ids": [cam.json()["id"]],
        "T_machine_table": [[1, 0, 0, -450], [0, 1, 0, -250], [0, 0, 1, -320], [0, 0, 0, 1]],
        "travel_mm": {"x": [-600, 600], "y": [-400, 400], "z": [-500, 0]}})
    assert r.status_code == 201, r.text
    return r.json()["id"], bracket


def start_setup(client: httpx.Client, machine_id: int, model_id: int) -> dict:
    """POST the sample photo; the 202 answer (setup id, job id and URLs)."""
    r = client.post("/api/v1/setups", data={"machine_id": str(machine_id), "model_ids": str(model_id)},
                    files={"image": ("bracket_on_table.jpg", (SAMPLES / "bracket_on_table.jpg").read_bytes(),
                                     "image/jpeg")})
    assert r.status_code == 202, r.text
    return r.json()


def wait_for(client: httpx.Client, url: str, done, timeout_s: float = 180.0, what: str = "") -> dict:
    """GET ``url`` until ``done(body)``; the body then (fails after ``timeout_s`` with the last body)."""
    deadline = time.monotonic() + timeout_s
    while True:
        body = client.get(url).json()
        if done(body):
            return body
        assert time.monotonic() < deadline, f"{what or url} not reached in {timeout_s} s: {body}"
        time.sleep(0.1)
