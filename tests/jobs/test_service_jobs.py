"""Jobs run by the service itself (SETUPCAM_EMBEDDED_WORKER, the default): a setup as a job while the pages
answer, a job's timeout; a service killed (-9) with one job running (a localisation) and one queued (a sheet
alignment), started again (SQLite and PostgreSQL): both end located."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest

from app.services import setups
from app.services.job_kinds import KINDS
from app.services.setups import search_threads
from app.synth.bed_images import bed_camera, render_bed_image, scene_variant
from tests.support.factories import make_machine
from tests.support.live_server import live_server, postgres_database, postgres_unavailable_reason
from tests.support.sample_setup import sample_machine, start_setup, wait_for
from tests.support.service_process import clean_env, service_process

pytestmark = pytest.mark.integration
REPO = Path(__file__).resolve().parents[2]


def sse_events(client: httpx.Client, url: str) -> list[tuple[str, dict]]:
    """Every (event, data) of a server-sent event stream, until the server ends it."""
    out, event = [], None
    with client.stream("GET", url, timeout=300) as r:
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
        for line in r.iter_lines():
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: "):
                out.append((event, json.loads(line[6:])))
    return out


@pytest.mark.slow
def test_embedded_worker_runs_a_setup_as_a_job_and_the_pages_answer_meanwhile(tmp_path):
    """One localisation (about 20 s of CPU) as a job of the service's own worker, its plane search on two
    threads (a 2-core panel PC's share for one job): its events stream to the end, it ends located, and
    all the while (at a lower priority) the service keeps answering."""
    with live_server(tmp_path / "data", search_threads=2) as srv, srv.client() as c:
        assert srv.settings.embedded_worker and srv.app.state.engine.dialect.name == "sqlite"
        assert search_threads(srv.settings) == 2
        machine_id, bracket = sample_machine(c)
        accepted = start_setup(c, machine_id, bracket)
        assert accepted["job_url"] == f"/api/v1/jobs/{accepted['job_id']}"
        assert accepted["url"] == f"/api/v1/setups/{accepted['id']}"  # the shape the pages already read
        events: list[tuple[str, dict]] = []
        reader = threading.Thread(target=lambda: events.extend(sse_events(c, f"{accepted['job_url']}/events")),
                                  daemon=True)
        reader.start()
        times = []
        while c.get(accepted["job_url"]).json()["status"] in ("queued", "running"):
            t0 = time.perf_counter()
            assert c.get("/api/v1/health").status_code == 200
            assert c.get(accepted["url"]).status_code == 200
            times.append(time.perf_counter() - t0)
            time.sleep(0.05)
        reader.join(30)
        statuses = [d["status"] for e, d in events if e == "status"]
        assert not reader.is_alive() and statuses[-1] == "done" and set(statuses) <= {"queued", "running", "done"}, \
            statuses
        job = c.get(accepted["job_url"]).json()
        assert job["kind"] == "localize" and job["attempts"] == 1 and str(os.getpid()) in job["worker"]
        assert job["result"]["url"] == accepted["url"]
        setup = c.get(accepted["url"]).json()
        assert setup["status"] == "located" and setup["result"]["offset"], setup["reason"]
        assert c.get("/api/v1/health").json()["worker"] == "ok"
        assert len(times) >= 20, "the localisation ran long enough to be measured"
        # two calls each; generous for a shared CI machine (BENCHMARKS.md has the figures under load)
        assert sorted(times)[int(0.95 * (len(times) - 1))] < 0.5, times


def test_a_job_past_its_timeout_fails_with_that_reason(tmp_path):
    with live_server(tmp_path / "data", job_timeout_s=1.0, job_heartbeat_s=0.2) as srv, srv.client() as c:
        machine_id, bracket = sample_machine(c)
        accepted = start_setup(c, machine_id, bracket)
        job = wait_for(c, accepted["job_url"], lambda j: j["status"] in ("done", "failed"), 120)
        assert job["status"] == "failed" and job["reason"].startswith("timed out after 1 s"), job
        # the watchdog ends the job first, then marks its setup: a client reading at once may be between
        setup = wait_for(c, accepted["url"], lambda s: s["status"] != "running", 30, "the setup's end")
        assert setup["status"] == "failed" and setup["reason"] == job["reason"]


def test_a_job_that_times_out_before_its_setup_starts_leaves_the_setup_failed(tmp_path, monkeypatch):
    # the job still reads its library when the watchdog ends it (a loaded machine): its first write, the
    # setup "running", came after the watchdog's "failed" and left the setup running for good
    slow, kind, ended = setups.library_candidates, KINDS["localize"], threading.Event()

    def slow_library(*args, **kwargs):
        time.sleep(0.75)  # twice: the models, then the table
        return slow(*args, **kwargs)

    def run_then_say_so(*args, **kwargs):
        try:
            return kind.run(*args, **kwargs)
        finally:
            ended.set()

    monkeypatch.setattr(setups, "library_candidates", slow_library)
    monkeypatch.setitem(KINDS, "localize", dataclasses.replace(kind, run=run_then_say_so))
    with live_server(tmp_path / "data", job_timeout_s=1.0, job_heartbeat_s=0.2) as srv, srv.client() as c:
        machine_id, bracket = sample_machine(c)
        accepted = start_setup(c, machine_id, bracket)
        job = wait_for(c, accepted["job_url"], lambda j: j["status"] in ("done", "failed"), 60)
        assert job["status"] == "failed" and job["reason"].startswith("timed out after 1 s"), job
        assert ended.wait(60), "the job's own run ended"
        setup = c.get(accepted["url"]).json()
        assert setup["status"] == "failed" and setup["reason"] == job["reason"] and setup["stages"] == [], setup


def test_a_warm_up_that_fails_holds_up_no_job(tmp_path, monkeypatch):
    # the compiled loops made ready before a claim (app.vision.compiled_kernels): should that fail, the
    # job runs anyway and whatever needs the loops makes them itself
    from app.services import jobs

    def broken() -> float:
        raise RuntimeError("no compiler here")

    monkeypatch.setattr(jobs, "warm_up", broken)
    with live_server(tmp_path / "data") as srv, srv.client() as c:
        accepted = start_alignment(c)
        job = wait_for(c, accepted["job_url"], lambda j: j["status"] in ("done", "failed"), 120)
        assert job["status"] == "done" and job["attempts"] == 1, job


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_service_killed_with_jobs_running_and_queued_finishes_them_after_restart(tmp_path, backend):
    data = tmp_path / "data"
    # one worker thread: the first setup runs, the second waits; a job silent for 2 s is taken as dead
    env = clean_env(SETUPCAM_WORKERS="1", SETUPCAM_JOB_STALL_S="2", SETUPCAM_JOB_HEARTBEAT_S="0.5",
                    SETUPCAM_LOG_JSON="false", PYTHONPATH=str(REPO))
    command = [sys.executable, "-m", "app.cli"]
    with contextlib.ExitStack() as stack:
        if backend == "postgres":
            why = postgres_unavailable_reason()
            if why:
                pytest.skip(why)
            env["DATABASE_URL"] = stack.enter_context(postgres_database())
        _kill_and_restart(command, data, env)


def _kill_and_restart(command: list[str], data, env: dict) -> None:
    with service_process(command, data, cwd=REPO, env=env) as svc:
        password = svc.first_admin_password()
        with signed_in(svc.url, password) as c:
            machine_id, bracket = sample_machine(c)
            # a localisation (runs) and a sheet alignment (queued behind it: any kind waits in the same queue)
            first, second = start_setup(c, machine_id, bracket), start_alignment(c)
            wait_for(c, first["url"], lambda s: s["status"] == "running" and s["stages"], 120, "first setup running")
            assert c.get(second["job_url"]).json()["status"] == "queued"
        os.kill(svc.proc.pid, signal.SIGKILL)  # power cut: nothing is settled on the way down
        svc.proc.wait(10)
    env = {**env, "SETUPCAM_WORKERS": "2"}  # after the restart both run side by side
    with service_process(command, data, cwd=REPO, env=env) as svc:
        with signed_in(svc.url, password) as c:
            for accepted, attempts in ((first, 2), (second, 1)):
                job = wait_for(c, accepted["job_url"], lambda j: j["status"] in ("done", "failed"), 240)
                assert job["status"] == "done" and job["attempts"] == attempts, job
                assert c.get(job["result"]["url"]).json()["status"] == "located"


def start_alignment(c: httpx.Client) -> dict:
    """A sheet alignment of a generated bed picture (800 x 600 px): a job of about a second; the 202 answer."""
    cam = bed_camera(800, 600, mm_per_px=1.0, target_bed_mm=(650.0, 420.0))
    scene = scene_variant("plain", sheet_angle_deg=2.0, thickness_mm=3.0, seed=0)
    camera = c.post("/api/v1/cameras", json={"name": "bed cam", "intrinsics": cam.intrinsics_dict()}).json()
    machine = make_machine(c, None, T_machine_table=np.eye(4).tolist(),
                           travel={"x": [0, 1500], "y": [0, 1000], "z": [-100, 100]})
    image = cv2.imencode(".jpg", render_bed_image(scene, cam).image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
    r = c.post("/api/v1/sheet/alignments", data={"machine_id": machine["id"], "camera_id": camera["id"],
                                                 "thickness_mm": 3.0, "T_cam_bed": json.dumps(cam.T_cam_bed.tolist())},
               files={"image": ("bed.jpg", image)})
    assert r.status_code == 202, r.text
    return r.json()



def signed_in(url: str, password: str) -> httpx.Client:
    """A client of the service at ``url`` signed in as its first admin."""
    r = httpx.post(f"{url}/api/v1/auth/login", json={"name": "admin", "password": password}, timeout=60)
    assert r.status_code == 200, r.text
    return httpx.Client(base_url=url, timeout=60, headers={"Authorization": f"Bearer {r.json()['token']}"})
