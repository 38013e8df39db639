"""``setupcam worker [--concurrency N]``: run jobs (localisations, sheet alignments, calibrations, rotary
runs) for a service that only enqueues them (``SETUPCAM_EMBEDDED_WORKER=false``).

It reads the same settings as the service (``DATABASE_URL``, ``SETUPCAM_FILE_STORE`` (a shared folder or an
``s3://`` bucket; default ``$SETUPCAM_DATA_DIR/files``), ...). On PostgreSQL it is a Procrastinate worker (heartbeats; the jobs of a worker that went silent are
given to another one); on SQLite it polls the job table. Any number of workers on any number of
machines share the database and the file store. SIGTERM/SIGINT stop it; what it was running goes back
to the queue.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("worker", help="run queued jobs (for a service started with SETUPCAM_EMBEDDED_WORKER=false)")
    p.add_argument("--concurrency", type=int, default=1,
                   help="jobs run at once in this process (threads; default 1). For CPU-bound work on a machine "
                        "with N cores, start N workers of concurrency 1 rather than one of N")
    p.add_argument("--data-dir", help="data folder (overrides SETUPCAM_DATA_DIR): where the file store is, unless "
                                      "SETUPCAM_FILE_STORE names another folder or a bucket")
    p.add_argument("--wait-schema-s", type=float, default=60.0,
                   help="how long to wait for the service to create the database schema (default 60 s)")
    p.set_defaults(func=run)


def worker_settings(settings):
    """The settings a worker process runs its jobs with: a setup's plane search on one thread unless
    ``SETUPCAM_SEARCH_THREADS`` says otherwise. Workers are started one per core (``--concurrency``), and
    a process does not know how many others share its machine; the service's embedded worker shares the
    cores among its own ``SETUPCAM_WORKERS`` instead."""
    return settings if settings.search_threads else settings.model_copy(update={"search_threads": 1})


def run(args: argparse.Namespace) -> int:
    from app.config import Settings
    from app.logging_setup import configure_logging
    from app.services.events import EventBus
    from app.services.job_kinds import KINDS
    from app.services.jobs import JobContext, worker_name
    from app.store.db import make_engine
    from app.store.files import FileStoreError, open_file_store

    if args.concurrency < 1:
        print("setupcam worker: --concurrency must be 1 or more", file=sys.stderr)
        return 2
    if args.data_dir:
        os.environ["SETUPCAM_DATA_DIR"] = args.data_dir
    settings = worker_settings(Settings())
    configure_logging(settings.log_json)
    engine = make_engine(settings.database_url)
    why = wait_for_schema(engine, args.wait_schema_s)
    if why:
        print(f"setupcam worker: {why}", file=sys.stderr)
        return 1
    try:
        files = open_file_store(settings)
    except FileStoreError as exc:
        print(f"setupcam worker: file store: {exc}", file=sys.stderr)
        return 1
    events = EventBus(settings.webhooks, settings.mqtt_url, settings.mqtt_topic_prefix)
    ctx = JobContext(engine, files, settings, events)
    print(f"setupcam worker {worker_name()}: {engine.dialect.name}, files in {files.describe()}, "
          f"concurrency {args.concurrency}",
          file=sys.stderr, flush=True)
    try:
        if engine.dialect.name == "postgresql":
            run_procrastinate(ctx, KINDS, args.concurrency)
        else:
            run_polling(ctx, KINDS, args.concurrency)
    finally:
        events.close()
        engine.dispose()
    return 0


def wait_for_schema(engine, wait_s: float) -> str | None:
    """None once the ``job`` table exists (the service migrates; workers never do, so that two of them
    starting together cannot race on it); else the sentence why not."""
    from sqlalchemy import inspect

    deadline = time.monotonic() + wait_s
    while True:
        try:
            if inspect(engine).has_table("job"):
                return None
            said = "the database has no job table yet"
        except Exception as exc:  # noqa: BLE001 - any refusal becomes the sentence
            said = str(getattr(exc, "orig", None) or exc).strip().splitlines()[0][:300]
        if time.monotonic() > deadline:
            where = engine.url.render_as_string(hide_password=True)
            return f"{where}: {said} (start `setupcam serve` once: it creates the schema)"
        time.sleep(1.0)


def run_procrastinate(ctx, kinds, concurrency: int) -> None:
    import asyncio

    from app.services.jobs import worker_name
    from app.services.queues import run_procrastinate_worker

    asyncio.run(run_procrastinate_worker(ctx, kinds, concurrency=concurrency, name=worker_name(),
                                         install_signal_handlers=True))


def run_polling(ctx, kinds, concurrency: int) -> None:
    from app.services.queues import EmbeddedQueue

    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    queue = EmbeddedQueue(ctx, kinds, run_jobs=True, concurrency=concurrency)
    try:
        stop.wait()
    finally:
        queue.shutdown()
