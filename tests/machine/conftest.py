"""Fixtures for controller tests: one simulated LinuxCNC per test process (one instance per
computer is all LinuxCNC allows), started from a fresh config folder (see linuxcnc_sim.py)."""

from __future__ import annotations

import pytest

from tests.machine.linuxcnc_sim import SimError, shared_sim, skip_reason


@pytest.fixture(scope="session")
def linuxcnc_sim():
    """A running, homed, powered LinuxCNC sim (mm, XYZ, linuxcncrsh on a free port of 127.0.0.1).

    Skips with the reason when LinuxCNC is not installed. ``sim.settings`` is the machine's
    controller settings dict; ``sim.read_slot("G54")`` reads LinuxCNC's own status independently.
    """
    why = skip_reason()
    if why:
        pytest.skip(why)
    try:
        return shared_sim()  # one instance per test process, stopped at exit
    except SimError as exc:
        pytest.fail(f"LinuxCNC sim did not start: {exc}")
