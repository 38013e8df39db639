"""The LinuxCNC adapter (linuxcncrsh over TCP) against a real simulated LinuxCNC.

Every write is checked with LinuxCNC's own status read through its Python module in a child
process (tests/machine/lcnc_child.py), not through the adapter.
"""

from __future__ import annotations

import math
import socket
import threading
import time

import numpy as np
import pytest

from app.machine.base import ControllerError, MachinePosition, WorkOffset
from app.machine.linuxcnc import LinuxCncController

pytestmark = [pytest.mark.integration, pytest.mark.linuxcnc]


@pytest.fixture
def controller(linuxcnc_sim):
    c = LinuxCncController(linuxcnc_sim.host, linuxcnc_sim.port)
    yield c
    c.close()


def _assert_status_matches(status: dict, offset: WorkOffset, c: LinuxCncController) -> float:
    got = WorkOffset(*status["g5x_offset"], status["rotation_xy"])
    assert offset.agrees_with(got, c.rounding_mm, c.rounding_deg), (offset, got)
    return max(offset.difference(got))


def test_write_g54_and_read_back_independently(linuxcnc_sim, controller):
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(3):
        x, y, z = rng.uniform(-400, 400, 3)
        c_deg = rng.uniform(-179, 179)
        want = WorkOffset(x, y, z, c_deg)
        controller.write_offset("G54", want)
        status = linuxcnc_sim.read_slot("G54")
        assert status["g5x_index"] == 1
        worst = max(worst, _assert_status_matches(status, want, controller))
        # the adapter's own read-back agrees too
        assert want.agrees_with(controller.read_offset("G54"), controller.rounding_mm, controller.rounding_deg)
    assert worst <= 5e-7  # values are written with 6 decimals


def test_slots_are_independent(linuxcnc_sim, controller):
    g54 = WorkOffset(1.5, 2.5, 3.5, 4.5)
    g59_3 = WorkOffset(-11.0, 22.0, -33.0, -44.0)
    controller.write_offset("G54", g54)
    controller.write_offset("G59.3", g59_3)
    _assert_status_matches(linuxcnc_sim.read_slot("G59.3"), g59_3, controller)
    _assert_status_matches(linuxcnc_sim.read_slot("G54"), g54, controller)
    assert controller.read_offset("G59.3") == g59_3


def test_rotation_sign_matches_our_c(linuxcnc_sim, controller):
    """A program point p lands at Rz(C) p + (X, Y, Z) in machine coordinates (DESIGN's T_machine_datum)."""
    offset = WorkOffset(10.0, 20.0, -5.0, 30.0)
    controller.write_offset("G54", offset)
    status = linuxcnc_sim.mdi("G54 G0 X5 Y2 Z1")
    expect = offset.to_pose() @ np.array([5.0, 2.0, 1.0, 1.0])
    assert status["position"] == pytest.approx(expect[:3].tolist(), abs=1e-6)
    linuxcnc_sim.mdi("G53 G0 X0 Y0 Z0")


def _settled(sim, target_mm, tol_mm: float = 1e-4, timeout_s: float = 2.0) -> None:
    """Wait until the sim's actual position is within ``tol_mm`` of ``target_mm``; fail after ``timeout_s``."""
    end = time.monotonic() + timeout_s
    while True:
        pos = sim.status()["actual_position"]
        if np.allclose(pos[:3], target_mm, atol=tol_mm) or time.monotonic() > end:
            break
        time.sleep(0.02)
    assert pos[:3] == pytest.approx(target_mm, abs=tol_mm)


def test_read_position_is_the_tool_tip_in_machine_coordinates(linuxcnc_sim, controller):
    """Jogged (G53 moves by MDI) to a point, the adapter reads LinuxCNC's actual position; with a tool
    length offset active (G43.1) it reports the tip, not the spindle; G5x offsets do not matter."""
    try:
        linuxcnc_sim.mdi("G10 L2 P1 X100 Y50 Z-5 R10")   # a rotated work offset must not leak into the answer
        linuxcnc_sim.mdi("G54")
        linuxcnc_sim.mdi("G53 G0 X-123.4567 Y211.25 Z-40.125")
        # the feedback trails the commanded end by a few servo periods on a busy machine (0.3 um seen)
        _settled(linuxcnc_sim, [-123.4567, 211.25, -40.125])
        got = controller.read_position()
        assert isinstance(got, MachinePosition)
        assert (got.x_mm, got.y_mm, got.z_mm) == pytest.approx((-123.4567, 211.25, -40.125), abs=1e-4)
        assert got.tool_offset_mm == pytest.approx((0.0, 0.0, 0.0), abs=1e-4)
        status = linuxcnc_sim.mdi("G43.1 Z52.5")
        assert status["tool_offset"][2] == pytest.approx(52.5)
        got = controller.read_position()
        assert (got.x_mm, got.y_mm, got.z_mm) == pytest.approx((-123.4567, 211.25, -40.125 - 52.5), abs=1e-4)
        assert got.tool_offset_mm == pytest.approx((0.0, 0.0, 52.5), abs=1e-4)
        st = linuxcnc_sim.mdi("G92 X1 Y2 Z3")           # a G92 offset changes nothing either
        assert st["g92_offset"] != [0.0, 0.0, 0.0]
        again = controller.read_position()
        assert (again.x_mm, again.y_mm, again.z_mm) == pytest.approx((got.x_mm, got.y_mm, got.z_mm), abs=1e-6)
        assert linuxcnc_sim.status()["actual_position"] == pytest.approx([-123.4567, 211.25, -40.125], abs=1e-4)
    finally:
        linuxcnc_sim.mdi("G92.1")
        linuxcnc_sim.mdi("G49")
        linuxcnc_sim.mdi("G10 L2 P1 X0 Y0 Z0 R0")
        linuxcnc_sim.mdi("G53 G0 X0 Y0 Z0")


def test_pause_and_stop_a_running_program(linuxcnc_sim, controller):
    linuxcnc_sim.mdi("G53 G0 X0 Y0 Z0")
    before = WorkOffset(7.0, 8.0, 9.0, 0.0)
    controller.write_offset("G54", before)
    linuxcnc_sim.run_program("G54 G90 G21\nG1 X200 F600\nG1 X0\nM2\n")
    # a running program blocks any offset change
    with pytest.raises(ControllerError, match="a program is running"):
        controller.write_offset("G54", WorkOffset(0, 0, 0, 0))

    controller.pause()
    time.sleep(0.3)
    s1 = linuxcnc_sim.status()
    time.sleep(0.3)
    s2 = linuxcnc_sim.status()
    assert s1["paused"] or s1["interp_paused"]
    assert s2["position"] == s1["position"]            # nothing moves while paused
    assert 0 < s2["position"][0] < 200 - 7.0
    with pytest.raises(ControllerError, match="a program is paused"):
        controller.write_offset("G54", WorkOffset(0, 0, 0, 0))

    controller.stop()
    deadline = time.monotonic() + 5
    while not linuxcnc_sim.status()["interp_idle"] and time.monotonic() < deadline:
        time.sleep(0.05)
    s3 = linuxcnc_sim.status()
    assert s3["interp_idle"] and not s3["paused"]
    _assert_status_matches(linuxcnc_sim.read_slot("G54"), before, controller)  # untouched by the refusals


def test_controller_errors_are_reported_with_linuxcnc_text(linuxcnc_sim, controller):
    # a G10 the interpreter refuses: arc-style word not allowed; LinuxCNC's own message comes back
    s = controller._session()
    try:
        controller._prepare_mdi(s, "test")
        with pytest.raises(ControllerError, match=r"'G10 L2 P10 X1' was refused: P value out of range"):
            controller._mdi(s, "G10 L2 P10 X1")
    finally:
        s.close()


def test_unknown_slot_is_a_value_error(controller):
    with pytest.raises(ValueError, match="unknown work offset slot 'G60'"):
        controller.write_offset("G60", WorkOffset(0, 0, 0))


def test_unreachable_controller_is_refused_with_a_sentence():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    c = LinuxCncController("127.0.0.1", port, timeout_s=1)
    with pytest.raises(ControllerError) as err:
        c.write_offset("G54", WorkOffset(1, 2, 3, 4))
    assert str(err.value).startswith(f"LinuxCNC at 127.0.0.1:{port}: connection refused")


def _fake_rsh_server(drop_on: str):
    """A linuxcncrsh look-alike that answers like the real one and drops the link at ``drop_on``."""
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    seen: list[str] = []

    def serve():
        conn, _ = srv.accept()
        f = conn.makefile("rb")
        answers = {"hello": "HELLO ACK EMCNETSVR 1.1\r\n", "set echo": "set echo off\r\n",
                   "get estop": "ESTOP OFF\r\n", "get machine": "MACHINE ON\r\n",
                   "get program_status": "PROGRAM_STATUS IDLE\r\n", "get program_linear_units": "PROGRAM_UNITS MM\r\n",
                   "get mode": "MODE MDI\r\n"}
        for raw in f:
            line = raw.decode().strip()
            seen.append(line)
            if line.startswith(drop_on):
                break
            reply = next((v for k, v in answers.items() if line.startswith(k)), None)
            if reply is None and line.startswith("set "):
                reply = f"SET {line.split()[1].upper()} ACK\n\r"
            conn.sendall((reply or "ERROR\r\n").encode())
        conn.close()
        srv.close()

    threading.Thread(target=serve, daemon=True).start()
    return srv.getsockname()[1], seen


def test_link_lost_mid_write_says_the_offset_is_uncertain():
    port, seen = _fake_rsh_server(drop_on="set mdi G10")
    c = LinuxCncController("127.0.0.1", port, timeout_s=2)
    with pytest.raises(ControllerError, match=r"connection lost after sending 'G10 L2 P1 X1\.000000 Y2\.000000 "
                                              r"Z3\.000000 R4\.500000'; the offset may or may not have changed"):
        c.write_offset("G54", WorkOffset(1, 2, 3, 4.5))
    assert any(line.startswith("set mdi G10 L2 P1") for line in seen)
    assert math.isclose(c.rounding_mm, 1e-6)


def test_missing_linuxcnc_gives_a_skip_message(monkeypatch):
    from tests.machine import linuxcnc_sim

    monkeypatch.setattr(linuxcnc_sim.shutil, "which", lambda name: None)
    assert "LinuxCNC is not installed: run scripts/install-linuxcnc.sh" in linuxcnc_sim.skip_reason()
