"""README.md, "First run without hardware", step by step over real HTTP, with the commands and numbers
written there: the service as its own process (as ``make run`` starts it) from an empty data folder,
the printed first-admin password, ``setupcam user passwd``, an admin key from the CLI, the camera from
``samples/camera-intrinsics.json``, the machine JSON of the README (file controller), the sample photo
uploaded as the setup page uploads it, confirm, the first export's acknowledgement, and the offset read
back from the NC file and the API, compared with the values the README promises.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from tests.support.service_process import clean_env, service_process

pytestmark = [pytest.mark.integration, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
SAMPLES = REPO / "samples"


@pytest.fixture(scope="module")
def walkthrough() -> str:
    text = (REPO / "README.md").read_text()
    m = re.search(r"^## First run without hardware\n(.*?)^## ", text, re.S | re.M)
    assert m, "README.md has no section 'First run without hardware'"
    return m.group(1)


def _shell_block(section: str, start: str) -> str:
    """The indented code lines of the README's step that begins with ``start``, unindented."""
    i = section.index(start)
    lines = []
    for line in section[i:].splitlines():
        if lines and not line.startswith("       "):
            break
        lines.append(line[7:])
    return "\n".join(lines)


def _cli(cwd: Path, *args: str) -> str:
    """``.venv/bin/setupcam ARGS`` run in the folder that holds ./var, as the README runs it."""
    r = subprocess.run([sys.executable, "-m", "app.cli", *args], cwd=cwd, capture_output=True, text=True,
                       env=clean_env(PYTHONPATH=str(REPO)), timeout=120)
    assert r.returncode == 0, r.stderr
    return r.stdout


def _readme_offset(section: str) -> dict:
    m = re.search(r"`G10 L2 P1 X(\S+) Y(\S+) Z(\S+) R(\S+)`", section)
    assert m, "the README names the G10 line it expects"
    return dict(zip(("x_mm", "y_mm", "z_mm", "c_deg"), map(float, m.groups())))


def test_first_run_without_hardware(walkthrough, tmp_path):
    here = tmp_path                      # plays the checkout: the service's data folder is ./var
    env = clean_env(PYTHONPATH=str(REPO))
    with service_process([sys.executable, "-m", "app.cli"], here / "var", cwd=here, env=env) as svc:
        # 1. the printed password signs in; `setupcam user passwd admin` replaces it
        printed = svc.first_admin_password()
        assert "setupcam: first start - user 'admin' created with password: <password>" in walkthrough
        assert f"setupcam: first start - user 'admin' created with password: {printed}" in svc.log_text()
        assert ".venv/bin/setupcam user passwd admin" in walkthrough
        assert httpx.post(f"{svc.url}/api/v1/auth/login",
                          json={"name": "admin", "password": printed}).status_code == 200
        new = _cli(here, "user", "passwd", "admin").split("new password (shown once): ")[1].split()[0]

        # 2. the admin key, cut out of the CLI's output the way the README's sed does
        assert "sed -n 's/^key (shown once): //p'" in walkthrough
        key = next(line.removeprefix("key (shown once): ") for line in
                   _cli(here, "apikey", "create", "--scope", "admin", "--name", "first-run").splitlines()
                   if line.startswith("key (shown once): "))
        api = httpx.Client(base_url=svc.url, timeout=60, headers={"Authorization": f"Bearer {key}"})

        # 3. the camera from the sample's intrinsics file
        cam = api.post("/api/v1/cameras", json={"name": "Cabin camera",
                                                "intrinsics": json.loads((SAMPLES / "camera-intrinsics.json").read_text())})
        assert cam.status_code == 201 and cam.json()["id"] == 1, cam.text

        # 4. the machine: the README's JSON with $TABLE and $PWD filled in as the shell would
        table = next(m["id"] for m in api.get("/api/v1/models", params={"kind": "table"}).json()["data"]
                     if m["key"] == "tslot_table_800x400")
        block = _shell_block(walkthrough, "TABLE=$(")
        body = block.split("<<EOF\n", 1)[1].split("\nEOF", 1)[0]
        body = body.replace("$TABLE", str(table)).replace("$PWD", str(here))
        (here / "var" / "nc").mkdir()
        machine = api.post("/api/v1/machines", content=body, headers={"Content-Type": "application/json"})
        assert machine.status_code == 201, machine.text
        assert machine.json()["id"] == 1 and machine.json()["controller"]["kind"] == "file"

        # 5. the sample uploaded as the setup page does (signed in as the admin, machine 1, recognition)
        ui = httpx.Client(base_url=svc.url, timeout=60, headers={"Origin": svc.url})   # a page's own origin
        assert ui.post("/api/v1/auth/login", json={"name": "admin", "password": new}).status_code == 200
        r = ui.post("/api/v1/setups", data={"machine_id": "1"},
                    files={"image": ("bracket_on_table.jpg", (SAMPLES / "bracket_on_table.jpg").read_bytes(),
                                     "image/jpeg")})
        assert r.status_code == 202, r.text
        t0 = time.monotonic()
        while (setup := ui.get(r.json()["url"]).json())["status"] not in ("located", "failed"):
            assert time.monotonic() - t0 < 300, "the sample took more than 5 minutes"
            time.sleep(0.5)
        assert setup["status"] == "located", setup["reason"]
        obj = setup["result"]["objects"][0]
        assert obj["name"] == "Bracket 140 x 90 x 35" and obj["uncertainty_pass"], obj.get("uncertainty_reason")
        print(f"sample located in {time.monotonic() - t0:.1f} s; 1 sigma {obj['sigma']}")

        # 6. confirm; the first export to the empty folder asks for the acknowledgement, then writes
        assert ui.post(f"/api/v1/setups/{setup['id']}/confirm",
                       json={"result_revision": setup["result_revision"]}).status_code == 200
        r = ui.post(f"/api/v1/setups/{setup['id']}/export", json={"slot": "G54"})
        assert r.status_code == 409 and "change" in r.json()["detail"], r.text   # the page's "write anyway"
        r = ui.post(f"/api/v1/setups/{setup['id']}/export", json={"slot": "G54", "acknowledge_change": True})
        assert r.status_code == 200 and r.json()["status"] == "written", r.text

        # 7. the offset in the NC file and through the API, as the README says
        ngc = (here / "var" / "nc" / "setupcam_G54.ngc").read_text()
        m = re.search(r"^G10 L2 P1 X(\S+) Y(\S+) Z(\S+) R(\S+)$", ngc, re.M)
        assert m, ngc
        in_file = dict(zip(("x_mm", "y_mm", "z_mm", "c_deg"), map(float, m.groups())))
        via_api = api.get("/api/v1/machines/1/offsets/G54").json()
        promised = _readme_offset(walkthrough)
        sig = obj["sigma"]
        for k, s in (("x_mm", sig["x_mm"]), ("y_mm", sig["y_mm"]), ("z_mm", sig["z_mm"]), ("c_deg", sig["rz_deg"])):
            assert in_file[k] == pytest.approx(via_api[k], abs=1e-6)
            assert abs(in_file[k] - promised[k]) <= 3 * s + 0.01, (k, in_file[k], promised[k], s)
        truth = json.loads((SAMPLES / "bracket_on_table.truth.json").read_text())["T_table_obj"]
        assert f"table x {truth[0][3]:.2f}, y {truth[1][3]:.2f}, z 35" in walkthrough
