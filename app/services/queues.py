"""Who delivers jobs to workers: worker threads polling the ``job`` table, or Procrastinate.

* :class:`EmbeddedQueue` (SQLite, the two-command start): threads in this process take queued jobs
  from the table; a sweeper queues again the jobs whose worker died (stale heartbeat). Several
  processes on one SQLite file may share it (claims are guarded UPDATEs).
* :class:`ProcrastinateQueue` (PostgreSQL): each job gets a Procrastinate job on queue ``setupcam``;
  Procrastinate hands it to exactly one worker (``FOR UPDATE SKIP LOCKED``), its workers send
  heartbeats, and :func:`retry_stalled` gives the jobs of a silent worker to another one.

Both run a job with :func:`app.services.jobs.execute`, so a job behaves the same wherever it runs.
"""

from __future__ import annotations

import asyncio
import logging
import threading
from typing import Protocol

from procrastinate import App, PsycopgConnector, SyncPsycopgConnector
from procrastinate.exceptions import AlreadyEnqueued, ProcrastinateException
from sqlalchemy.engine import Engine
from sqlmodel import Session, select

from app.services.jobs import JobContext, JobKind, execute, next_queued, recover_stalled, release, worker_name
from app.store.models import Job

log = logging.getLogger(__name__)

QUEUE = "setupcam"
TASK = "setupcam.run_job"
POLL_S = 0.5  # how often an idle embedded worker looks for jobs queued by another process


class Queue(Protocol):
    def push(self, job_id: int) -> None: ...
    def alive(self) -> bool: ...
    def shutdown(self) -> None: ...


def is_postgres(engine: Engine) -> bool:
    return engine.dialect.name == "postgresql"


def make_queue(ctx: JobContext, kinds: dict[str, JobKind], *, run_jobs: bool, concurrency: int) -> Queue:
    """The service's queue: Procrastinate on PostgreSQL, the table poller on SQLite; with ``run_jobs``
    it also runs jobs in this process (SETUPCAM_EMBEDDED_WORKER), else it only enqueues."""
    if is_postgres(ctx.engine):
        return ProcrastinateQueue(ctx, kinds, run_jobs=run_jobs, concurrency=concurrency)
    return EmbeddedQueue(ctx, kinds, run_jobs=run_jobs, concurrency=concurrency)


# ------------------------------------------------------------------------------------------ embedded
class EmbeddedQueue:
    """Worker threads that take queued jobs from the table (or none: enqueue only)."""

    def __init__(self, ctx: JobContext, kinds: dict[str, JobKind], *, run_jobs: bool = True, concurrency: int = 1):
        self.ctx, self.kinds = ctx, kinds
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._running: set[int] = set()
        self._lock = threading.Lock()
        self._threads: list[threading.Thread] = []
        if run_jobs:
            self._threads = [threading.Thread(target=self._work, name=f"setupcam-worker-{i}", daemon=True)
                             for i in range(max(1, concurrency))]
            self._threads.append(threading.Thread(target=self._sweep, name="setupcam-job-sweeper", daemon=True))
        for t in self._threads:
            t.start()

    def push(self, job_id: int) -> None:
        self._wake.set()  # the row is the queue: wake an idle thread rather than wait for its poll

    def alive(self) -> bool:
        return not self._stop.is_set()

    def running(self) -> set[int]:
        with self._lock:
            return set(self._running)

    def _work(self) -> None:
        kinds = list(self.kinds)
        while not self._stop.is_set():
            job_id = next_queued(self.ctx.engine, kinds)
            if job_id is None:
                self._wake.wait(POLL_S)
                self._wake.clear()
                continue
            with self._lock:
                self._running.add(job_id)
            try:
                execute(self.ctx, self.kinds, job_id)
            except Exception:  # noqa: BLE001 - the database went away: keep the thread alive, retry later
                log.exception("job runner error", extra={"job_id": job_id})
                self._stop.wait(POLL_S)
            finally:
                with self._lock:
                    self._running.discard(job_id)

    def _sweep(self) -> None:
        period = max(0.5, self.ctx.settings.job_stall_s / 4)
        while True:
            try:
                recover_stalled(self.ctx, self.kinds, self.push)
            except Exception:  # noqa: BLE001
                log.exception("stalled-job sweep failed")
            if self._stop.wait(period):
                return

    def shutdown(self) -> None:
        """Stop taking jobs; the jobs running here go back to the queue (their threads cannot be
        interrupted; what they write afterwards is refused)."""
        self._stop.set()
        self._wake.set()
        release(self.ctx, self.kinds, sorted(self.running()))


# ------------------------------------------------------------------------------------------ procrastinate
def conninfo(engine: Engine) -> str:
    """The libpq URL of the engine's PostgreSQL database (for Procrastinate's own connections)."""
    return engine.url.set(drivername="postgresql").render_as_string(hide_password=False)


def procrastinate_app(connector, ctx: JobContext, kinds: dict[str, JobKind]) -> App:
    """A Procrastinate app whose one task runs our job ``job_id`` with the context built at start-up."""
    app = App(connector=connector)

    @app.task(name=TASK, queue=QUEUE)
    def run_job(job_id: int) -> None:
        # A job Procrastinate delivers again was left by a worker whose heartbeats stopped (stalled-job
        # recovery): take over a running row whose own heartbeat is 3 beats old.
        execute(ctx, kinds, job_id, stale_s=3 * ctx.settings.job_heartbeat_s)

    return app


def defer(app: App, job_id: int) -> None:
    """One Procrastinate job per job row; a second defer of a job still waiting is a no-op."""
    try:
        app.configure_task(TASK, queueing_lock=f"job-{job_id}", queue=QUEUE).defer(job_id=job_id)
    except AlreadyEnqueued:
        pass


async def retry_stalled(app: App, ctx: JobContext) -> None:
    """Procrastinate's stalled-job recovery: jobs held by a worker without heartbeat for
    ``job_stall_s`` go back to ``todo`` and another worker takes them."""
    period = max(0.5, ctx.settings.job_stall_s / 4)
    while True:
        await asyncio.sleep(period)
        try:
            stalled = await app.job_manager.get_stalled_jobs(seconds_since_heartbeat=ctx.settings.job_stall_s,
                                                             queue=QUEUE)
            for job in stalled:
                try:
                    await app.job_manager.retry_job(job)
                    log.warning("stalled job given to another worker", extra={"procrastinate_job": job.id,
                                                                               "args": job.task_kwargs})
                except ProcrastinateException:
                    pass  # another worker retried it first
        except Exception:  # noqa: BLE001 - the database went away for a moment: try again next period
            log.exception("stalled-job check failed")


async def run_procrastinate_worker(ctx: JobContext, kinds: dict[str, JobKind], *, concurrency: int, name: str,
                                   install_signal_handlers: bool) -> None:
    """A Procrastinate worker (sync jobs in ``concurrency`` threads) plus the stalled-job check, until
    cancelled or signalled."""
    app = procrastinate_app(PsycopgConnector(conninfo=conninfo(ctx.engine)), ctx, kinds)
    async with app.open_async():
        checker = asyncio.create_task(retry_stalled(app, ctx))
        try:
            await app.run_worker_async(
                queues=[QUEUE], concurrency=concurrency, name=name, wait=True,
                install_signal_handlers=install_signal_handlers, listen_notify=True,
                fetch_job_polling_interval=1.0, update_heartbeat_interval=ctx.settings.job_heartbeat_s,
                stalled_worker_timeout=ctx.settings.job_stall_s, shutdown_graceful_timeout=2.0, delete_jobs="successful")
        finally:
            checker.cancel()


class ProcrastinateQueue:
    """Jobs go through Procrastinate; with ``run_jobs`` a worker also runs in a thread of this process."""

    def __init__(self, ctx: JobContext, kinds: dict[str, JobKind], *, run_jobs: bool = False, concurrency: int = 1):
        self.ctx, self.kinds = ctx, kinds
        self.app = procrastinate_app(SyncPsycopgConnector(conninfo=conninfo(ctx.engine)), ctx, kinds)
        self.app.open()
        self._stopped = False
        self._loop: asyncio.AbstractEventLoop | None = None
        self._task: asyncio.Task | None = None
        self._thread: threading.Thread | None = None
        self._requeue_waiting()
        if run_jobs:
            ready = threading.Event()
            self._thread = threading.Thread(target=self._run, args=(concurrency, ready), daemon=True,
                                            name="setupcam-procrastinate")
            self._thread.start()
            ready.wait(10)

    def _requeue_waiting(self) -> None:
        """Queued rows whose Procrastinate job never got written (the process died between the two)."""
        with Session(self.ctx.engine) as session:
            for job_id in session.exec(select(Job.id).where(Job.status == "queued")).all():
                defer(self.app, job_id)

    def _run(self, concurrency: int, ready: threading.Event) -> None:
        async def main() -> None:
            self._loop = asyncio.get_running_loop()
            self._task = asyncio.current_task()
            ready.set()
            await run_procrastinate_worker(self.ctx, self.kinds, concurrency=concurrency, name=worker_name(),
                                           install_signal_handlers=False)

        try:
            asyncio.run(main())
        except asyncio.CancelledError:
            pass
        except Exception:  # noqa: BLE001
            log.exception("embedded Procrastinate worker stopped")

    def push(self, job_id: int) -> None:
        defer(self.app, job_id)

    def alive(self) -> bool:
        return not self._stopped and (self._thread is None or self._thread.is_alive())

    def shutdown(self) -> None:
        self._stopped = True
        if self._loop is not None and self._task is not None:
            self._loop.call_soon_threadsafe(self._task.cancel)
            self._thread.join(timeout=10)
        self.app.close()
