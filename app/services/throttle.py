"""Sign-in throttling: after ``free`` failures for one user name or one address, every further
attempt waits, and the wait doubles with each failure (``window_s``, 2 x, 4 x ... up to ``max_delay_s``).

Kept in the service process (a restart forgets it; with several service processes each counts its own),
which is what a panel-PC service needs: it stops password guessing at the speed of HTTP.
"""

from __future__ import annotations

import threading
import time
from collections import deque


class LoginThrottle:
    """Failure times per key ("user:anna", "addr:10.0.0.5"); ``wait_s`` says how long a key must wait."""

    def __init__(self, free: int = 5, window_s: float = 60.0, max_delay_s: float = 900.0,
                 memory_s: float = 3600.0, clock=time.monotonic):
        self.free, self.window_s, self.max_delay_s, self.memory_s = free, window_s, max_delay_s, memory_s
        self.clock = clock
        self._failures: dict[str, deque[float]] = {}
        self._lock = threading.Lock()

    def _recent(self, key: str, now: float) -> deque[float]:
        q = self._failures.get(key, deque())
        while q and now - q[0] > self.memory_s:
            q.popleft()
        return q

    def wait_s(self, *keys: str) -> float:
        """Seconds until the next attempt is allowed for all ``keys`` (0: now)."""
        now = self.clock()
        wait = 0.0
        with self._lock:
            for key in keys:
                q = self._recent(key, now)
                if len(q) >= self.free:
                    delay = min(self.max_delay_s, self.window_s * 2 ** (len(q) - self.free))
                    if len(q) == self.free and now - q[0] > self.window_s:
                        delay = 0.0  # the free failures were spread over more than the window
                    wait = max(wait, q[-1] + delay - now)
        return max(0.0, wait)

    def failed(self, *keys: str) -> None:
        now = self.clock()
        with self._lock:
            for key in keys:
                q = self._recent(key, now)
                q.append(now)
                self._failures[key] = q
            if len(self._failures) > 100_000:  # a flood of made-up names must not grow without bound
                for key in [k for k, q in self._failures.items() if not q or now - q[-1] > self.memory_s]:
                    del self._failures[key]

    def succeeded(self, *keys: str) -> None:
        with self._lock:
            for key in keys:
                self._failures.pop(key, None)
