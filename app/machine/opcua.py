"""OPC UA adapter (asyncua client): write X, Y, Z, C variables or call a vendor method, read back.

There is no standard OPC UA node for *setting* a work offset (OPC 40502 CNC only reports the
active axis ``ZeroOffset``, without rotation; OPC 40501 Machine Tools has none), so the node ids
come from the machine's settings. Node ids may contain ``{slot}`` ("G54") and ``{p}`` (1..9)
placeholders so that one setting covers all slots, e.g. ``"ns=2;s={slot}.X"``; without placeholders
only the configured ``slot`` may be written. Values are taken to be mm and degrees, rotation C
counter-clockwise about machine Z (our convention); vendors that differ need a sign/scale in front.

Each call opens its own session and closes it (the interface is synchronous; asyncua's coroutines run
under ``asyncio.run`` in the caller's thread, or in a helper thread when that thread already runs a loop).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import math
from dataclasses import dataclass, field

from app.machine.base import ControllerError, MachinePosition, PositionUnavailable, WorkOffset, slot_number

AXES = ("x", "y", "z", "c")


@dataclass(frozen=True)
class OpcUaMethod:
    """A method to call instead of writing variables: ``object`` and ``method`` node ids and the
    input arguments in order, each one of "slot" (String "G54"), "p" (Int32 1..9), "x", "y", "z", "c" (Double)."""

    object: str
    method: str
    args: tuple[str, ...] = ("x", "y", "z", "c")


@dataclass(frozen=True)
class OpcUaSettings:
    endpoint: str
    nodes: dict[str, str | None] = field(default_factory=dict)  # x, y, z, c (c may be None: no rotation)
    method: OpcUaMethod | None = None
    slot: str = "G54"  # the only slot when the node ids carry no {slot}/{p} placeholder
    timeout_s: float = 5.0
    rounding_mm: float = 1e-6
    rounding_deg: float = 1e-6
    username: str | None = None
    password: str | None = None
    pause_method: OpcUaMethod | None = None  # called without arguments (args ignored)
    stop_method: OpcUaMethod | None = None
    # x, y, z of the tool tip in machine coordinates (mm), e.g. OPC 40502 CNC axes' ActPos; None: not offered
    position_nodes: dict[str, str] | None = None


def _run(coro):
    """Run a coroutine to the end from synchronous code, even when this thread runs an event loop."""
    try:
        asyncio.get_running_loop()
    except RuntimeError:
        return asyncio.run(coro)
    with concurrent.futures.ThreadPoolExecutor(max_workers=1) as pool:
        return pool.submit(asyncio.run, coro).result()


class OpcUaController:
    """Controller adapter for an OPC UA server (see module docstring)."""

    def __init__(self, settings: OpcUaSettings):
        self.settings = settings
        self.rounding_mm = settings.rounding_mm
        self.rounding_deg = settings.rounding_deg
        self.describe = f"OPC UA server at {settings.endpoint}"
        self._closed = False

    def _fail(self, what: str) -> ControllerError:
        return ControllerError(f"{self.describe}: {what}")

    def _node_ids(self, slot: str) -> dict[str, str | None]:
        p = slot_number(slot)
        ids = {a: self.settings.nodes.get(a) for a in AXES}
        templated = any(v and ("{slot}" in v or "{p}" in v) for v in ids.values())
        if not templated and slot.upper() != self.settings.slot.upper():
            raise self._fail(f"only slot {self.settings.slot} is configured (node ids without {{slot}}), "
                             f"cannot use {slot}")
        return {a: (v.format(slot=slot.upper(), p=p) if v else None) for a, v in ids.items()}

    # -- asyncio core -----------------------------------------------------------------------------
    async def _with_client(self, work, writing: str = ""):
        from asyncua import Client, ua  # imported here: the service starts without asyncua loaded

        client = Client(self.settings.endpoint, timeout=self.settings.timeout_s)
        if self.settings.username:
            client.set_user(self.settings.username)
            client.set_password(self.settings.password or "")
        try:
            await asyncio.wait_for(client.connect(), self.settings.timeout_s)
        except ConnectionRefusedError:
            raise self._fail("connection refused") from None
        except (asyncio.TimeoutError, TimeoutError):
            raise self._fail(f"no connection within {self.settings.timeout_s:g} s") from None
        except OSError as exc:
            raise self._fail(f"cannot connect ({exc.strerror or exc})") from None
        except ua.UaError as exc:
            raise self._fail(f"connection refused by the server ({exc})") from None
        try:
            return await work(client, ua)
        except ControllerError:
            raise
        except ua.UaStatusCodeError as exc:
            raise self._fail(f"{type(exc).__name__} ({exc})") from None
        except (OSError, ConnectionError, asyncio.TimeoutError, TimeoutError, ua.UaError) as exc:
            what = "no answer" if isinstance(exc, (asyncio.TimeoutError, TimeoutError)) else "connection lost"
            if writing:
                raise self._fail(f"{what} while writing {writing}; the offset may or may not have changed: "
                                 "read it back before trusting it") from None
            raise self._fail(f"{what} ({type(exc).__name__})") from None
        finally:
            try:
                await asyncio.wait_for(client.disconnect(), 2.0)
            except Exception:  # noqa: BLE001 - the server may be gone already
                pass

    async def _read(self, client, ua, ids: dict[str, str | None]) -> WorkOffset:
        values = await self._read_numbers(client, ua, ids)
        return WorkOffset(values["x"], values["y"], values["z"], values.get("c", 0.0))

    async def _read_numbers(self, client, ua, ids: dict[str, str | None]) -> dict[str, float]:
        """The finite numbers held by the node ids present in ``ids`` (keys among x, y, z, c)."""
        present = [a for a in AXES if ids.get(a)]
        nodes = [client.get_node(ids[a]) for a in present]
        dvs = await client.read_attributes(nodes, ua.AttributeIds.Value)
        values = {}
        for a, dv in zip(present, dvs):
            if not dv.StatusCode.is_good():
                raise self._fail(f"reading {ids[a]} failed ({dv.StatusCode.name})")
            v = dv.Value.Value if dv.Value is not None else None
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise self._fail(f"{ids[a]} holds {v!r}, not a number")
            values[a] = float(v)
        return values

    # -- Controller interface ---------------------------------------------------------------------
    def read_offset(self, slot: str) -> WorkOffset:
        ids = self._node_ids(slot)
        if self._closed:
            raise self._fail("adapter already closed")
        return _run(self._with_client(lambda client, ua: self._read(client, ua, ids)))

    def read_position(self) -> MachinePosition:
        ids = self.settings.position_nodes
        if not ids:
            raise PositionUnavailable(f"{self.describe}: no position nodes are configured (settings: position_nodes "
                                      "with x, y, z node ids of the tool tip in machine coordinates); type the "
                                      "position the controller shows")
        if self._closed:
            raise self._fail("adapter already closed")
        values = _run(self._with_client(lambda client, ua: self._read_numbers(client, ua, ids)))
        return MachinePosition(values["x"], values["y"], values["z"])

    def read_axis_deg(self, name: str) -> float:
        raise PositionUnavailable(f"{self.describe}: reading the {name} axis over OPC UA is not supported; "
                                  "set the machine's rotary axis to angle_from 'operator' and type the angle")

    def write_offset(self, slot: str, offset: WorkOffset) -> None:
        ids = self._node_ids(slot)
        if self._closed:
            raise self._fail("adapter already closed")
        if not ids.get("c") and abs(offset.c_deg) > self.rounding_deg:
            raise self._fail(f"no node for the rotation C is configured, cannot write C = {offset.c_deg:.4f}°")
        values = {"x": offset.x_mm, "y": offset.y_mm, "z": offset.z_mm, "c": offset.c_deg}
        label = f"{slot} ({offset})"
        if self.settings.method is not None:
            work = lambda client, ua: self._call_method(client, ua, slot, values)  # noqa: E731
        else:
            work = lambda client, ua: self._write_nodes(client, ua, ids, values)  # noqa: E731
        _run(self._with_client(work, writing=label))

    async def _call_method(self, client, ua, slot: str, values: dict[str, float]) -> None:
        m = self.settings.method
        args = []
        for name in m.args:
            if name == "slot":
                args.append(ua.Variant(slot.upper(), ua.VariantType.String))
            elif name == "p":
                args.append(ua.Variant(slot_number(slot), ua.VariantType.Int32))
            else:
                args.append(ua.Variant(float(values[name]), ua.VariantType.Double))
        result = await client.get_node(m.object).call_method(ua.NodeId.from_string(m.method), *args)
        if result is False:
            raise self._fail(f"method {m.method} answered False for {slot}")

    async def _write_nodes(self, client, ua, ids: dict[str, str | None], values: dict[str, float]) -> None:
        present = [a for a in AXES if ids[a]]
        nodes = [client.get_node(ids[a]) for a in present]
        # keep each node's own numeric type (Double or Float) and remember the old values for a rollback
        before = await client.read_attributes(nodes, ua.AttributeIds.Value)
        dvs = []
        for a, dv in zip(present, before):
            vtype = dv.Value.VariantType if dv.Value is not None else ua.VariantType.Double
            if vtype not in (ua.VariantType.Double, ua.VariantType.Float):
                raise self._fail(f"{ids[a]} is of type {vtype.name}, expected Double or Float")
            dvs.append(ua.DataValue(ua.Variant(float(values[a]), vtype)))
        results = await client.uaclient.write_attributes([n.nodeid for n in nodes], dvs, ua.AttributeIds.Value)
        bad = [(a, r) for a, r in zip(present, results) if not r.is_good()]
        if not bad:
            return
        done = [(n, dv.Value) for (a, r), n, dv in zip(zip(present, results), nodes, before) if r.is_good()]
        restored = "nothing else was written"
        if done:
            back = await client.uaclient.write_attributes(
                [n.nodeid for n, _ in done], [ua.DataValue(v) for _, v in done], ua.AttributeIds.Value)
            restored = ("the other values were restored" if all(r.is_good() for r in back)
                        else "restoring the other values FAILED: check the controller")
        refused = ", ".join(f"{ids[a]} ({r.name})" for a, r in bad)
        raise self._fail(f"the server refused {refused}; {restored}")

    def _call_plain(self, m: OpcUaMethod | None, what: str) -> None:
        if m is None:
            raise self._fail(f"{what} is not configured for this OPC UA machine (settings: {what}_method)")
        if self._closed:
            raise self._fail("adapter already closed")

        async def work(client, ua):
            if await client.get_node(m.object).call_method(ua.NodeId.from_string(m.method)) is False:
                raise self._fail(f"method {m.method} answered False")

        _run(self._with_client(work))

    def pause(self) -> None:
        self._call_plain(self.settings.pause_method, "pause")

    def stop(self) -> None:
        self._call_plain(self.settings.stop_method, "stop")

    def close(self) -> None:
        self._closed = True
