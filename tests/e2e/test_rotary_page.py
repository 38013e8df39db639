"""The rotary axis check page in a real headless Chromium: upload pictures, see the errors, the plot, a refusal."""

from __future__ import annotations

import cv2
import pytest

from app.synth.rotary_images import RotaryScene, generate_run
from app.vision.rotary_target import default_target
from tests.support.browser import ARTIFACTS, signed_in_page, skip_without_chromium
from tests.support.live_server import live_server

pytestmark = pytest.mark.integration

ANGLES = [0, 45, 90, 45, 0]

skip_without_chromium()


def test_rotary_page_measures_uploaded_pictures_and_shows_refusals(tmp_path):
    scene = RotaryScene(noise_sigma=0.005)
    shots = generate_run(default_target(), ANGLES, scene=scene, seed=1)
    paths = []
    for i, s in enumerate(shots):
        paths.append(tmp_path / f"c{i:02d}.png")
        cv2.imwrite(str(paths[-1]), s.image)
    with live_server(tmp_path / "data", "sqlite") as srv:
        with srv.client("admin") as c:
            cam = c.post("/api/v1/cameras", json={"name": "rotary cam", "intrinsics": scene.intrinsics_dict()}).json()
        with signed_in_page(srv) as (page, errors):
            page.goto(srv.url + "/")
            page.get_by_role("link", name="Rotary axis check").click()
            page.wait_for_url("**/rotary")
            page.get_by_test_id("rotary-camera").locator(f"option[value='{cam['id']}']").wait_for(state="attached")
            assert page.get_by_test_id("rotary-camera").input_value() == str(cam["id"])
            page.get_by_test_id("rotary-images").set_input_files([str(q) for q in paths])

            # a refusal: 5 pictures but 3 angles -> the service's reason in plain words, nothing measured
            page.get_by_test_id("rotary-angles").fill("0,45,90")
            page.get_by_test_id("rotary-measure").click()
            page.get_by_test_id("rotary-error").filter(has_text="5 images but 3 commanded angles").wait_for(timeout=15_000)
            assert page.get_by_test_id("rotary-rows").locator("tr").count() == 0

            page.get_by_test_id("rotary-angles").fill(",".join(map(str, ANGLES)))
            page.get_by_test_id("rotary-measure").click()
            page.get_by_test_id("rotary-error").filter(has_text="Measured.").wait_for(timeout=30_000)
            rows = page.get_by_test_id("rotary-rows").locator("tr")
            assert rows.count() == len(ANGLES)
            cells = [rows.nth(i).locator("td").all_inner_texts() for i in range(len(ANGLES))]
            assert [float(r[1]) for r in cells] == [float(a) for a in ANGLES]
            assert all(abs(float(r[3])) < 60.0 for r in cells)  # arc-seconds; the page shows numbers, not reasons
            plot = page.get_by_test_id("rotary-plot")
            page.wait_for_function("() => { const i = document.querySelector('[data-testid=rotary-plot]'); "
                                   "return i.complete && i.naturalWidth > 100; }", timeout=10_000)
            assert plot.evaluate("i => i.naturalHeight") > 100
            assert "PROPOSAL" in page.get_by_test_id("rotary-result").inner_text().upper()
            assert page.get_by_test_id("rotary-proposals").locator("a").count() == 2
            assert page.get_by_test_id("rotary-downloads").locator("a[href$='.csv']").count() >= 1
            assert page.get_by_test_id("rotary-run").count() == 1  # the past runs list has the new run
            page.screenshot(path=str(ARTIFACTS / "rotary-page.png"), full_page=True)
            box = plot.bounding_box()
            assert box and box["x"] + box["width"] <= 1280  # the plot fits the 1280 px screen
            assert errors == []
