"""One BLAS thread for the engine, and how many cores this process may use.

The engine's linear algebra is many small products (n x 3 points times a 3 x 3 rotation, 6 x 6
solves), where OpenBLAS's worker threads cost more than they give; on a 2-core machine shared with
other jobs they spin against them (measured here under load: a 130 000 x 3 @ 3 x 3 product took
10 ms on one thread and 30 to 160 ms on the default two). The engine's entry points run with BLAS
limited to one thread; the limit is restored when they return.
"""

from __future__ import annotations

import functools
import os
from typing import Callable, TypeVar

from threadpoolctl import threadpool_limits

F = TypeVar("F", bound=Callable)


def one_blas_thread(fn: F) -> F:
    """Decorator: run ``fn`` with BLAS limited to one thread (threadpoolctl)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity where the system tells it, else all)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


def cores_per_job(jobs: int = 1) -> int:
    """Threads each of ``jobs`` jobs run at once may use: this process's cores shared out, at least one."""
    return max(1, available_cores() // max(int(jobs), 1))
