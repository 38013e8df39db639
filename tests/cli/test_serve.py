"""``setupcam serve`` as a user starts it: a fresh data folder, first admin printed once, sign-in works."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import httpx
import pytest

from tests.support.live_server import free_port


@pytest.mark.integration
def test_serve_fresh_install_prints_first_admin_once(tmp_path):
    port = free_port()
    env = {**os.environ, "SETUPCAM_DATA_DIR": str(tmp_path), "SETUPCAM_LOAD_EXAMPLES": "false"}
    env.pop("DATABASE_URL", None)

    def start():
        return subprocess.Popen([sys.executable, "-m", "app.cli", "serve", "--port", str(port)], env=env,
                                stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)

    def wait_up(proc):
        for _ in range(300):
            if proc.poll() is not None:
                raise AssertionError(f"serve exited: {proc.stderr.read()}")
            try:
                if httpx.get(f"http://127.0.0.1:{port}/api/v1/health", timeout=1).status_code == 200:
                    return
            except httpx.HTTPError:
                time.sleep(0.1)
        raise AssertionError("serve did not come up")

    proc = start()
    try:
        wait_up(proc)
    finally:
        proc.terminate()
        err = proc.communicate(timeout=20)[1]
    line = next(x for x in err.splitlines() if "first start" in x)
    password = line.rsplit(": ", 1)[1].strip()
    assert (tmp_path / "setupcam.db").exists()

    proc = start()
    try:
        wait_up(proc)
        r = httpx.post(f"http://127.0.0.1:{port}/api/v1/auth/login", json={"name": "admin", "password": password})
        assert r.status_code == 200 and r.json()["role"] == "admin"
    finally:
        proc.terminate()
        err = proc.communicate(timeout=20)[1]
    assert "first start" not in err, "the password is printed once, on the first start only"
