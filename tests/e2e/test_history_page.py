"""History in a real headless Chromium: each export's status and why, including exports a gate refused
before anything was written (not confirmed, outside the travel); and the setup page shows a file
controller's "nothing written yet" as a note, never as an error."""

from __future__ import annotations

import pytest

from app.geometry.transforms import pose_from_xyz_euler
from tests.support.browser import ARTIFACTS, signed_in_page, skip_without_chromium
from tests.support.factories import located_setup, make_machine
from tests.support.live_server import live_server

pytestmark = [pytest.mark.integration, pytest.mark.slow]

skip_without_chromium()


def test_history_shows_written_failed_and_refused_exports_with_the_reason(tmp_path):
    folder = tmp_path / "nc"
    folder.mkdir()
    with live_server(tmp_path / "data", "sqlite", load_example_library=False) as srv:
        with srv.client("admin") as c:
            m = make_machine(c, {"kind": "file", "dialect": "linuxcnc", "folder": str(folder)})
        unconfirmed = located_setup(srv, m["id"], pose_from_xyz_euler(100, 50, 0))
        far = located_setup(srv, m["id"], pose_from_xyz_euler(5000, 0, 0))
        first = located_setup(srv, m["id"], pose_from_xyz_euler(120, 60, 0, 0, 0, 5))
        with srv.client("operator") as c:
            r = c.post(f"/api/v1/setups/{unconfirmed}/export", json={"slot": "G54"})
            assert r.status_code == 409 and "is not confirmed" in r.text
            for sid in (far, first):
                assert c.post(f"/api/v1/setups/{sid}/confirm", json={"result_revision": 1}).status_code == 200
            r = c.post(f"/api/v1/setups/{far}/export", json={"slot": "G54", "acknowledge_change": True})
            assert r.status_code == 422 and "outside the machine's travel" in r.text
            r = c.post(f"/api/v1/setups/{first}/export", json={"slot": "G54"})   # first write: needs a yes
            assert r.status_code == 409 and "acknowledge_change=true" in r.text
            refused = c.get(f"/api/v1/setups/{far}/export-refusals").json()
            assert [x["slot"] for x in refused] == ["G54"] and "outside the machine's travel" in refused[0]["reason"]
            assert c.get("/api/v1/setups/999999/export-refusals").status_code == 404

        with signed_in_page(srv, "operator") as (page, errors):
            page.goto(f"{srv.url}/history?machine={m['id']}")
            cells = page.get_by_test_id("history-export")
            cells.first.wait_for()
            page.wait_for_function("() => ![...document.querySelectorAll('[data-testid=history-export]')]"
                                   ".some(c => c.textContent === '…')")
            text = {sid: page.locator("tr", has=page.get_by_text(f"#{sid}", exact=True))
                    .get_by_test_id("history-export").inner_text() for sid in (unconfirmed, far, first)}
            assert "G54: refused, nothing written (test-operator (operator)" in text[unconfirmed]
            assert "is not confirmed" in text[unconfirmed]
            assert "refused, nothing written" in text[far] and "outside the machine's travel" in text[far]
            assert "G54: failed. refused, nothing written" in text[first] and "acknowledge_change" in text[first]
            page.screenshot(path=str(ARTIFACTS / "history-refusals.png"), full_page=True)

            # the setup page: the slot never written is a note next to the offset, not an error
            page.goto(f"{srv.url}/setup?machine={m['id']}&setup={first}")
            note = page.locator("#offset-note")
            note.filter(has_text="Controller:").wait_for(timeout=30_000)
            assert "written yet for G54" in note.inner_text() and "502" not in note.inner_text()
            assert not errors, errors
