"""Rotary tables on the pages, in a real headless Chromium: the admin sees and changes a machine's rotary
axis on the Machines page (the table pose is then derived, read-only); the operator types the table angle
with a picture on the setup page (refused without it) and reads beside the offset for which angle it is
and at which angle the picture was taken."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.geometry.rotary_chain import RotaryChain
from app.geometry.transforms import pose_from_xyz_euler
from app.store.db import session_scope
from app.store.models import Setup
from tests.support.browser import ARTIFACTS, signed_in_page, skip_without_chromium, upload_photo
from tests.support.factories import INTRINSICS, located_setup, make_machine
from tests.support.live_server import live_server

pytestmark = [pytest.mark.integration, pytest.mark.slow]

skip_without_chromium()

T_MACHINE_AXIS = pose_from_xyz_euler(10.0, -20.0, -320.0)
T_AXIS_TABLE = pose_from_xyz_euler(-400.0, -200.0, 0.0)
ROTARY = {"name": "C", "T_machine_axis": T_MACHINE_AXIS.tolist(), "T_axis_table": T_AXIS_TABLE.tolist(),
          "angle_from": "operator", "export_at_deg": 0.0}


def test_admin_sets_the_axis_and_the_operator_types_the_angle(tmp_path):
    with live_server(tmp_path / "data", "sqlite", load_example_library=False) as srv:
        with srv.client("admin") as c:
            m = make_machine(c, None)
            r = c.patch(f"/api/v1/machines/{m['id']}", json={"rotary_axis": ROTARY, "T_machine_table": None})
            assert r.status_code == 422  # null is no pose: refused with the reason
            r = c.patch(f"/api/v1/machines/{m['id']}", json={"rotary_axis": ROTARY})
            assert r.status_code == 200, r.text

        with signed_in_page(srv, "admin") as (page, errors):
            page.goto(f"{srv.url}/machines")
            assert "rotary C (angle typed, offsets for C = 0°)" in page.get_by_test_id("machine-card").inner_text()
            page.get_by_test_id("machine-edit").click()
            form = page.get_by_test_id("machine-form")
            form.wait_for()
            assert form.get_by_test_id("machine-rotary-on").is_checked()
            assert form.get_by_test_id("machine-rotary-name").input_value() == "C"
            assert form.get_by_test_id("machine-table-x").is_disabled()  # derived from the chain
            form.get_by_test_id("machine-rotary-export").fill("90")
            page.get_by_test_id("machine-save").click()
            page.get_by_test_id("machine-message").filter(has_text="Saved").wait_for()
            with srv.client("admin") as c:
                got = c.get(f"/api/v1/machines/{m['id']}").json()
            assert got["rotary_axis"]["export_at_deg"] == 90.0
            assert np.allclose(got["T_machine_table"], RotaryChain("C", T_MACHINE_AXIS, T_AXIS_TABLE).T_machine_table(90))
            assert not errors, errors
            with srv.client("admin") as c:  # back to C = 0 for the operator's part
                c.patch(f"/api/v1/machines/{m['id']}", json={"rotary_axis": ROTARY})

        png = cv2.imencode(".png", np.full((INTRINSICS["height"], INTRINSICS["width"], 3), 90, np.uint8))[1].tobytes()
        with signed_in_page(srv, "operator") as (page, errors):
            page.goto(f"{srv.url}/setup?machine={m['id']}")
            box = page.get_by_test_id("table-angle-box")
            box.wait_for()
            assert "offsets are for C = 0" in page.get_by_test_id("table-angle-note").inner_text()
            upload_photo(page, {"name": "c.png", "mimeType": "image/png", "buffer": png})
            page.get_by_test_id("status-message").filter(has_text="Type the table angle C").wait_for()
            page.get_by_test_id("table-angle").fill("37.5")
            upload_photo(page, {"name": "c.png", "mimeType": "image/png", "buffer": png})
            page.wait_for_function("() => /Setup \\d+/.test(document.getElementById('setup-id').textContent)")
            with srv.client("admin") as c:
                latest = c.get("/api/v1/setups", params={"machine_id": m["id"], "limit": 1}).json()[0]
            assert latest["table_angle_deg"] == 37.5 and latest["table_angle_from"] == "operator"
            assert not errors, errors

        sid = located_setup(srv, m["id"], pose_from_xyz_euler(300, 120, 0, c_deg=20))
        with session_scope(srv.app.state.engine) as session:
            s = session.get(Setup, sid)
            s.table_angle_deg, s.table_angle_from = 37.0, "operator"
            session.add(s)
        with signed_in_page(srv, "operator") as (page, errors):
            page.goto(f"{srv.url}/setup?machine={m['id']}&setup={sid}")
            note = page.get_by_test_id("offset-note")
            note.filter(has_text="Offset for C").wait_for()
            text = note.inner_text()
            assert "Offset for C = 0" in text and "picture taken at C = 37" in text and "typed by the operator" in text
            page.screenshot(path=str(ARTIFACTS / "rotary-setup.png"))
            assert not errors, errors
