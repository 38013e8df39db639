"""The PostgreSQL path: a service that only enqueues (SETUPCAM_EMBEDDED_WORKER=false), two
``setupcam worker`` processes sharing its database and file store, Procrastinate between them. A worker
killed (-9) in the middle of a localisation: its job goes to the other worker and ends located."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support.live_server import live_server, postgres_unavailable_reason
from tests.support.sample_setup import sample_machine, start_setup, wait_for
from tests.support.service_process import clean_env

pytestmark = [pytest.mark.integration, pytest.mark.postgres, pytest.mark.slow]

STALL_S, HEARTBEAT_S = 3.0, 0.5  # a worker silent for 3 s is dead (production: 30 s, 2 s)
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture()
def service(tmp_path):
    why = postgres_unavailable_reason()
    if why:
        pytest.skip(why)
    with live_server(tmp_path / "data", "postgres", embedded_worker=False, job_stall_s=STALL_S,
                     job_heartbeat_s=HEARTBEAT_S) as srv:
        yield srv


def start_worker(srv, log: Path) -> subprocess.Popen:
    """``setupcam worker`` as its own process, with the service's database and data folder."""
    env = clean_env(DATABASE_URL=srv.settings.database_url, SETUPCAM_DATA_DIR=str(srv.settings.data_dir),
                    SETUPCAM_JOB_STALL_S=str(STALL_S), SETUPCAM_JOB_HEARTBEAT_S=str(HEARTBEAT_S),
                    SETUPCAM_LOG_JSON="false", PYTHONPATH=str(REPO))
    with open(log, "w") as out:
        return subprocess.Popen([sys.executable, "-m", "app.cli", "worker", "--concurrency", "1"], cwd=REPO,
                                env=env, stdout=out, stderr=subprocess.STDOUT)


def pid_of(job: dict) -> int:
    """The process id in a job's ``worker`` (host:pid/thread)."""
    return int(job["worker"].split(":", 1)[1].split("/", 1)[0])


def test_a_worker_killed_mid_localisation_its_job_finishes_on_the_other(service, tmp_path):
    with service.client() as c:
        machine_id, bracket = sample_machine(c)
        accepted = start_setup(c, machine_id, bracket)
        time.sleep(1.0)
        job = c.get(accepted["job_url"]).json()
        assert job["status"] == "queued" and job["attempts"] == 0, "the service only enqueues"
        workers = [start_worker(service, tmp_path / f"worker-{i}.log") for i in range(2)]
        try:
            setup = wait_for(c, accepted["url"], lambda s: s["status"] == "running" and s["stages"], 120,
                             "localisation under way")
            job = c.get(accepted["job_url"]).json()
            victim = next(w for w in workers if w.pid == pid_of(job))
            survivor = next(w for w in workers if w is not victim)
            os.kill(victim.pid, signal.SIGKILL)
            killed_at = time.monotonic()
            victim.wait(10)
            job = wait_for(c, accepted["job_url"], lambda j: j["attempts"] == 2, 60, "taken over")
            taken_after_s = time.monotonic() - killed_at
            # stated: within job_stall_s (+ a check period, STALL_S / 4, and a poll)
            assert taken_after_s < STALL_S + STALL_S / 4 + 3.0, taken_after_s
            assert pid_of(job) == survivor.pid
            job = wait_for(c, accepted["job_url"], lambda j: j["status"] in ("done", "failed"), 180)
            assert job["status"] == "done" and job["attempts"] == 2, job
            setup = c.get(accepted["url"]).json()
            assert setup["status"] == "located", setup["reason"]
            assert [s["name"] for s in setup["stages"]].count(setup["stages"][0]["name"]) == 1, \
                "the second run starts its stages afresh"
            assert survivor.poll() is None, "the survivor keeps running"
        finally:
            for w in workers:
                if w.poll() is None:
                    w.send_signal(signal.SIGTERM)
            for w in workers:
                try:
                    w.wait(15)
                except subprocess.TimeoutExpired:
                    w.kill()
