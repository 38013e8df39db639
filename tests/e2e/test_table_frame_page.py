"""T_machine_table without maths, in a real headless Chromium against the LinuxCNC sim: the admin adds a
machine with the sim as its controller, jogs (MDI moves in machine coordinates) to the table's corner,
a point on its front edge and one on its left edge, presses Read position at each, works the pose out,
sees the table drawn where it sits, and saves; the saved T_machine_table is checked over the API.

Run alone under the LinuxCNC lock: ``flock /tmp/lcnc.lock python -m pytest tests/e2e/test_table_frame_page.py``.
"""

from __future__ import annotations

import math
import re
import sys
import urllib.parse

import numpy as np
import pytest

from tests.e2e.test_admin_pages import REPO, browser, lcnc, menu, sign_in  # noqa: F401 - shared fixtures
from tests.support.browser import ARTIFACTS, skip_without_chromium
from tests.support.service_process import clean_env, service_process

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.linuxcnc]

skip_without_chromium()

CORNER = np.array([-420.0, -230.0, -280.0])   # the table's front-left top corner, machine coordinates (mm)
C_DEG = 5.0                                    # the table turned 5° on the machine
TOOL_MM = 25.0                                 # a probe with this length offset (G43.1) touches the corner


def _on_edge(along_deg: float, span_mm: float, dz_mm: float = 0.0) -> np.ndarray:
    a = math.radians(C_DEG + along_deg)
    return CORNER + [span_mm * math.cos(a), span_mm * math.sin(a), dz_mm]


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("table-frame-page")
    env = clean_env(PYTHONPATH=str(REPO))
    with service_process([sys.executable, "-m", "app.cli"], tmp / "data", cwd=tmp, env=env) as svc:
        yield svc


def _field(form, testid: str) -> float:
    return float(form.get_by_test_id(testid).input_value())


def test_admin_reads_jogged_points_from_linuxcnc_and_sees_the_table(service, browser, lcnc):  # noqa: F811
    page = sign_in(browser, service.url, "admin", service.first_admin_password())
    menu(page, "Machines", "/machines")
    page.get_by_test_id("machine-add").click()
    mf = page.get_by_test_id("machine-form")
    mf.get_by_test_id("machine-name").fill("Mill with a turned table")
    assert mf.get_by_test_id("machine-read-point1").is_disabled()        # no controller saved yet
    mf.get_by_test_id("machine-controller-kind").select_option("linuxcnc")
    mf.get_by_test_id("machine-controller-host").fill(lcnc.settings["host"])
    mf.get_by_test_id("machine-controller-port").fill(str(lcnc.settings["port"]))
    for axis, (lo, hi) in {"x": (-500, 500), "y": (-500, 500), "z": (-300, 300)}.items():
        mf.locator(f"#tr-{axis}0").fill(str(lo))
        mf.locator(f"#tr-{axis}1").fill(str(hi))
    page.get_by_test_id("machine-save").click()
    page.get_by_test_id("machine-message").filter(has_text="Saved").wait_for()
    read_msg = page.get_by_test_id("machine-read-message")

    points = {"1": CORNER, "2": _on_edge(0.0, 600.0, dz_mm=-0.02), "3": _on_edge(90.0, 300.0)}
    prefixes = {"1": "machine-table", "2": "machine-point2", "3": "machine-point3"}
    try:
        for n, p in points.items():
            if n == "1":   # the corner is touched with a probe whose length offset is active
                lcnc.mdi(f"G43.1 Z{TOOL_MM}")
                lcnc.mdi(f"G53 G0 X{p[0]:.4f} Y{p[1]:.4f} Z{p[2] + TOOL_MM:.4f}")
            else:
                lcnc.mdi("G49")
                lcnc.mdi(f"G53 G0 X{p[0]:.4f} Y{p[1]:.4f} Z{p[2]:.4f}")
            mf.get_by_test_id(f"machine-read-point{n}").click()
            read_msg.filter(has_text=f"Point {n}:").wait_for(timeout=30_000)
            shown = [_field(mf, f"{prefixes[n]}-{a}") for a in "xyz"]
            assert shown == pytest.approx(p, abs=1e-3), (n, shown, read_msg.inner_text())
            if n == "1":
                assert "tool length offset 0.000 / 0.000 / 25.000 mm taken off" in read_msg.inner_text()
                # LinuxCNC's own word: the spindle is 25 mm above the tip the page shows
                assert lcnc.status()["actual_position"][2] == pytest.approx(p[2] + TOOL_MM, abs=1e-3)
    finally:
        lcnc.mdi("G49")
        lcnc.mdi("G53 G0 X0 Y0 Z0")

    mf.get_by_test_id("machine-from-points").click()
    page.wait_for_function("c => Math.abs(Number(document.querySelector('[data-testid=machine-table-c]').value)"
                           " - c) < 1e-3", arg=C_DEG)
    notes = page.get_by_test_id("machine-frame-notes")
    notes.filter(has_text="agree within").wait_for()
    assert "-0.020 mm above the corner" in notes.inner_text()
    figure = page.get_by_test_id("machine-table-figure")
    figure.wait_for(state="visible")
    assert figure.evaluate("img => img.complete && img.naturalWidth") > 0
    svg = urllib.parse.unquote(figure.get_attribute("src").split(",", 1)[1])
    drawn = {k: (float(x), float(y)) for k, x, y in
             re.findall(r'data-point="(\d)" data-x-mm="([-\d.]+)" data-y-mm="([-\d.]+)"', svg)}
    assert set(drawn) == {"1", "2", "3"}
    for n, p in points.items():
        assert drawn[n] == pytest.approx(tuple(p[:2]), abs=1e-3)
    assert svg.count('class="marker"') == 12 and "C 5.0000°" in svg    # the example table's 12 markers
    page.screenshot(path=str(ARTIFACTS / "machines-table-frame.png"), full_page=True)

    page.get_by_test_id("machine-save").click()
    page.get_by_test_id("machine-message").filter(has_text="Saved").wait_for()
    machines = page.request.get(f"{service.url}/api/v1/machines").json()
    T = np.asarray(machines[0]["T_machine_table"])
    c, s = math.cos(math.radians(C_DEG)), math.sin(math.radians(C_DEG))
    assert np.allclose(T[:3, :3], [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-6), T
    assert T[:3, 3] == pytest.approx(CORNER, abs=1e-3)
    assert not page.js_errors, page.js_errors
