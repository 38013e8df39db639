"""How a setup job shares the machine's cores (app/services/setups.py)."""

from __future__ import annotations

import os

from app.config import Settings
from app.services.setups import search_threads


def test_a_setup_job_searches_on_its_share_of_the_cores_or_as_told(monkeypatch):
    monkeypatch.delenv("SETUPCAM_SEARCH_THREADS", raising=False)     # the suite's own (tests/conftest.py)
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    assert search_threads(Settings(workers=1)) == 4            # one job at a time: every core
    assert search_threads(Settings(workers=2)) == 2
    assert search_threads(Settings(workers=8)) == 1            # never none
    assert search_threads(Settings(workers=1, search_threads=1)) == 1     # told: as told
    monkeypatch.setenv("SETUPCAM_SEARCH_THREADS", "3")
    assert search_threads(Settings()) == 3
