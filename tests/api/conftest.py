"""API tests run against a real server over HTTP, once on SQLite and once on PostgreSQL."""

from __future__ import annotations

import pytest

from tests.support.live_server import live_server, postgres_unavailable_reason


@pytest.fixture(scope="session", params=["sqlite", "postgres"])
def server(request, tmp_path_factory):
    if request.param == "postgres":
        reason = postgres_unavailable_reason()
        if reason:
            pytest.skip(reason)
    with live_server(tmp_path_factory.mktemp(f"data-{request.param}"), request.param,
                     max_upload_mb=5, max_mesh_faces=50_000) as srv:
        yield srv


@pytest.fixture()
def client(server):
    with server.client() as c:
        yield c


@pytest.fixture(scope="module")
def lcnc():
    """The process's LinuxCNC sim (tests/machine/linuxcnc_sim.py); skips with the reason when absent."""
    from tests.machine.linuxcnc_sim import shared_sim, skip_reason

    why = skip_reason()
    if why:
        pytest.skip(why)
    return shared_sim()
