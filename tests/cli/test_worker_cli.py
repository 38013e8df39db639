"""``setupcam worker``'s settings (app/cli/worker.py)."""

from __future__ import annotations

from app.cli.worker import worker_settings
from app.config import Settings
from app.services.setups import search_threads


def test_a_worker_process_searches_on_one_thread_unless_told(monkeypatch):
    monkeypatch.delenv("SETUPCAM_SEARCH_THREADS", raising=False)     # the suite's own (tests/conftest.py)
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1}, raising=False)
    assert search_threads(Settings()) == 2                       # the service's embedded worker: both cores
    assert search_threads(worker_settings(Settings())) == 1      # one of a worker per core
    monkeypatch.setenv("SETUPCAM_SEARCH_THREADS", "2")
    assert search_threads(worker_settings(Settings())) == 2      # told
