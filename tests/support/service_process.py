"""``setupcam serve`` as its own process, as a user starts it, for tests that must not share the test
process's imports (the installed wheel, the README walkthrough).

The service's stderr goes to a log file (read for the first admin's password and shown on failure).
"""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx

from tests.support.live_server import free_ports

FIRST_ADMIN = re.compile(r"user 'admin' created with password: (\S+)")


@dataclass
class ServiceProcess:
    url: str
    log: Path
    proc: subprocess.Popen

    def log_text(self) -> str:
        return self.log.read_text(errors="replace")

    def first_admin_password(self) -> str:
        """The password printed once on the first start (the line README.md tells the admin to look for)."""
        m = FIRST_ADMIN.search(self.log_text())
        assert m, f"no first-admin line in the service's output:\n{self.log_text()[-3000:]}"
        return m.group(1)


def clean_env(**extra: str) -> dict[str, str]:
    """This process's environment without anything that points the service elsewhere, plus ``extra``
    (``SETUPCAM_SEARCH_THREADS`` stays: how much of the machine a job takes, tests/conftest.py)."""
    env = {k: v for k, v in os.environ.items()
           if not ((k.startswith("SETUPCAM_") and k != "SETUPCAM_SEARCH_THREADS")
                   or k in ("DATABASE_URL", "PYTHONPATH", "PYTHONHOME"))}
    env.update(extra)
    return env


@contextlib.contextmanager
def service_process(command: list[str], data_dir: Path, *, cwd: Path, env: dict[str, str] | None = None,
                    timeout_s: float = 120.0) -> Iterator[ServiceProcess]:
    """Run ``command + ['serve', --port, --viser-port, --data-dir]`` until the block ends (then SIGTERM)."""
    port, viser_port = free_ports(2)
    log = data_dir.parent / f"{data_dir.name}-service.log"
    with open(log, "w") as out:
        proc = subprocess.Popen([*command, "serve", "--host", "127.0.0.1", "--port", str(port),
                                 "--viser-port", str(viser_port), "--data-dir", str(data_dir)],
                                cwd=cwd, env=env if env is not None else clean_env(), stdout=out,
                                stderr=subprocess.STDOUT)
    svc = ServiceProcess(f"http://127.0.0.1:{port}", log, proc)
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            if proc.poll() is not None:
                raise AssertionError(f"the service exited with {proc.returncode}:\n{svc.log_text()[-5000:]}")
            try:
                if httpx.get(f"{svc.url}/api/v1/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline:
                raise AssertionError(f"the service did not answer within {timeout_s} s:\n{svc.log_text()[-5000:]}")
            time.sleep(0.2)
        yield svc
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=10)
