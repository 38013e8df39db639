"""Shared test fixtures.

Real outside data lives in ``../shared/data/external`` beside the checkout (CI has it too); tests read
it from there and never copy it into the repo.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

# The suite runs on two xdist workers of a 2-core machine beside the LinuxCNC sim, whose simulated probe
# trips late when the cores are oversubscribed (a touch 0.095 mm long in a run where setup jobs searched
# on both cores): the services the tests start search on one thread, as the engine does by default;
# tests/jobs/test_service_jobs.py runs one setup on two (SETUPCAM_SEARCH_THREADS, services/setups.py).
os.environ.setdefault("SETUPCAM_SEARCH_THREADS", "1")

REPO_ROOT = Path(__file__).resolve().parent.parent
EXTERNAL_DATA = (REPO_ROOT.parent / "shared" / "data" / "external").resolve()


@pytest.fixture(scope="session")
def external_data() -> Path:
    """Folder of real third-party data (calibration images, CAD parts); see its SOURCES.md."""
    if not EXTERNAL_DATA.is_dir():
        pytest.fail(f"external test data missing: expected {EXTERNAL_DATA} (../shared beside the clone)")
    return EXTERNAL_DATA


# -- pytest-xdist (``make test`` runs ``-n 2 --dist loadgroup``) -----------------------------------------
LINUXCNC_GROUP = "linuxcnc"


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(config, items):
    """Every test marked ``linuxcnc`` goes to one xdist worker: LinuxCNC runs once per computer, and the
    process that started the sim keeps it, and its session lock, until it exits (linuxcnc_sim.py), so a
    second worker asking for it would wait for the lock and fail."""
    for item in items:  # before xdist's own hook reads the xdist_group marks
        if item.get_closest_marker("linuxcnc"):
            item.add_marker(pytest.mark.xdist_group(LINUXCNC_GROUP))
    result = yield
    if getattr(config.option, "loadgroup", False):  # an xdist worker under --dist loadgroup
        for item in items:
            if item.get_closest_marker("linuxcnc"):
                _join_group(item)
    return result


def _join_group(item: pytest.Item) -> None:
    """Give ``item`` the ``@group`` nodeid suffix by which xdist's loadgroup scheduler groups tests.
    pytest-xdist 3.8 writes it to ``item._nodeid``, which pytest 9.2 no longer reads (structured node
    ids; pytest-dev/pytest-xdist#1386), so the grouping silently stopped: set it the way pytest 9.2
    keeps it, and refuse to run rather than let two workers fight over the sim."""
    suffix = f"@{LINUXCNC_GROUP}"
    if not item.nodeid.endswith(suffix) and hasattr(item, "_id"):
        from _pytest.nodeid import NodeId

        item._id = NodeId.parse(item.nodeid + suffix)
    if not item.nodeid.endswith(suffix):
        raise pytest.UsageError(f"pytest-xdist did not put {item.nodeid} in the {LINUXCNC_GROUP!r} group "
                                "(this pytest and pytest-xdist do not work together); run with -n 0")


@pytest.hookimpl(tryfirst=True)  # before the test's fixtures are set up
def pytest_runtest_setup(item):
    """Tell linuxcnc_sim whether the test about to run may start the sim (see ``shared_sim``)."""
    from tests.machine import linuxcnc_sim

    linuxcnc_sim.CALLER_MARKED = item.get_closest_marker("linuxcnc") is not None
