"""Teach from camera on the Library page, in a real headless Chromium: the admin chooses the machine,
names the object, gives its height, picks two pictures and presses Teach; the page says what it
learnt, shows the object seen from above, and a tap on the plate's corner there sets the datum (a new
revision whose T_obj_datum is that corner, checked over the API)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.support.browser import ARTIFACTS, signed_in_page, skip_without_chromium
from tests.support.live_server import live_server
from tests.support.photo_pictures import jpeg, photo_machine, pictures

pytestmark = [pytest.mark.integration, pytest.mark.slow]

skip_without_chromium()


def test_admin_teaches_a_plate_and_taps_its_datum(tmp_path):
    teach1, teach2, _ = pictures()
    paths = []
    for i, s in enumerate((teach1, teach2)):
        paths.append(tmp_path / f"teach{i}.jpg")
        paths[-1].write_bytes(jpeg(s.image))
    with live_server(tmp_path / "data", "sqlite") as srv:
        with srv.client("admin") as c:
            photo_machine(c)
        with signed_in_page(srv, "admin") as (page, errors):
            page.goto(f"{srv.url}/library")
            page.get_by_test_id("teach-machine").select_option(label="photo mill")
            page.get_by_test_id("teach-name").fill("Plate from the page")
            page.get_by_test_id("teach-height").fill("12")
            page.get_by_test_id("teach-pictures").set_input_files([str(p) for p in paths])
            page.get_by_test_id("teach-submit").click()
            msg = page.get_by_test_id("teach-message").filter(has_text="Taught")
            msg.wait_for(timeout=180_000)
            assert "2 hole(s)" in msg.inner_text() and "from 2 picture(s)" in msg.inner_text()
            with srv.client("admin") as c:
                (model,) = [m for m in c.get("/api/v1/models", params={"name": "Plate from the page"}).json()["data"]]
            photo = model["revision"]["photo"]
            img = page.get_by_test_id("teach-picture")
            page.wait_for_function("document.querySelector('[data-testid=teach-picture]').naturalWidth > 0")
            # where the plate's front-left top corner is on the shown (flipped) picture
            g, T = photo["teach_grid"], np.asarray(photo["T_table_obj_teach"])
            corner = teach1.T_table_obj @ np.array([0.0, 0.0, 12.0, 1.0])
            u = (corner[0] - g["x0_mm"]) / g["mm_per_px"]
            v = (corner[1] - g["y0_mm"]) / g["mm_per_px"]
            box = img.bounding_box()
            img.click(position={"x": u / g["width"] * box["width"], "y": (1 - v / g["height"]) * box["height"]})
            page.get_by_test_id("datum-message").filter(has_text="Datum set").wait_for()
            page.screenshot(path=str(ARTIFACTS / "library-teach-from-camera.png"), full_page=True)
            assert not errors, errors
        with srv.client("admin") as c:
            rev = c.get(f"/api/v1/models/{model['id']}").json()["revision"]
        assert rev["revision"] == 2 and rev["photo"]["teach_grid"] == g
        datum = np.asarray(rev["T_obj_datum"])
        expected = np.linalg.inv(T) @ corner
        # a tap is good to about a shown pixel (the picture is shown at about 0.5 mm per pixel)
        assert np.hypot(*(datum[:2, 3] - expected[:2])) < 1.5 and datum[2, 3] == pytest.approx(12.0)
