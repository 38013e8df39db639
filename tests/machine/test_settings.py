"""Controller settings validation and the factory."""

from __future__ import annotations

import pytest
from pydantic import TypeAdapter

from app.machine.base import Controller, WorkOffset, slot_name, slot_number, wrap_deg
from app.machine.linuxcnc import LinuxCncController
from app.machine.nc_files import FileController
from app.machine.opcua import OpcUaController
from app.machine.settings import ControllerSettings, OpcUaControllerSettings, make_controller, parse_controller_settings

NODES = {"x": "ns=2;s={slot}.X", "y": "ns=2;s={slot}.Y", "z": "ns=2;s={slot}.Z", "c": "ns=2;s={slot}.C"}


def test_each_kind_makes_its_adapter(tmp_path):
    lc = make_controller({"kind": "linuxcnc", "host": "10.0.0.7", "port": 5007})
    assert isinstance(lc, LinuxCncController) and lc.describe == "LinuxCNC at 10.0.0.7:5007"
    op = make_controller({"kind": "opcua", "endpoint": "opc.tcp://10.0.0.8:4840", "nodes": NODES})
    assert isinstance(op, OpcUaController) and op.describe == "OPC UA server at opc.tcp://10.0.0.8:4840"
    fc = make_controller({"kind": "file", "dialect": "siemens", "folder": str(tmp_path)})
    assert isinstance(fc, FileController) and fc.rounding_mm == pytest.approx(0.0005)
    for c in (lc, op, fc):
        assert isinstance(c, Controller)


@pytest.mark.parametrize("settings,reason", [
    ({"host": "x"}, "kind must be one of linuxcnc, opcua, file, got None"),
    ({"kind": "fanuc-focas"}, "got 'fanuc-focas'"),
    ({"kind": "linuxcnc"}, "linuxcnc controller settings are not valid: host: Field required"),
    ({"kind": "linuxcnc", "host": "a", "port": 70000}, "port: Input should be less than or equal to 65535"),
    ({"kind": "linuxcnc", "host": "a", "passwd": "x"}, "passwd: Extra inputs are not permitted"),
    ({"kind": "opcua", "endpoint": "http://a", "nodes": NODES}, "endpoint: String should match pattern"),
    ({"kind": "opcua", "endpoint": "opc.tcp://a", "nodes": {"x": "X", "y": "ns=2;s=Y", "z": "ns=2;s=Z"}},
     "nodes.x: String should match pattern"),
    ({"kind": "opcua", "endpoint": "opc.tcp://a", "nodes": NODES, "slot": "G60"}, "unknown work offset slot 'G60'"),
    ({"kind": "opcua", "endpoint": "opc.tcp://a", "nodes": NODES,
      "method": {"object": "ns=2;s=M", "method": "ns=2;s=F", "args": ["slot", "x", "y"]}},
     "method args must include x, y and z; missing z"),
    ({"kind": "file", "dialect": "okuma", "folder": "/x"}, "dialect: Input should be 'heidenhain', 'fanuc'"),
    ("linuxcnc", "controller settings must be an object, got str"),
])
def test_invalid_settings_say_why(settings, reason):
    with pytest.raises(ValueError) as err:
        make_controller(settings)
    assert reason in str(err.value)


def test_models_are_usable_by_the_api():
    model = parse_controller_settings({"kind": "opcua", "endpoint": "opc.tcp://a:4840", "nodes": NODES, "slot": "g55"})
    assert isinstance(model, OpcUaControllerSettings) and model.slot == "G55"
    assert make_controller(model).settings.slot == "G55"
    # the OpenAPI schema the API publishes: one object per kind, chosen by "kind"
    schema = TypeAdapter(ControllerSettings).json_schema()
    assert set(schema["discriminator"]["mapping"]) == {"linuxcnc", "opcua", "file"}


def test_slots_and_offsets():
    assert [slot_number(s) for s in ("G54", "g59", "G59.3")] == [1, 6, 9]
    assert slot_name(7) == "G59.1"
    with pytest.raises(ValueError, match="use one of G54, G55"):
        slot_number("G53")
    assert wrap_deg(190) == -170 and wrap_deg(-180) == 180 and wrap_deg(540) == 180
    o = WorkOffset(1, 2, 3, 179.9999995)
    assert o.agrees_with(WorkOffset(1.0000004, 2, 3, -179.9999999), 5e-7, 1e-6)
    assert not o.agrees_with(WorkOffset(1.000002, 2, 3, 180), 1e-6, 1e-6)
    with pytest.raises(ValueError, match="x_mm must be a finite number"):
        WorkOffset(float("nan"), 0, 0)


def test_only_linuxcnc_reads_a_rotary_axis(tmp_path):
    """A file drop and an OPC UA server say why they cannot tell the axis (the machine then takes the angle
    from the operator); LinuxCNC refuses a name that is no rotary axis before connecting (reading it on an
    XYZC sim: tests/e2e/test_rotary_table_sim.py)."""
    from app.machine.base import PositionUnavailable

    with pytest.raises(PositionUnavailable, match="C axis cannot be read here"):
        make_controller({"kind": "file", "dialect": "linuxcnc", "folder": str(tmp_path)}).read_axis_deg("C")
    with pytest.raises(PositionUnavailable, match="angle_from 'operator'"):
        make_controller({"kind": "opcua", "endpoint": "opc.tcp://127.0.0.1:4840", "nodes": NODES}).read_axis_deg("C")
    with pytest.raises(ValueError, match="A, B or C"):
        make_controller({"kind": "linuxcnc", "host": "127.0.0.1", "port": 1}).read_axis_deg("X")
