"""NC file dialects: exact text for a known offset, encode→decode round trips, conventions, FileController."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.machine.base import ControllerError, WorkOffset
from app.machine.nc_files import DIALECTS, FileController, NcFormatError, decode, encode, rounding

KNOWN = WorkOffset(12.3456, -3.25, 40.0, 1.5)


def _body(text: str) -> list[str]:
    """The lines that carry values (comments with the time stamp left out)."""
    return [l for l in text.splitlines() if l and not l.startswith(("(", ";", "1 ;", "2 ;")) and "UTC" not in l]


def test_linuxcnc_text():
    (f,) = encode("linuxcnc", "G55", KNOWN)
    assert f.name == "setupcam_G55.ngc"
    assert _body(f.text) == ["G21", "G10 L2 P2 X12.345600 Y-3.250000 Z40.000000 R1.500000", "M2"]


def test_fanuc_text():
    (f,) = encode("fanuc", "G54", KNOWN)
    assert f.name == "O9054.nc"
    assert "G10 L2 P1 X12.346 Y-3.250 Z40.000" in _body(f.text)  # always with a decimal point
    assert "G68 X0. Y0. R1.500" in _body(f.text)
    assert _body(f.text)[-2:] == ["M99", "%"]


def test_siemens_text():
    (f,) = encode("siemens", "G57", KNOWN)
    assert "$P_UIFR[4]=CTRANS(X,12.346,Y,-3.250,Z,40.000):CROT(Z,1.500)" in f.text
    assert "G710 ; metric, frames included" in f.text and "\nG57 ;" in f.text


def test_heidenhain_text():
    table, program = encode("heidenhain", "G56", KNOWN)
    assert table.name == "setupcam_G56.pr" and program.name == "SETUPCAM_G56.h"
    lines = table.text.splitlines()
    assert lines[0] == "BEGIN PRESET .PR MM" and lines[-1] == "[END]"
    assert lines[1].split() == ["NR", "DOC", "X", "Y", "Z", "ROT"]
    assert lines[2].split()[0] == "3" and lines[2].split()[-4:] == ["+12.3456", "-3.2500", "+40.0000", "+1.5000"]
    assert "CYCL DEF 247 DATUM SETTING ~\n  Q339=+3 ;DATUM NUMBER" in program.text


@pytest.mark.parametrize("dialect", DIALECTS)
def test_round_trip_within_resolution(dialect):
    rng = np.random.default_rng(0)
    half = rounding(dialect) / 2
    slots = ["G54", "G55", "G56", "G57"]
    for i in range(300):
        want = WorkOffset(*rng.uniform(-2000, 2000, 3), rng.uniform(-180, 180))
        slot = slots[i % 4]
        got_slot, got = decode(dialect, encode(dialect, slot, want)[0].text)
        assert got_slot == slot
        assert want.agrees_with(got, half, half), (dialect, want, got)


@pytest.mark.parametrize("dialect", DIALECTS)
def test_every_dialect_means_the_same_pose(dialect):
    """Sign convention: the decoded offset puts a program point where T_machine_datum does."""
    want = WorkOffset(100.0, 50.0, -20.0, 30.0)
    _, got = decode(dialect, encode(dialect, "G54", want)[0].text)
    p = np.array([10.0, 0.0, 0.0, 1.0])
    expect = [100 + 10 * math.cos(math.radians(30)), 50 + 10 * math.sin(math.radians(30)), -20.0]
    assert (got.to_pose() @ p)[:3] == pytest.approx(expect, abs=1e-9)


def test_angles_are_wrapped_and_minus_zero_is_not_written():
    (f,) = encode("fanuc", "G54", WorkOffset(-0.0001, 0, 0, 359.0))
    assert "X0.000" in f.text and "R-1.000" in f.text


def test_fanuc_numbers_without_decimal_point_are_micrometres():
    text = "G21 G90\nG10 L2 P1 X12500 Y-3.25 Z40.\nG68 X0 Y0 R1500\n"
    slot, got = decode("fanuc", text)
    assert slot == "G54" and got == WorkOffset(12.5, -3.25, 40.0, 1.5)


def test_fanuc_rotation_about_another_centre_moves_the_origin():
    # G68 about (10, 0) by 90°: the datum origin (0,0) lands at (10, -10) before the G54 shift
    slot, got = decode("fanuc", "G21 G90\nG10 L2 P1 X0. Y0. Z0.\nG54\nG68 X10. Y0. R90.\n")
    assert (got.x_mm, got.y_mm, got.c_deg) == pytest.approx((10.0, -10.0, 90.0))


def test_inch_files_are_converted():
    assert decode("linuxcnc", "G20\nG10 L2 P1 X1 Y2 Z-1 R5\n")[1] == WorkOffset(25.4, 50.8, -25.4, 5.0)
    got = decode("siemens", "G700\n$P_UIFR[1]=CTRANS(X,1,Y,0,Z,0)\n")[1]
    assert got.x_mm == pytest.approx(25.4)


def test_siemens_component_form():
    text = "$P_UIFR[2,X,TR]=1.5\n$P_UIFR[2,Y,TR]=-2\n$P_UIFR[2,Z,TR]=3\n$P_UIFR[2,Z,RT]=45\n"
    assert decode("siemens", text) == ("G55", WorkOffset(1.5, -2.0, 3.0, 45.0))


@pytest.mark.parametrize("dialect,text,match", [
    ("fanuc", "G91\nG10 L2 P1 X1. Y2. Z3.\n", "G91 adds to the offset"),
    ("fanuc", "G10 L2 X1. Y2. Z3.\n", "without P"),
    ("linuxcnc", "G10 L2 P1 X1 Y2\n", "does not set Z"),
    ("linuxcnc", "G0 X1\n", "no 'G10 L2"),
    ("siemens", "$P_UIFR[1]=CTRANS(X,1,Y,2,Z,3):CROT(X,5)\n", "rotations about X or Y"),
    ("siemens", "$P_UIFR[0]=CTRANS(X,1,Y,2,Z,3)\n", "not G54..G57"),
    ("heidenhain", "NR X Y Z\n", "not a HEIDENHAIN preset table"),
    ("heidenhain", "BEGIN PRESET .PR MM\nNR DOC X Y\n1 a +1 +2\n[END]\n", "no Z column"),
])
def test_bad_files_are_refused_with_the_reason(dialect, text, match):
    with pytest.raises(NcFormatError, match=match):
        decode(dialect, text)


def test_slots_a_dialect_cannot_hold_are_refused():
    with pytest.raises(ValueError, match="Fanuc G10 L2 takes P1..P6"):
        encode("fanuc", "G59.1", KNOWN)
    with pytest.raises(ValueError, match="G58/G59 are programmable offsets"):
        encode("siemens", "G58", KNOWN)
    with pytest.raises(ValueError, match="unknown NC dialect 'mazak'"):
        encode("mazak", "G54", KNOWN)


@pytest.mark.parametrize("dialect", DIALECTS)
def test_file_controller_writes_atomically_and_reads_back(tmp_path, dialect):
    c = FileController(dialect, tmp_path)
    with pytest.raises(ControllerError, match="no .* written yet for G54"):
        c.read_offset("G54")
    c.write_offset("G54", KNOWN)
    c.write_offset("G55", WorkOffset(1, 2, 3, 4))
    c.write_offset("G54", WorkOffset(5, 6, 7, -8))  # replaces the first file
    assert c.read_offset("G54").agrees_with(WorkOffset(5, 6, 7, -8), c.rounding_mm, c.rounding_deg)
    assert c.read_offset("G55").agrees_with(WorkOffset(1, 2, 3, 4), c.rounding_mm, c.rounding_deg)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert not [n for n in names if n.startswith(".setupcam-")]  # no temporary files left
    assert len(names) == 2 * len(encode(dialect, "G54", KNOWN))


def test_file_controller_refusals(tmp_path):
    c = FileController("linuxcnc", tmp_path / "not-mounted")
    with pytest.raises(ControllerError, match="folder does not exist"):
        c.write_offset("G54", KNOWN)
    c = FileController("linuxcnc", tmp_path)
    (tmp_path / "setupcam_G54.ngc").write_text("G0 X1\n")
    with pytest.raises(ControllerError, match="setupcam_G54.ngc is not readable: no 'G10 L2"):
        c.read_offset("G54")
    with pytest.raises(ControllerError, match="cannot pause"):
        c.pause()


def test_file_controller_cannot_read_the_position(tmp_path):
    from app.machine.base import PositionUnavailable

    with pytest.raises(PositionUnavailable, match="type the position the controller shows"):
        FileController("linuxcnc", tmp_path).read_position()
