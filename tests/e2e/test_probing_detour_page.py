"""The probing page offers the detour as a controller subroutine (issue 16, part 3), in a real
headless Chromium: the operator chooses "detour as subroutine", the dialects of the subroutine are
offered, and the download is that dialect's program with one subroutine call per move."""

from __future__ import annotations

import pytest

from app.synth.scene import place_on_table
from tests.api.test_probing_gates import _confirmed
from tests.e2e.test_setup_page import browser, page, scene, service  # noqa: F401
from tests.support.browser import ARTIFACTS
from tests.support.factories import make_machine
from tests.support.scenes import library_mesh

pytestmark = pytest.mark.integration

ENABLED = "() => !document.querySelector('[data-testid=download-button]').disabled"


def test_operator_downloads_the_detour_subroutine_program(page, service):  # noqa: F811
    with service.client() as c:
        m = make_machine(c, None)
    sid = _confirmed(service, m["id"], place_on_table(library_mesh("bracket_140"), 300.0, 150.0, 10.0))
    page.goto(f"{service.url}/probing?setup={sid}")
    page.wait_for_function(ENABLED, timeout=60_000)
    assert page.get_by_test_id("dialect-select").locator("option").all_inner_texts() == ["linuxcnc"]
    page.get_by_test_id("detour-select").select_option("subroutine")
    page.wait_for_function("() => document.querySelector('[data-testid=probing-status]').textContent"
                           ".includes('detour subroutine')", timeout=60_000)
    offered = page.get_by_test_id("dialect-select").locator("option").all_inner_texts()
    assert sorted(offered) == ["fanuc", "heidenhain", "linuxcnc", "siemens"]
    page.get_by_test_id("dialect-select").select_option("fanuc")
    page.wait_for_function("() => document.querySelector('[data-testid=probing-status]').textContent"
                           ".includes('detour subroutine')", timeout=60_000)
    page.wait_for_function(ENABLED, timeout=60_000)
    with page.expect_download() as dl:
        page.get_by_test_id("download-button").click()
    assert dl.value.suggested_filename == f"setup{sid}-probe.nc"
    with open(dl.value.path(), encoding="utf-8") as f:
        text = f.read()
    lines = text.splitlines()
    assert sum(ln.startswith("G65 P9100 ") for ln in lines) == 5 and "O9100 (SETUPCAM DETOUR)" in lines
    assert sum(ln.startswith("G31 ") for ln in lines) == 4
    page.screenshot(path=str(ARTIFACTS / "probing-detour-subroutine.png"), full_page=True)
    assert page.js_errors == []
