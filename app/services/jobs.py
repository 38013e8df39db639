"""The embedded job queue: worker threads in the service process.

Job functions take plain arguments (ids) plus a :class:`JobContext` (engine, file store, settings)
and touch no web or global state, so moving them to Celery/Dramatiq workers later is a matter of
configuration, not of rewriting them.
"""

from __future__ import annotations

import logging
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Callable

from sqlalchemy.engine import Engine

from app.config import Settings
from app.store.files import FileStore

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JobContext:
    engine: Engine
    files: FileStore
    settings: Settings
    events: Any = None  # app.services.events.EventBus


class JobRunner:
    def __init__(self, ctx: JobContext, workers: int = 1):
        self.ctx = ctx
        self._pool = ThreadPoolExecutor(max_workers=max(1, workers), thread_name_prefix="setupcam-job")
        self._stopped = False

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        def run() -> Any:
            try:
                return fn(self.ctx, *args)
            except Exception:  # the job records its own failure; this is the last net
                log.exception("job crashed", extra={"job": getattr(fn, "__name__", str(fn)), "args": args})
                raise

        return self._pool.submit(run)

    def alive(self) -> bool:
        """True while jobs are taken (False once shut down)."""
        return not self._stopped

    def shutdown(self) -> None:
        self._stopped = True
        self._pool.shutdown(wait=False, cancel_futures=True)
