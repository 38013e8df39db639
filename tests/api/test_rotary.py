"""/api/v1/rotary over real HTTP: a generated run with an injected error curve is recovered."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.synth.rotary_images import ErrorCurve, RotaryScene, generate_run, true_errors_arcsec
from app.vision.rotary_target import default_target
from tests.support.jobs import settled

ANGLES = [0, 30, 60, 90, 120, 90, 60, 30, 0]


@pytest.fixture(scope="module")
def run_images():
    scene = RotaryScene(camera_tilt_deg=15.0, noise_sigma=0.005)
    shots = generate_run(default_target(), ANGLES, scene=scene, curve=ErrorCurve(), seed=1)
    return scene, shots


@pytest.mark.slow
def test_rotary_run_recovers_the_injected_error(client, run_images):
    scene, shots = run_images
    cam = client.post("/api/v1/cameras", json={"name": "rotary cam", "intrinsics": scene.intrinsics_dict()}).json()
    files = [("images", (f"a{i}.png", cv2.imencode(".png", s.image)[1].tobytes(), "image/png")) for i, s in enumerate(shots)]
    r = client.post("/api/v1/rotary/runs", files=files,
                    data={"camera_id": str(cam["id"]), "angles_deg": ",".join(map(str, ANGLES))})
    assert r.status_code == 202, r.text  # a job; its result is the run
    r = settled(client, r)
    assert r.status_code == 200, r.text
    run = r.json()
    assert run["ok"], run["reason"]
    err = np.array(run["result"]["error_arcsec"]) - true_errors_arcsec(shots)
    assert np.sqrt(np.mean(err ** 2)) < 3.0, err  # 1280 x 960 test images; BENCHMARKS.md has the figures
    assert run["report"] and "reversal" in str(run["report"]).lower()
    for name, url in run["files"].items():
        got = client.get(url)
        assert got.status_code == 200 and got.content, name
    assert any(n.endswith(".COM") for n in run["files"]) and "PROPOSAL" in client.get(
        next(u for n, u in run["files"].items() if n.endswith(".COM"))).text.upper()
    assert client.get(f"/api/v1/rotary/runs/{run['id']}").json()["id"] == run["id"]


def test_rotary_refusals(client, run_images):
    scene, shots = run_images
    cam = client.post("/api/v1/cameras", json={"name": "rc", "intrinsics": scene.intrinsics_dict()}).json()
    img = cv2.imencode(".png", shots[0].image)[1].tobytes()
    two = [("images", ("a.png", img, "image/png")), ("images", ("b.png", img, "image/png"))]
    cases = [
        ({"camera_id": str(cam["id"]), "angles_deg": "0,10,20"}, "2 images but 3 commanded angles"),
        ({"camera_id": str(cam["id"]), "angles_deg": "0,x"}, "angles_deg: give numbers"),
        ({"camera_id": str(cam["id"]), "angles_deg": "0,10", "target": '{"groups": []}'}, "target:"),
        ({"camera_id": str(cam["id"]), "angles_deg": "0,10", "method": "guess"}, "unknown method"),
    ]
    for data, detail in cases:
        r = client.post("/api/v1/rotary/runs", files=two, data=data)
        assert r.status_code == 422 and detail in r.json()["detail"], (data, r.text)
    assert client.get("/api/v1/rotary/target.pdf").content[:4] == b"%PDF"
