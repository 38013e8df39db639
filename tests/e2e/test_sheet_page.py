"""The sheet monitor page in a real headless Chromium: live decisions, the corner-error chart, Stop."""

from __future__ import annotations

import json

import cv2
import pytest

from app.synth.bed_images import bed_camera, drift_sequence, render_bed_image, scene_variant
from tests.support.jobs import settled
from tests.support.factories import make_machine
from tests.support.browser import ARTIFACTS, signed_in_page, skip_without_chromium
from tests.support.live_server import live_server

pytestmark = pytest.mark.integration

CAM = bed_camera(800, 600, mm_per_px=1.0, target_bed_mm=(650.0, 420.0))
SCENE = scene_variant("plain", sheet_angle_deg=2.0, thickness_mm=3.0, seed=0)

skip_without_chromium()


def _jpg(img) -> bytes:
    return cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()


def test_sheet_page_without_a_monitor_says_so_in_words(tmp_path):
    with live_server(tmp_path / "data", "sqlite", load_example_library=False) as srv:
        with signed_in_page(srv) as (page, errors):
            page.goto(f"{srv.url}/sheet")
            msg = page.get_by_test_id("status-message")
            msg.filter(has_text="No sheet is being monitored").wait_for()
            assert "/api/" not in msg.inner_text()
            assert not page.get_by_test_id("stop-button").is_visible()
            assert not page.get_by_test_id("alignment-picture").is_visible()
            assert page.locator("header.top nav a[href='/sheet']").count() == 1
            assert errors == []


def test_sheet_page_shows_live_decisions_chart_and_stops(tmp_path):
    with live_server(tmp_path / "data", "sqlite") as srv:
        with srv.client("admin") as c:
            cam = c.post("/api/v1/cameras", json={"name": "bed cam", "intrinsics": CAM.intrinsics_dict()}).json()
            machine = make_machine(c, None, T_machine_table=[[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]],
                                   travel={"x": [0, 1500], "y": [0, 1000], "z": [-100, 100]})
        with srv.client("operator") as c:
            a = c.post("/api/v1/sheet/alignments", data={
                "machine_id": machine["id"], "camera_id": cam["id"], "thickness_mm": 3.0,
                "T_cam_bed": json.dumps(CAM.T_cam_bed.tolist())},
                files={"image": ("bed.jpg", _jpg(render_bed_image(SCENE, CAM).image))})
            a = settled(c, a).json()
            c.post(f"/api/v1/sheet/alignments/{a['id']}/confirm")
            mid = c.post("/api/v1/sheet/monitors", json={"alignment_id": a["id"], "l1_mm": 1.0, "l2_mm": 4.0}).json()["id"]
            seq = drift_sequence(SCENE, CAM, [(0, 0, 0), (0.4, 0, 0), (1.5, 0.5, 0.1)])
            with signed_in_page(srv, viewport=(1280, 900)) as (page, errors):
                page.goto(f"{srv.url}/sheet?monitor={mid}")
                page.locator("#lastnone").filter(has_text="None so far").wait_for()   # no broken picture
                assert not page.get_by_test_id("decision-picture").is_visible()
                page.get_by_test_id("thresholds").filter(has_text="L2 = 4.00 mm").wait_for()
                for f in seq.frames:
                    assert c.post(f"/api/v1/sheet/monitors/{mid}/frames", files={"frame": ("f.jpg", _jpg(f))}).status_code == 200
                page.get_by_test_id("decision").filter(has_text="NEW ORIGIN").wait_for(timeout=10_000)
                c.post(f"/api/v1/sheet/monitors/{mid}/frames")  # a missing frame
                page.get_by_test_id("decision").filter(has_text="NO PICTURE").wait_for(timeout=10_000)
                # the chart has the four corner lines: blue pixels of corner 0 inside the plot
                blue = page.evaluate("""() => { const c = document.getElementById('chart');
                    const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; let n = 0;
                    for (let i = 0; i < d.length; i += 4) if (d[i] < 60 && d[i+1] < 110 && d[i+2] > 180) n++; return n; }""")
                assert blue > 20
                page.screenshot(path=str(ARTIFACTS / "sheet-page.png"))
                page.get_by_test_id("stop-button").click()
                page.get_by_test_id("status-message").filter(has_text="has ended").wait_for(timeout=10_000)
                assert page.get_by_test_id("stop-button").is_disabled()
                assert errors == []
            assert c.get(f"/api/v1/sheet/monitors/{mid}").json()["state"] == "finished"
