"""The OPC UA adapter against a real asyncua server (tests/machine/opcua_sim.py in a child process).

Read-back is checked with a plain asyncua client, not with the adapter's own read.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from app.machine.base import ControllerError, MachinePosition, PositionUnavailable, WorkOffset
from app.machine.settings import make_controller

pytestmark = pytest.mark.integration
SIM = Path(__file__).resolve().parent / "opcua_sim.py"


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class OpcUaSim:
    """One opcua_sim.py child process; ``start()`` returns at once, ``wait_ready()`` blocks for READY."""

    def __init__(self, *flags: str):
        self.port = _free_port()
        self.endpoint = f"opc.tcp://127.0.0.1:{self.port}/setupcam-test/"
        self.t0 = time.monotonic()
        self.proc = subprocess.Popen([sys.executable, str(SIM), str(self.port), *flags],
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)

    def wait_ready(self) -> "OpcUaSim":
        line = self.proc.stdout.readline()  # blocks until READY (or EOF if it died)
        if not line.startswith("READY"):
            self.stop()
            raise RuntimeError(f"OPC UA test server did not start (rc={self.proc.returncode})")
        self.startup_s = time.monotonic() - self.t0
        return self

    def read(self, node_ids: list[str]) -> list:
        """Independent read with asyncua's sync client."""
        from asyncua.sync import Client

        with Client(self.endpoint, timeout=5) as c:
            return [c.get_node(n).read_value() for n in node_ids]

    def write(self, values: dict[str, float]) -> None:
        """Independent write of Double variables (e.g. "jog" the position nodes)."""
        from asyncua import ua
        from asyncua.sync import Client

        with Client(self.endpoint, timeout=5) as c:
            for node, value in values.items():
                c.get_node(node).write_value(ua.Variant(float(value), ua.VariantType.Double))

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


@pytest.fixture(scope="module")
def servers():
    """The normal server and one that dies on the first Write, started side by side (start-up
    of asyncua's Server.init() dominates: ~1.2 s idle, several seconds on a busy machine)."""
    sims = {"ok": OpcUaSim(), "dying": OpcUaSim("--die-on-write")}
    try:
        for sim in sims.values():
            sim.wait_ready()
        yield sims
    finally:
        for sim in sims.values():
            sim.stop()


@pytest.fixture
def opcua_sim(servers):
    return servers["ok"]


def _settings(sim: OpcUaSim, **extra) -> dict:
    return {"kind": "opcua", "endpoint": sim.endpoint,
            "nodes": {a: f"ns=2;s={{slot}}.{a.upper()}" for a in "xyzc"}, **extra}


def _ids(slot: str) -> list[str]:
    return [f"ns=2;s={slot}.{a}" for a in "XYZC"]


def test_write_nodes_and_read_back_independently(opcua_sim):
    c = make_controller(_settings(opcua_sim))
    want = WorkOffset(123.456789012345, -3.25, 40.0, -17.123456789)
    c.write_offset("G55", want)
    got = opcua_sim.read(_ids("G55"))
    assert got == [want.x_mm, want.y_mm, want.z_mm, want.c_deg]  # Double nodes: bit-exact
    assert c.read_offset("G55") == want
    assert opcua_sim.read(_ids("G54")) == [0.0, 0.0, 0.0, 0.0]  # other slots untouched


def test_method_call_and_read_back(opcua_sim):
    c = make_controller(_settings(opcua_sim, method={
        "object": "ns=2;s=MachineTool", "method": "ns=2;s=SetWorkOffset", "args": ["slot", "x", "y", "z", "c"]}))
    want = WorkOffset(1.5, 2.5, -3.5, 90.0)
    c.write_offset("G57", want)
    assert opcua_sim.read(_ids("G57")) == [1.5, 2.5, -3.5, 90.0]
    assert c.read_offset("G57") == want


def test_float_nodes_round_to_single_precision(opcua_sim):
    s = _settings(opcua_sim, rounding_mm=1e-4, rounding_deg=1e-5, slot="G54")
    s["nodes"] = {a: f"ns=2;s=G54F.{a.upper()}" for a in "xyzc"}
    c = make_controller(s)
    want = WorkOffset(1234.56789, -0.1, 40.0, 1.23456789)
    c.write_offset("G54", want)
    got = c.read_offset("G54")
    d_mm, d_deg = want.difference(got)
    assert 0 < d_mm < 1e-4 and d_deg < 1e-6  # float32 keeps ~7 significant digits
    assert want.agrees_with(got, c.rounding_mm, c.rounding_deg)
    with pytest.raises(ControllerError, match="only slot G54 is configured"):
        c.write_offset("G55", want)


def test_a_refused_value_rolls_the_others_back(opcua_sim):
    c = make_controller(_settings(opcua_sim))
    before = opcua_sim.read(_ids("G59"))
    with pytest.raises(ControllerError, match=r"the server refused ns=2;s=G59\.C \(Bad\w+\); the other values were restored"):
        c.write_offset("G59", WorkOffset(9, 9, 9, 9))
    assert opcua_sim.read(_ids("G59")) == before


def test_pause_and_stop_methods(opcua_sim):
    plain = make_controller(_settings(opcua_sim))
    with pytest.raises(ControllerError, match="pause is not configured"):
        plain.pause()
    c = make_controller(_settings(opcua_sim,
                                  pause_method={"object": "ns=2;s=MachineTool", "method": "ns=2;s=Pause"},
                                  stop_method={"object": "ns=2;s=MachineTool", "method": "ns=2;s=Stop"}))
    c.pause()
    assert opcua_sim.read(["ns=2;s=ProgramState"]) == ["paused"]
    c.stop()
    assert opcua_sim.read(["ns=2;s=ProgramState"]) == ["stopped"]


def test_rotation_without_a_c_node_is_refused(opcua_sim):
    s = _settings(opcua_sim)
    s["nodes"].pop("c")
    c = make_controller(s)
    with pytest.raises(ControllerError, match="no node for the rotation C is configured, cannot write C = 2.0000°"):
        c.write_offset("G56", WorkOffset(1, 2, 3, 2.0))
    c.write_offset("G56", WorkOffset(1, 2, 3, 0.0))
    assert opcua_sim.read(_ids("G56"))[:3] == [1.0, 2.0, 3.0]


def test_unknown_node_is_reported(opcua_sim):
    s = _settings(opcua_sim)
    s["nodes"]["x"] = "ns=2;s=NoSuchNode"
    with pytest.raises(ControllerError, match=r"reading ns=2;s=NoSuchNode failed \(BadNodeIdUnknown\)"):
        make_controller(s).read_offset("G54")


def test_server_down_before_the_write_is_refused():
    port = _free_port()
    c = make_controller({"kind": "opcua", "endpoint": f"opc.tcp://127.0.0.1:{port}/x/", "timeout_s": 2,
                         "nodes": {"x": "ns=2;s=X", "y": "ns=2;s=Y", "z": "ns=2;s=Z"}})
    with pytest.raises(ControllerError, match=rf"^OPC UA server at opc.tcp://127.0.0.1:{port}/x/: connection refused"):
        c.write_offset("G54", WorkOffset(1, 2, 3))


def test_server_down_mid_write_says_the_offset_is_uncertain(servers):
    sim = servers["dying"]
    c = make_controller(_settings(sim, timeout_s=3))
    t0 = time.monotonic()
    with pytest.raises(ControllerError, match=r"while writing G54 \(X\+1\.0000 .*\); the offset may or may "
                                              r"not have changed: read it back"):
        c.write_offset("G54", WorkOffset(1, 2, 3, 4))
    assert time.monotonic() - t0 < 10
    assert sim.proc.wait(timeout=5) == 3  # the server really died in the write
    with pytest.raises(ControllerError, match="connection refused"):
        c.read_offset("G54")


def test_usable_from_inside_a_running_event_loop(opcua_sim):
    """The service may call the synchronous interface from async code (FastAPI): no 'loop running' error."""
    import asyncio

    c = make_controller(_settings(opcua_sim))

    async def from_async():
        c.write_offset("G58", WorkOffset(4, 5, 6, 7))
        return c.read_offset("G58")

    assert asyncio.run(from_async()) == WorkOffset(4, 5, 6, 7)


def test_position_is_read_from_the_configured_nodes(opcua_sim):
    opcua_sim.write({"ns=2;s=Position.X": 312.125, "ns=2;s=Position.Y": -40.5, "ns=2;s=Position.Z": -287.75})
    c = make_controller(_settings(opcua_sim, position_nodes={a: f"ns=2;s=Position.{a.upper()}" for a in "xyz"}))
    assert c.read_position() == MachinePosition(312.125, -40.5, -287.75)


def test_position_without_nodes_is_unavailable_with_the_setting_to_add(opcua_sim):
    with pytest.raises(PositionUnavailable, match="no position nodes are configured.*position_nodes"):
        make_controller(_settings(opcua_sim)).read_position()
