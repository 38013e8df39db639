"""A small 'machine tool' OPC UA server for tests (asyncua), run as a child process.

Address space (namespace ``urn:setupcam:test:machine``, index 2):
  Objects/MachineTool/WorkOffsets/<slot>/{X,Y,Z,C}  Double, writable, node ids ``ns=2;s=<slot>.<axis>``
      for slot G54..G59; ``ns=2;s=G59.C`` is read-only (a controller that refuses one value).
  Objects/MachineTool/SetWorkOffset(Slot: String, X, Y, Z, C: Double) -> Ok: Boolean
      node id ``ns=2;s=SetWorkOffset`` on object ``ns=2;s=MachineTool``.
  ``ns=2;s=G54F.{X,Y,Z,C}``  Float (single precision) variables, to show float rounding.
  Objects/MachineTool/Position/{X,Y,Z}  Double, writable (a test "jogs" by writing them), node ids
      ``ns=2;s=Position.<axis>``: the tool tip in machine coordinates, mm.
  Objects/MachineTool/Pause(), Stop() -> Ok set ``ns=2;s=ProgramState`` to "paused" / "stopped".

Usage: python opcua_sim.py PORT [--die-on-write]
Prints ``READY <port>`` once listening. ``--die-on-write``: the process exits hard (no answer) as
soon as a client's Write request arrives: a controller that goes down in the middle of a write.
"""

import asyncio
import logging
import os
import sys

from asyncua import Server, ua, uamethod
from asyncua.common.callback import CallbackType

URI = "urn:setupcam:test:machine"
SLOTS = ["G54", "G55", "G56", "G57", "G58", "G59"]


async def main(port: int, die_on_write: bool) -> None:
    logging.basicConfig(level=logging.ERROR)
    server = Server()
    await server.init()
    server.set_endpoint(f"opc.tcp://127.0.0.1:{port}/setupcam-test/")
    server.set_server_name("setupcam test machine tool")
    server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
    idx = await server.register_namespace(URI)
    mt = await server.nodes.objects.add_object(ua.NodeId("MachineTool", idx), ua.QualifiedName("MachineTool", idx))
    wos = await mt.add_object(ua.NodeId("WorkOffsets", idx), ua.QualifiedName("WorkOffsets", idx))
    nodes = {}
    for slot in SLOTS:
        obj = await wos.add_object(ua.NodeId(f"{slot}", idx), ua.QualifiedName(slot, idx))
        for axis in "XYZC":
            v = await obj.add_variable(ua.NodeId(f"{slot}.{axis}", idx), ua.QualifiedName(axis, idx), 0.0,
                                       varianttype=ua.VariantType.Double)
            if (slot, axis) != ("G59", "C"):
                await v.set_writable()
            nodes[(slot, axis)] = v
    fobj = await wos.add_object(ua.NodeId("G54F", idx), ua.QualifiedName("G54F", idx))
    for axis in "XYZC":
        v = await fobj.add_variable(ua.NodeId(f"G54F.{axis}", idx), ua.QualifiedName(axis, idx),
                                    ua.Variant(0.0, ua.VariantType.Float))
        await v.set_writable()

    pos = await mt.add_object(ua.NodeId("Position", idx), ua.QualifiedName("Position", idx))
    for axis in "XYZ":
        v = await pos.add_variable(ua.NodeId(f"Position.{axis}", idx), ua.QualifiedName(axis, idx), 0.0,
                                   varianttype=ua.VariantType.Double)
        await v.set_writable()

    @uamethod
    async def set_work_offset(parent, slot, x, y, z, c):
        if slot not in SLOTS:
            raise ua.UaStatusCodeError(ua.StatusCodes.BadInvalidArgument)
        for axis, val in zip("XYZC", (x, y, z, c)):
            await nodes[(slot, axis)].write_value(ua.Variant(float(val), ua.VariantType.Double))
        return True

    args_in = [ua.Argument(Name="Slot", DataType=ua.NodeId(ua.ObjectIds.String), ValueRank=-1)] + [
        ua.Argument(Name=n, DataType=ua.NodeId(ua.ObjectIds.Double), ValueRank=-1) for n in "XYZC"]
    args_out = [ua.Argument(Name="Ok", DataType=ua.NodeId(ua.ObjectIds.Boolean), ValueRank=-1)]
    await mt.add_method(ua.NodeId("SetWorkOffset", idx), ua.QualifiedName("SetWorkOffset", idx),
                        set_work_offset, args_in, args_out)

    state = await mt.add_variable(ua.NodeId("ProgramState", idx), ua.QualifiedName("ProgramState", idx), "running")

    @uamethod
    async def pause(parent):
        await state.write_value("paused")
        return True

    @uamethod
    async def stop(parent):
        await state.write_value("stopped")
        return True

    for name, fn in (("Pause", pause), ("Stop", stop)):
        await mt.add_method(ua.NodeId(name, idx), ua.QualifiedName(name, idx), fn, [], args_out)

    if die_on_write:
        async def die(event, dispatcher):
            if event.is_external:  # a client's Write request (the server's own writes also pass here)
                os._exit(3)  # gone without an answer, like a controller switched off mid-write

        server.subscribe_server_callback(CallbackType.PreWrite, die)

    async with server:
        print(f"READY {port}", flush=True)
        while True:
            await asyncio.sleep(3600)


if __name__ == "__main__":
    asyncio.run(main(int(sys.argv[1]), "--die-on-write" in sys.argv[2:]))
