"""One BLAS thread for the engine.

The engine's linear algebra is many small products (n x 3 points times a 3 x 3 rotation, 6 x 6
solves), where OpenBLAS's worker threads cost more than they give; on a 2-core machine shared with
other jobs they spin against them (measured here under load: a 130 000 x 3 @ 3 x 3 product took
10 ms on one thread and 30 to 160 ms on the default two). The engine's entry points run with BLAS
limited to one thread; the limit is restored when they return.
"""

from __future__ import annotations

import functools
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
