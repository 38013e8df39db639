"""Per-machine limits on the machines page, in a real headless Chromium: the admin sees the global
defaults as placeholders, sets a machine's own change limit, sees it refused when out of range and
persisted when not (checked over the API and after a reload), sets it back to the global one by
emptying the field; an operator sees the limit read-only. The export it gates: tests/api/test_export_gate.py."""

from __future__ import annotations

import pytest

from tests.support.browser import ARTIFACTS, signed_in_page, skip_without_chromium
from tests.support.factories import make_machine
from tests.support.live_server import live_server

pytestmark = [pytest.mark.integration, pytest.mark.slow]

skip_without_chromium()

FIELDS = {"max_tilt_deg": "machine-max-tilt", "max_offset_change_mm": "machine-max-change-mm",
          "max_offset_change_deg": "machine-max-change-deg"}


def _open_form(page, url: str):
    page.goto(f"{url}/machines")
    page.get_by_test_id("machine-edit").click()
    form = page.get_by_test_id("machine-form")
    form.wait_for()
    return form


def _save(page, words: str) -> str:
    page.get_by_test_id("machine-save").click()
    msg = page.get_by_test_id("machine-message").filter(has_text=words)
    msg.wait_for()
    return msg.inner_text()


def test_admin_sets_a_machine_change_limit_and_an_operator_reads_it(tmp_path):
    folder = tmp_path / "nc"
    folder.mkdir()
    with live_server(tmp_path / "data", "sqlite", load_example_library=False,
                     max_offset_change_mm=4.0) as srv:
        with srv.client("admin") as c:
            m = make_machine(c, {"kind": "file", "dialect": "linuxcnc", "folder": str(folder)})

        def stored() -> dict:
            with srv.client("admin") as c:
                got = c.get(f"/api/v1/machines/{m['id']}").json()
            return {k: got[k] for k in FIELDS}

        with signed_in_page(srv, "admin") as (page, errors):
            form = _open_form(page, srv.url)
            mm = form.get_by_test_id("machine-max-change-mm")
            assert [form.get_by_test_id(t).input_value() for t in FIELDS.values()] == ["", "", ""]
            assert [form.get_by_test_id(t).get_attribute("placeholder") for t in FIELDS.values()] == ["0.2", "4", "2"]
            note = form.get_by_test_id("machine-limits-note")
            assert "X, Y, Z change 4 mm (SETUPCAM_MAX_OFFSET_CHANGE_MM)" in note.inner_text()

            mm.fill("0.5")
            assert "X, Y, Z change 0.5 mm (this machine)" in note.inner_text()
            _save(page, "Saved")
            assert stored() == {"max_tilt_deg": None, "max_offset_change_mm": 0.5, "max_offset_change_deg": None}
            assert "own limits: X, Y, Z change 0.5 mm" in page.get_by_test_id("machine-card").inner_text()

            form.get_by_test_id("machine-max-tilt").fill("12")     # beyond 10°: the service says why
            text = _save(page, "max_tilt_deg")
            assert "less than or equal to 10" in text, text
            assert stored()["max_tilt_deg"] is None

            form = _open_form(page, srv.url)                       # after a reload: as saved
            assert form.get_by_test_id("machine-max-change-mm").input_value() == "0.5"
            assert form.get_by_test_id("machine-max-tilt").input_value() == ""
            form.get_by_test_id("machine-limits-note").scroll_into_view_if_needed()
            page.screenshot(path=str(ARTIFACTS / "machine-limits.png"))
            assert not errors, errors

        with signed_in_page(srv, "operator") as (page, errors):
            form = _open_form(page, srv.url)
            field = form.get_by_test_id("machine-max-change-mm")
            assert field.input_value() == "0.5" and field.is_disabled()
            assert not page.get_by_test_id("machine-save").is_visible()
            assert not errors, errors

        with signed_in_page(srv, "admin") as (page, errors):   # emptied: the global setting again
            form = _open_form(page, srv.url)
            form.get_by_test_id("machine-max-change-mm").fill("")
            _save(page, "Saved")
            assert stored() == {"max_tilt_deg": None, "max_offset_change_mm": None, "max_offset_change_deg": None}
            assert "(SETUPCAM_MAX_OFFSET_CHANGE_MM)" in form.get_by_test_id("machine-limits-note").inner_text()
            assert not errors, errors
