"""Jobs under load (issue 14): does the page wait on the CPU, and how do workers scale?

1. **Page latency**: 4 localisations of the README sample run at once on this 2-core machine; meanwhile
   4 clients call, for ``--seconds`` (20), the health route, the setup page's API calls (the setup, the
   list of setups, its job) and open the setup's SSE stream (time to its first event). p50/p95/max per
   call, for two set-ups: the two-command default (SQLite, the 4 jobs in the service's own worker
   threads) and a plant (PostgreSQL, the service only enqueues, two `setupcam worker --concurrency 2`).
2. **Throughput**: 100 setups queued at once (PostgreSQL), drained by 1, 2 and 4 `setupcam worker`
   processes (concurrency 1); the time from the first job's start to the last job's end, from the job
   rows' own timestamps. The job is the short path of a real localisation (a picture without table
   markers: decode, marker search, failed with its reason, stages stored), so the figures show the
   queue, not the vision. Its direct cost: the same job function called in this process on 100 more
   such setups; the queue's overhead per job is the 1-worker drain per job minus that.

    PYTHONPATH=. .venv/bin/python benchmarks/job_queue.py [--seconds 20]   # writes benchmarks/job_queue.md
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import os
import platform
import statistics
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import httpx
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from app.config import Settings  # noqa: E402
from app.services.jobs import JobContext, JobRun  # noqa: E402
from app.services.setups import run_setup_job  # noqa: E402
from app.store.db import make_engine  # noqa: E402
from app.store.files import FolderStore  # noqa: E402
from app.store.models import Job  # noqa: E402
from sqlmodel import Session, select  # noqa: E402
from tests.support.factories import make_machine  # noqa: E402
from tests.support.live_server import postgres_database  # noqa: E402
from tests.support.sample_setup import sample_machine, start_setup, wait_for  # noqa: E402
from tests.support.service_process import clean_env, service_process  # noqa: E402

OUT = Path(__file__).with_suffix(".md")
COMMAND = [sys.executable, "-m", "app.cli"]


# ------------------------------------------------------------------------------------------ processes
def env_for(database_url: str | None, **extra: str) -> dict[str, str]:
    env = clean_env(SETUPCAM_LOG_JSON="false", PYTHONPATH=str(REPO), **extra)
    if database_url:
        env["DATABASE_URL"] = database_url
    return env


@contextlib.contextmanager
def workers(n: int, concurrency: int, data_dir: Path, database_url: str):
    """``n`` ``setupcam worker`` processes; yields once each has said it is up."""
    procs, logs = [], []
    env = env_for(database_url, SETUPCAM_DATA_DIR=str(data_dir))
    for i in range(n):
        log = data_dir.parent / f"worker-{i}-{time.monotonic_ns()}.log"
        logs.append(log)
        with open(log, "w") as out:
            procs.append(subprocess.Popen([*COMMAND, "worker", "--concurrency", str(concurrency)], cwd=REPO,
                                          env=env, stdout=out, stderr=subprocess.STDOUT))
    try:
        deadline = time.monotonic() + 120
        while not all("setupcam worker" in log.read_text() for log in logs):
            assert time.monotonic() < deadline, "workers did not start"
            time.sleep(0.2)
        time.sleep(1.0)  # past the log line: the Procrastinate worker registers and listens
        yield procs
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()


def signed_in(url: str, password: str) -> httpx.Client:
    r = httpx.post(f"{url}/api/v1/auth/login", json={"name": "admin", "password": password}, timeout=60)
    r.raise_for_status()
    return httpx.Client(base_url=url, timeout=60, headers={"Authorization": f"Bearer {r.json()['token']}"})


# ------------------------------------------------------------------------------------------ latency
def first_event_ms(client: httpx.Client, url: str) -> float:
    t0 = time.perf_counter()
    with client.stream("GET", url, timeout=30) as r:
        for line in r.iter_lines():
            if line.startswith("event: "):
                return (time.perf_counter() - t0) * 1e3
    raise AssertionError(f"no event from {url}")


def load(client: httpx.Client, setup: dict, seconds: float, n_clients: int = 4) -> dict[str, list[float]]:
    """``n_clients`` threads calling the page's routes in turn (20 ms apart each) for ``seconds``."""
    calls = {
        "GET /api/v1/health": lambda: client.get("/api/v1/health"),
        "GET /api/v1/setups/{id}": lambda: client.get(setup["url"]),
        "GET /api/v1/setups?limit=20": lambda: client.get("/api/v1/setups", params={"limit": 20}),
        "GET /api/v1/jobs/{id}": lambda: client.get(setup["job_url"]),
    }
    times: dict[str, list[float]] = {k: [] for k in [*calls, "SSE /api/v1/setups/{id}/events (first event)"]}
    lock, stop = threading.Lock(), time.monotonic() + seconds

    def run(offset: int) -> None:
        names, i = list(times), offset
        while time.monotonic() < stop:
            name = names[i % len(names)]
            i += 1
            if name.startswith("SSE"):
                ms = first_event_ms(client, setup["events_url"])
            else:
                t0 = time.perf_counter()
                r = calls[name]()
                ms = (time.perf_counter() - t0) * 1e3
                assert r.status_code in (200, 503), r.text
            with lock:
                times[name].append(ms)
            time.sleep(0.02)

    with ThreadPoolExecutor(n_clients) as pool:
        list(pool.map(run, range(n_clients)))
    return times


def latency_run(label: str, tmp: Path, seconds: float, plant: bool) -> tuple[str, dict, float]:
    data = tmp / f"lat-{label}"
    with contextlib.ExitStack() as stack:
        url = stack.enter_context(postgres_database()) if plant else None
        env = env_for(url, SETUPCAM_WORKERS="4", SETUPCAM_EMBEDDED_WORKER="false" if plant else "true")
        svc = stack.enter_context(service_process(COMMAND, data, cwd=REPO, env=env))
        if plant:
            stack.enter_context(workers(2, 2, data, url))
        c = stack.enter_context(signed_in(svc.url, svc.first_admin_password()))
        machine_id, bracket = sample_machine(c)
        setups = [start_setup(c, machine_id, bracket) for _ in range(4)]
        for s in setups:
            wait_for(c, s["url"], lambda b: b["status"] == "running", 300, "all four running")
        load_avg = os.getloadavg()[0]
        times = load(c, setups[0], seconds)
        running = [c.get(s["url"]).json()["status"] for s in setups]
    return f"{label}; at the end of the measurement the 4 setups were {', '.join(running)}", times, load_avg


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


# ------------------------------------------------------------------------------------------ throughput
def blank_setups(c: httpx.Client, n: int) -> list[dict]:
    """``n`` setups of a grey picture (no table markers): the job's short path."""
    machine = make_machine(c, None)

    def post(i: int) -> dict:
        grey = np.full((200, 320), 128, np.uint8)
        grey.flat[:4] = np.frombuffer(int(i + n * time.time_ns() % 10**9).to_bytes(4, "little"), np.uint8)
        img = cv2.imencode(".png", grey)[1].tobytes()  # one file each: no two requests store the same bytes
        r = c.post("/api/v1/setups", data={"machine_id": str(machine["id"])},
                   files={"image": (f"grey{i}.png", img, "image/png")})
        assert r.status_code == 202, r.text
        return r.json()

    with ThreadPoolExecutor(8) as pool:
        return list(pool.map(post, range(n)))


def drain(n_workers: int, tmp: Path, n_jobs: int) -> dict:
    data = tmp / f"drain-{n_workers}"
    with contextlib.ExitStack() as stack:
        url = stack.enter_context(postgres_database())
        svc = stack.enter_context(service_process(COMMAND, data, cwd=REPO,
                                                  env=env_for(url, SETUPCAM_EMBEDDED_WORKER="false")))
        c = stack.enter_context(signed_in(svc.url, svc.first_admin_password()))
        accepted = blank_setups(c, n_jobs)
        ids = [a["job_id"] for a in accepted]
        engine = make_engine(url)
        with workers(n_workers, 1, data, url):
            deadline = time.monotonic() + 600
            while True:
                with Session(engine) as session:
                    rows = session.exec(select(Job).where(Job.id.in_(ids))).all()
                if all(r.status in ("done", "failed") for r in rows):
                    break
                assert time.monotonic() < deadline, "not drained in 10 min"
                time.sleep(0.5)
        lost = [r.id for r in rows if r.reason and "internal error" in r.reason]
        statuses = {r.status for r in rows}
        # steady state: each worker's first job prepares the library's models for its process (seconds);
        # the window starts when the last worker has finished its first job
        per_worker: dict[str, list] = {}
        for r in sorted(rows, key=lambda r: r.started_at):
            per_worker.setdefault(r.worker.split("/")[0], []).append(r)
        warm = max(jobs[0].finished_at for jobs in per_worker.values())
        steady = [r for r in rows if r.started_at >= warm]
        last = max(r.finished_at for r in rows)
        first_job_s = statistics.mean((jobs[0].finished_at - jobs[0].started_at).total_seconds()
                                      for jobs in per_worker.values())
        run_s = [(r.finished_at - r.started_at).total_seconds() for r in steady]
        # the same job function called directly, on as many fresh setups (the first one warms the cache)
        direct = blank_setups(c, n_jobs + 1)
        ctx = JobContext(engine, FolderStore(Path(data) / "files"), Settings(SETUPCAM_DATA_DIR=str(data), DATABASE_URL=url))
        run_setup_job(JobRun(ctx, direct[0]["job_id"], 1, time.monotonic() + 600), direct[0]["id"])
        t0 = time.perf_counter()
        for a in direct[1:]:
            run_setup_job(JobRun(ctx, a["job_id"], 1, time.monotonic() + 600), a["id"])
        direct_s = (time.perf_counter() - t0) / n_jobs
        engine.dispose()
    return {"workers": n_workers, "drain_s": (last - warm).total_seconds(), "steady_jobs": len(steady),
            "jobs": len(rows), "ended": sorted(statuses), "crashed": len(lost), "first_job_s": first_job_s,
            "mean_run_s": statistics.mean(run_s), "per_worker": sorted(len(j) for j in per_worker.values()),
            "direct_s": direct_s, "total_s": (last - min(r.started_at for r in rows)).total_seconds()}


# ------------------------------------------------------------------------------------------ report
def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--jobs", type=int, default=100)
    ap.add_argument("--workers", default="1,2,4", help="worker processes per drain, comma-separated")
    args = ap.parse_args()
    started = time.monotonic()
    import tempfile

    tmp = Path(tempfile.mkdtemp(prefix="setupcam-queue-bench-"))
    lat = [latency_run("SQLite, 4 jobs in the service (embedded worker, SETUPCAM_WORKERS=4)", tmp, args.seconds, False),
           latency_run("PostgreSQL, service only enqueues, 2 x `setupcam worker --concurrency 2`", tmp, args.seconds,
                       True)]
    thr = [drain(int(n), tmp, args.jobs) for n in args.workers.split(",")]
    cpu = next((l.split(":", 1)[1].strip() for l in Path("/proc/cpuinfo").read_text().splitlines()
                if l.startswith("model name")), platform.processor())
    lines = [
        "# Jobs under load: page latency and queue throughput (issue 14)", "",
        "Command:", "", "    PYTHONPATH=. .venv/bin/python benchmarks/job_queue.py", "",
        f"Date: {datetime.date.today()}. Machine: {os.cpu_count()} cores, `{cpu}`, shared with other work. "
        f"Wall clock {time.monotonic() - started:.0f} s.", "",
        "## Page latency while 4 localisations run", "",
        f"The README sample localised 4 times at once (each about 20 s alone); once all 4 are `running`, 4 "
        f"clients call the page's routes in turn for {args.seconds:.0f} s (20 ms pause per call); the SSE "
        "figure is the time from opening the setup's event stream to its first event. All over loopback, "
        "the service in its own process (`setupcam serve`).", ""]
    for label, times, load_avg in lat:
        lines += [f"**{label}** (load average {load_avg:.1f} at the start)", "",
                  "| call | n | p50 ms | p95 ms | max ms |", "| --- | ---: | ---: | ---: | ---: |"]
        for name, v in times.items():
            lines.append(f"| {name} | {len(v)} | {pct(v, 50):.1f} | {pct(v, 95):.1f} | {max(v):.1f} |")
        worst = max(pct(v, 95) for v in times.values())
        lines += ["", f"Worst p95: {worst:.1f} ms ({'within' if worst < 100 else 'ABOVE'} the 100 ms goal).", ""]
    lines += [f"## Throughput: {args.jobs} setups drained by 1, 2 and 4 worker processes (PostgreSQL, Procrastinate)",
              "", "The job's short path (a grey picture: its stored image decoded, the marker search, failed "
              "with its reason and stages stored), so that the queue shows, not the vision. The setups are "
              "queued first, then the workers start. Each worker's first job also prepares the example "
              "library's models for its process (recognition looks at all of them): that is the "
              "\"first job\" column; the steady state starts when every worker has done its first job and "
              "ends with the last job (the job rows' own timestamps).", "",
              "| workers | jobs | ended | all jobs, s | first job, s | steady: jobs | steady: s | jobs/s | "
              "speed-up | run per job, ms | jobs per worker |",
              "| ---: | ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |"]
    base = thr[0]["steady_jobs"] / thr[0]["drain_s"]
    for t in thr:
        rate = t["steady_jobs"] / t["drain_s"]
        lines.append(f"| {t['workers']} | {t['jobs']} | {', '.join(t['ended'])} (none lost, {t['crashed']} crashed) "
                     f"| {t['total_s']:.1f} | {t['first_job_s']:.1f} | {t['steady_jobs']} | {t['drain_s']:.1f} | "
                     f"{rate:.1f} | {rate / base:.2f} | {t['mean_run_s'] * 1e3:.0f} | {t['per_worker']} |")
    direct = statistics.mean(t["direct_s"] for t in thr)
    per_job = thr[0]["drain_s"] / thr[0]["steady_jobs"]
    lines += ["", f"The same job function called directly in one process (warm): {direct * 1e3:.0f} ms per job. "
              f"Through the queue with one worker (steady state): {per_job * 1e3:.0f} ms per job, so the queue "
              f"(Procrastinate's fetch, the claim, the heartbeat thread, the result write) costs about "
              f"{(per_job - direct) * 1e3:.0f} ms per job: nothing against a localisation of 10 to 30 s.", "",
              "On 2 cores the speed-up ends at 2 workers; more workers only share the same cores. Nothing was "
              "lost: every job ended (the short path ends `failed`, no table markers)."]
    OUT.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
