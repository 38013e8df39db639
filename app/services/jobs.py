"""One way to run long work: a row in the ``job`` table, run by a worker, wherever that worker is.

A job is a kind (``localize``, ``sheet_align``, ``calibrate``, ``rotary``) and its arguments (ids and
small parameters; images are in the file store by sha256). Its function (app/services/job_kinds.py)
takes a :class:`JobRun` (the job's id, its attempt, the :class:`JobContext` built once at start-up)
and the arguments, and returns an :class:`Outcome`. Who delivers the job to a worker is the queue's
business (app/services/queues.py): worker threads polling this table (SQLite) or Procrastinate
(PostgreSQL). Whatever delivers it, :func:`execute` runs it the same way:

* **claim**: a guarded UPDATE takes a queued job, or a running one whose heartbeat is stale (its
  worker died); ``attempts`` grows by one and is the claim's token. Past ``max_attempts`` it fails.
* **heartbeat and timeout**: a watchdog thread renews ``heartbeat_at`` every ``heartbeat_s``; past
  ``timeout_s`` it fails the job with that reason, and the job's next :meth:`JobRun.check` stops it.
* **finish**: guarded by the token, so a run that lost its claim writes nothing.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from dataclasses import dataclass, field
from datetime import timedelta
from typing import Any, Callable

from sqlalchemy import update
from sqlalchemy.engine import Engine
from sqlmodel import Session, col, select

from app.config import Settings
from app.services.errors import NotFound
from app.store.db import session_scope
from app.store.files import FileStore
from app.store.models import Job, utcnow
from app.vision.compiled_kernels import warm_up

log = logging.getLogger(__name__)

FINAL = ("done", "failed")
JOB_NICE = 10  # jobs run at a lower CPU priority than the pages, the event streams and the heartbeats


@dataclass
class JobContext:
    """What every job may use, built once when a service or worker starts (nothing module-global)."""

    engine: Engine
    files: FileStore
    settings: Settings
    events: Any = None  # app.services.events.EventBus
    cache: dict = field(default_factory=dict)  # per process: prepared models by (glb sha256, kind)


@dataclass(frozen=True)
class Outcome:
    """How a job ended: ``ok`` False means it ran but failed (reason in plain words); ``result`` links
    what it made ({"resource": "calibration", "id": 5, "url": ...})."""

    ok: bool
    reason: str = ""
    result: dict | None = None


class JobStopped(Exception):
    """Raised by :meth:`JobRun.check` when the job timed out or another worker took it over."""


@dataclass
class JobRun:
    ctx: JobContext
    job_id: int
    attempt: int
    deadline: float  # time.monotonic() past which the job has timed out
    stopped: threading.Event = field(default_factory=threading.Event)

    def check(self) -> None:
        """Stop here (raise :class:`JobStopped`) when the job timed out or lost its claim; job
        functions call it between stages and before their last write."""
        if self.stopped.is_set() or time.monotonic() > self.deadline:
            raise JobStopped(f"job {self.job_id} attempt {self.attempt} stopped")


@dataclass(frozen=True)
class JobKind:
    """A job function and what to do with its subject (e.g. the setup row) when the job fails
    without it (timeout, crash, worker gone) or goes back to the queue."""

    run: Callable[..., Outcome]
    on_fail: Callable[[JobContext, dict, str], None] | None = None
    on_requeue: Callable[[JobContext, dict], None] | None = None


def worker_name() -> str:
    """host:pid/thread: where a run happens (shown on the job, for the operator and the logs)."""
    return f"{socket.gethostname()}:{os.getpid()}/{threading.current_thread().name}"[:200]


# ------------------------------------------------------------------------------------------ enqueue, read
def create_job(session: Session, kind: str, args: dict, settings: Settings, *, created_by: str | None = None,
               timeout_s: float | None = None) -> Job:
    """A queued job row (flushed, not committed); the caller commits, then hands its id to the queue."""
    job = Job(kind=kind, args=args, timeout_s=timeout_s or settings.job_timeout_s,
              max_attempts=settings.job_max_attempts, created_by=created_by)
    session.add(job)
    session.flush()
    return job


def get_job(session: Session, job_id: int) -> Job:
    job = session.get(Job, job_id)
    if job is None:
        raise NotFound(f"job {job_id} not found")
    return job


def list_jobs(session: Session, *, status: str | None = None, limit: int = 50) -> list[Job]:
    q = select(Job)
    if status:
        q = q.where(Job.status == status)
    return list(session.exec(q.order_by(col(Job.id).desc()).limit(limit)).all())


def next_queued(engine: Engine, kinds: list[str]) -> int | None:
    """The oldest queued job of these kinds (for the polling worker), or None."""
    with Session(engine) as session:
        return session.exec(select(Job.id).where(Job.status == "queued", col(Job.kind).in_(kinds))
                            .order_by(col(Job.id)).limit(1)).first()


# ------------------------------------------------------------------------------------------ run
def _set(engine: Engine, job_id: int, guard: dict, **values: Any) -> bool:
    """UPDATE job SET values WHERE id and every guard column matches; True when the row changed."""
    stmt = update(Job).where(Job.id == job_id)
    for name, value in guard.items():
        stmt = stmt.where(getattr(Job, name) == value)
    with session_scope(engine) as session:
        return session.execute(stmt.values(updated_at=utcnow(), **values)).rowcount == 1


def claim(engine: Engine, job_id: int, worker: str, stale_s: float) -> Job | None:
    """Take the job if it is queued, or running with a heartbeat older than ``stale_s`` (its worker
    died); None when it is someone else's or finished."""
    now = utcnow()
    stale = now - timedelta(seconds=stale_s)
    stmt = (update(Job).where(Job.id == job_id)
            .where((Job.status == "queued") | ((Job.status == "running") & (col(Job.heartbeat_at) < stale)))
            .values(status="running", attempts=Job.attempts + 1, worker=worker, heartbeat_at=now, started_at=now,
                    updated_at=now))
    with session_scope(engine) as session:
        if session.execute(stmt).rowcount != 1:
            return None
    with Session(engine, expire_on_commit=False) as session:
        return session.get(Job, job_id)


def fail_job(ctx: JobContext, kinds: dict[str, JobKind], job: Job, reason: str, *, attempt: int | None = None) -> bool:
    """End the job ``failed`` with ``reason`` (only the run holding ``attempt``, if given) and let its
    kind mark its subject failed too."""
    guard = {"status": "running"} if attempt is None else {"status": "running", "attempts": attempt}
    if not _set(ctx.engine, job.id, guard, status="failed", reason=reason[:2000], finished_at=utcnow()):
        return False
    kind = kinds.get(job.kind)
    if kind is not None and kind.on_fail is not None:
        try:
            kind.on_fail(ctx, job.args, reason)
        except Exception:  # noqa: BLE001 - the job row already says why
            log.exception("marking a failed job's subject failed crashed", extra={"job_id": job.id})
    return True


def execute(ctx: JobContext, kinds: dict[str, JobKind], job_id: int, worker: str | None = None,
            stale_s: float | None = None) -> str | None:
    """Run job ``job_id`` here if it can be claimed (queued, or running with a heartbeat older than
    ``stale_s``, default ``job_stall_s``); the status it ended with (None: not claimed)."""
    # the engine's compiled loops first, before any job of this process is claimed: compiling or
    # loading them holds Python's lock, and a claimed job's heartbeats would wait meanwhile
    try:
        took = warm_up()
        if took:
            log.info("compiled loops ready", extra={"seconds": round(took, 2)})
    except Exception:  # noqa: BLE001 - the jobs that need the loops then make them (or fail) themselves
        log.exception("making the compiled loops ready failed")
    job = claim(ctx.engine, job_id, worker or worker_name(), stale_s or ctx.settings.job_stall_s)
    if job is None:
        return None
    kind = kinds.get(job.kind)
    if kind is None:
        fail_job(ctx, kinds, job, f"unknown job kind {job.kind!r}: this worker is older than the service")
        return "failed"
    if job.attempts > job.max_attempts:
        fail_job(ctx, kinds, job, f"gave up after {job.max_attempts} attempts: the worker running it stopped "
                                  "each time", attempt=job.attempts)
        return "failed"
    run = JobRun(ctx, job.id, job.attempts, time.monotonic() + job.timeout_s)
    watchdog = threading.Thread(target=_watch, args=(ctx, kinds, job, run), daemon=True,
                                name=f"job-{job.id}-watchdog")
    watchdog.start()
    log.info("job started", extra={"job_id": job.id, "kind": job.kind, "attempt": job.attempts})
    lower_priority()  # after the watchdog started: its heartbeats keep the normal priority
    try:
        outcome = kind.run(run, **job.args)
        run.check()
    except JobStopped:
        if time.monotonic() > run.deadline:  # the watchdog may not have looked yet: the reason is written once
            fail_job(ctx, kinds, job, timeout_reason(job), attempt=run.attempt)
        return "failed"  # else another worker holds the job now
    except Exception as exc:  # noqa: BLE001 - a crash ends the job failed, with a reason
        log.exception("job crashed", extra={"job_id": job.id, "kind": job.kind})
        fail_job(ctx, kinds, job, f"internal error in {job.kind} ({exc.__class__.__name__}); it has been logged",
                 attempt=job.attempts)
        return "failed"
    finally:
        run.stopped.set()
        watchdog.join(timeout=5)
    status = "done" if outcome.ok else "failed"
    _set(ctx.engine, job.id, {"status": "running", "attempts": job.attempts}, status=status,
         reason=outcome.reason[:2000], result=outcome.result, finished_at=utcnow())
    log.info("job finished", extra={"job_id": job.id, "kind": job.kind, "status": status})
    return status


def _watch(ctx: JobContext, kinds: dict[str, JobKind], job: Job, run: JobRun) -> None:
    """Renew the heartbeat; past the deadline fail the job (timeout); stop when the run ends or
    another worker took the job."""
    beat = ctx.settings.job_heartbeat_s
    while not run.stopped.wait(beat):
        if time.monotonic() > run.deadline:
            fail_job(ctx, kinds, job, timeout_reason(job), attempt=run.attempt)
            run.stopped.set()
            return
        if not _set(ctx.engine, job.id, {"status": "running", "attempts": run.attempt}, heartbeat_at=utcnow()):
            run.stopped.set()  # taken over or ended elsewhere: this run's writes would be refused anyway
            return


def timeout_reason(job: Job) -> str:
    return f"timed out after {job.timeout_s:g} s (SETUPCAM_JOB_TIMEOUT_S)"


def lower_priority() -> None:
    """Give this thread (only it: Linux schedules threads one by one) nice ``JOB_NICE``, so that a
    localisation yields the CPU to the pages of the same machine; a no-op where that is not possible."""
    try:
        tid = threading.get_native_id()
        if os.getpriority(os.PRIO_PROCESS, tid) < JOB_NICE:
            os.setpriority(os.PRIO_PROCESS, tid, JOB_NICE)
    except (AttributeError, OSError):
        pass


def recover_stalled(ctx: JobContext, kinds: dict[str, JobKind], push: Callable[[int], None]) -> list[int]:
    """Jobs ``running`` whose heartbeat is older than ``job_stall_s`` (their worker died: killed,
    power cut, service restarted): back to the queue while attempts remain, else failed with the
    reason. Returns the ids sent back."""
    stale = utcnow() - timedelta(seconds=ctx.settings.job_stall_s)
    with Session(ctx.engine, expire_on_commit=False) as session:
        rows = session.exec(select(Job).where(Job.status == "running", col(Job.heartbeat_at) < stale)).all()
    requeued = []
    for job in rows:
        if job.attempts >= job.max_attempts:
            fail_job(ctx, kinds, job, f"its worker ({job.worker}) stopped while it ran, {job.attempts} times; "
                                      "given up", attempt=job.attempts)
            continue
        if _set(ctx.engine, job.id, {"status": "running", "attempts": job.attempts}, status="queued",
                reason=f"its worker ({job.worker}) stopped; queued again"):
            kind = kinds.get(job.kind)
            if kind is not None and kind.on_requeue is not None:
                kind.on_requeue(ctx, job.args)
            push(job.id)
            requeued.append(job.id)
    if requeued:
        log.warning("stalled jobs queued again", extra={"job_ids": requeued})
    return requeued


def release(ctx: JobContext, kinds: dict[str, JobKind], job_ids: list[int]) -> None:
    """Jobs this process was running when it stopped (SIGTERM): back to the queue at once instead of
    waiting for their heartbeat to go stale. The abandoned runs cannot finish them (token)."""
    with Session(ctx.engine, expire_on_commit=False) as session:
        rows = [j for j in (session.get(Job, i) for i in job_ids) if j is not None and j.status == "running"]
    for job in rows:
        if _set(ctx.engine, job.id, {"status": "running", "attempts": job.attempts}, status="queued",
                reason="the worker stopped; queued again"):
            kind = kinds.get(job.kind)
            if kind is not None and kind.on_requeue is not None:
                kind.on_requeue(ctx, job.args)

