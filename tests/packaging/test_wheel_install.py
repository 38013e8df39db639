"""The service runs from a wheel installed outside the checkout (what the Docker image does).

Builds the wheel from the checkout's files (the tracked ones and new untracked ones, copied to a
temporary folder so no build output lands in the checkout), installs it into a fresh virtualenv in a
temporary folder and starts ``setupcam serve`` there with the working directory outside the checkout.
The new venv borrows the dependencies of the test environment through a ``.pth`` line (like
``--system-site-packages``) so nothing is downloaded but the build backend; it does not see the
checkout or its editable install. Then: migrations ran, the first admin signs in, pages and the API
reference are served, the example library is loaded, and the sample photo is located.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

import httpx
import pytest

from tests.support.service_process import clean_env, service_process

pytestmark = [pytest.mark.integration, pytest.mark.slow]

REPO = Path(__file__).resolve().parents[2]
SAMPLES = REPO / "samples"


def _run(cmd: list[str], cwd: Path, timeout: float = 300) -> str:
    r = subprocess.run(cmd, cwd=cwd, env=clean_env(), capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"{' '.join(map(str, cmd))} failed:\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r.stdout


def _source_copy(dest: Path) -> Path:
    """The checkout's files as git sees them (tracked, and untracked but not ignored)."""
    listing = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                             capture_output=True, check=True).stdout.decode().split("\0")
    for rel in filter(None, listing):
        src = REPO / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)
    return dest


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """The bin/ folder of a fresh venv outside the checkout with the built wheel installed."""
    if shutil.which("git") is None:
        pytest.fail("git is needed to list the checkout's files")
    tmp = tmp_path_factory.mktemp("wheel")
    src = _source_copy(tmp / "src")
    t0 = time.monotonic()
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp / "dist"), str(src)], cwd=tmp)
    wheel = next((tmp / "dist").glob("setupcam-*.whl"))
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], cwd=tmp)
    site = Path(_run([str(venv / "bin/python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                     cwd=tmp).strip())
    borrowed = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "_test_dependencies.pth").write_text("\n".join(sorted(borrowed)) + "\n")
    _run([str(venv / "bin/python"), "-m", "pip", "install", "--no-deps", "--no-index", "-q", str(wheel)], cwd=tmp)
    print(f"wheel {wheel.name} ({wheel.stat().st_size / 1024:.0f} KiB) built and installed in "
          f"{time.monotonic() - t0:.1f} s")
    return venv / "bin"


def test_installed_package_does_not_use_the_checkout(installed, tmp_path):
    out = _run([str(installed / "python"), "-c",
                "import app, app.resources as r; print(app.__file__); "
                "print(*(r.bundled_dir(n) for n in r.BUNDLED), sep='\\n')"], cwd=tmp_path)
    paths = [Path(p) for p in out.split()]
    venv = installed.parent
    for p in paths:
        assert p.is_relative_to(venv) and not p.is_relative_to(REPO), p
    assert (paths[1] / "env.py").is_file() and (paths[2] / "_layout.html").is_file()
    assert (paths[3] / "library.json").is_file()


def test_service_starts_from_the_wheel(installed, tmp_path):
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    with service_process([str(installed / "setupcam")], tmp_path / "data", cwd=run_dir) as svc:
        password = svc.first_admin_password()
        with httpx.Client(base_url=svc.url, timeout=60) as c:
            # pages, their static files and the offline API reference
            for path in ("/login", "/", "/setup", "/static/app.css", "/docs", "/docs-assets/swagger-ui-bundle.js"):
                assert c.get(path).status_code == 200, path
            r = c.post("/api/v1/auth/login", json={"name": "admin", "password": password})
            assert r.status_code == 200, r.text
            c.headers["Authorization"] = f"Bearer {r.json()['token']}"
            # migrations ran (users, machines...) and the example library was loaded from the package
            keys = {m["key"] for m in c.get("/api/v1/models", params={"limit": 100}).json()["data"]}
            assert {"tslot_table_800x400", "bracket_140", "vise_125"} <= keys, keys
            # one setup: the sample photo, located
            intrinsics = json.loads((SAMPLES / "camera-intrinsics.json").read_text())
            cam = c.post("/api/v1/cameras", json={"name": "Cabin camera", "intrinsics": intrinsics})
            assert cam.status_code == 201, cam.text
            table = next(m for m in c.get("/api/v1/models", params={"kind": "table"}).json()["data"]
                         if m["key"] == "tslot_table_800x400")
            machine = c.post("/api/v1/machines", json={
                "name": "Mill 1", "table_model_id": table["id"], "camera_ids": [cam.json()["id"]],
                "travel_mm": {"x": [0, 1000], "y": [0, 500], "z": [-500, 0]}})
            assert machine.status_code == 201, machine.text
            r = c.post("/api/v1/setups", data={"machine_id": str(machine.json()["id"])},
                       files={"image": ("sample.jpg", (SAMPLES / "bracket_on_table.jpg").read_bytes(), "image/jpeg")})
            assert r.status_code == 202, r.text
            setup = _wait_final(c, r.json()["url"])
            assert setup["status"] == "located", setup["reason"]
            assert setup["result"]["objects"][0]["name"] == "Bracket 140 x 90 x 35"
            assert c.get(setup["overlay_url"]).headers["content-type"] == "image/png"
    assert "Traceback" not in svc.log_text()


def _wait_final(c: httpx.Client, url: str, timeout_s: float = 300) -> dict:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        s = c.get(url).json()
        if s["status"] in ("located", "failed"):
            return s
        time.sleep(0.5)
    raise AssertionError(f"setup {url} not finished within {timeout_s} s")
