"""``setupcam user passwd NAME`` against a service's data folder, as an admin who lost the printed
password would run it: the new password signs in over HTTP, the old one and the old session do not."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from tests.support.service_process import clean_env, service_process

pytestmark = pytest.mark.integration

REPO = Path(__file__).resolve().parents[2]


def _cli(data_dir: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "app.cli", *args], cwd=REPO, capture_output=True, text=True,
                          env=clean_env(SETUPCAM_DATA_DIR=str(data_dir), PYTHONPATH=str(REPO)), timeout=120)


def test_user_passwd_resets_the_first_admin(tmp_path):
    data = tmp_path / "data"
    env = clean_env(SETUPCAM_LOAD_EXAMPLES="false", PYTHONPATH=str(REPO))
    with service_process([sys.executable, "-m", "app.cli"], data, cwd=REPO, env=env) as svc:
        old = svc.first_admin_password()
        login = httpx.post(f"{svc.url}/api/v1/auth/login", json={"name": "admin", "password": old})
        assert login.status_code == 200
        token = login.json()["token"]

        r = _cli(data, "user", "passwd", "admin")
        assert r.returncode == 0, r.stderr
        new = r.stdout.split("new password (shown once): ")[1].split()[0]
        assert new != old

        assert httpx.post(f"{svc.url}/api/v1/auth/login", json={"name": "admin", "password": old}).status_code == 401
        assert httpx.get(f"{svc.url}/api/v1/auth/me", headers={"Authorization": f"Bearer {token}"}).status_code == 401
        r = httpx.post(f"{svc.url}/api/v1/auth/login", json={"name": "admin", "password": new})
        assert r.status_code == 200 and r.json()["role"] == "admin"

        r = _cli(data, "user", "passwd", "admin", "--password", "chosen-by-me")
        assert r.returncode == 0 and "shown once" not in r.stdout
        assert httpx.post(f"{svc.url}/api/v1/auth/login",
                          json={"name": "admin", "password": "chosen-by-me"}).status_code == 200


def test_user_passwd_refuses_unknown_user_and_short_password(tmp_path):
    data = tmp_path / "data"
    assert _cli(data, "user", "add", "anna", "--role", "operator").returncode == 0
    r = _cli(data, "user", "passwd", "bob")
    assert r.returncode == 2 and "no user 'bob'" in r.stderr
    r = _cli(data, "user", "passwd", "anna", "--password", "short")
    assert r.returncode == 2 and "at least 8 characters" in r.stderr
