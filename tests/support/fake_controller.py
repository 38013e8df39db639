"""A controller in memory for tests of the write and export rules that need no LinuxCNC, and a way to
put it behind a machine of the live test server (which runs in this process)."""

from __future__ import annotations

import contextlib
import threading
from typing import Iterator

from app.machine import NoOffsetYet, WorkOffset


class FakeController:
    """Slots in memory; ``journal`` lists the calls, ``fail`` makes a call ("read", "write") raise,
    ``drift_mm`` shifts what a write stores in X (a controller that rounds or clamps differently)."""

    rounding_mm, rounding_deg, describe = 0.001, 0.001, "fake controller"

    def __init__(self, slots=None, fail: dict | None = None, drift_mm: float = 0.0):
        self.slots = dict(slots or {})
        self.fail = dict(fail or {})
        self.drift_mm = drift_mm
        self.journal: list[str] = []

    def _maybe_fail(self, what: str) -> None:
        exc = self.fail.get(what)
        if exc is not None:
            raise exc

    def read_offset(self, slot: str) -> WorkOffset:
        self.journal.append(f"read {slot}")
        self._maybe_fail("read")
        if slot not in self.slots:
            raise NoOffsetYet(f"fake controller holds no {slot} yet")
        return self.slots[slot]

    def write_offset(self, slot: str, offset: WorkOffset) -> None:
        self.journal.append(f"write {slot}")
        self.slots[slot] = WorkOffset(offset.x_mm + self.drift_mm, offset.y_mm, offset.z_mm, offset.c_deg)
        self._maybe_fail("write")  # after storing: the write arrived, its answer was lost

    def close(self) -> None:
        self.journal.append("close")

    @property
    def writes(self) -> list[str]:
        return [j for j in self.journal if j.startswith("write")]


class FakeControllers:
    """Fakes behind machines: a machine whose controller settings are ``settings(name)`` (a file drop
    into a folder that does not exist) gets the fake registered under that name instead."""

    PREFIX = "/nonexistent/fake-controller/"

    def __init__(self):
        self.fakes: dict[str, FakeController] = {}
        self._lock = threading.Lock()

    def settings(self, name: str) -> dict:
        return {"kind": "file", "dialect": "linuxcnc", "folder": self.PREFIX + name}

    def add(self, name: str, fake: FakeController) -> dict:
        with self._lock:
            self.fakes[name] = fake
        return self.settings(name)

    def factory(self, real):
        def make_controller(settings):
            folder = str(settings.get("folder", "")) if isinstance(settings, dict) else ""
            if folder.startswith(self.PREFIX):
                return self.fakes[folder.removeprefix(self.PREFIX)]
            return real(settings)

        return make_controller


@contextlib.contextmanager
def fake_controllers(monkeypatch) -> Iterator[FakeControllers]:
    """Every place the service opens a controller asks the registry first (the live server shares
    this process, so patching the module attributes reaches it)."""
    from app.services import controller_write, export

    fakes = FakeControllers()
    monkeypatch.setattr(controller_write, "make_controller", fakes.factory(controller_write.make_controller))
    monkeypatch.setattr(export, "make_controller", fakes.factory(export.make_controller))
    yield fakes
