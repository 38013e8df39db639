"""NC files carrying a work offset, for controllers without a live link: encode and decode.

One encoder and one decoder per dialect, so a test can show ``decode(encode(o)) == o`` within the
dialect's resolution. Conventions (docs/controller-conventions.md): every dialect here stores the
datum origin in machine coordinates (mm) and a rotation about machine Z (degrees, positive
counter-clockwise seen from +Z, about the datum origin), i.e. ``p_machine = Rz(C) p_program + (X, Y, Z)``:

* ``linuxcnc``  ``G10 L2 P<n> X Y Z R`` (n = 1..9 for G54..G59.3), program in G21 (mm).
* ``fanuc``     subprogram: ``G10 L2 P<n> X Y Z`` (n = 1..6 for G54..G59) + ``G54`` + ``G68 X0 Y0 R``
                (rotation about the datum origin; modal, so call it with M98 at the start of the job).
                Fanuc reads a number without a decimal point in least input increments (0.001 mm):
                the encoder always writes the point, the decoder honours the rule.
* ``siemens``   ``$P_UIFR[<n>]=CTRANS(X,..,Y,..,Z,..):CROT(Z,..)`` (n = 1..4 for G54..G57) under
                G710 (metric, including frames), then ``G54`` to activate.
* ``heidenhain`` a preset table row (``PRESET.PR``: NR, X, Y, Z, ROT = basic rotation) for preset
                n = 1..9, plus a program that activates it with ``CYCL DEF 247 DATUM SETTING Q339=n``.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from app.machine.base import (ControllerError, MachinePosition, NoOffsetYet, PositionUnavailable, WorkOffset, slot_name,
                              slot_number, wrap_deg)

DIALECTS = ("heidenhain", "fanuc", "siemens", "linuxcnc")

#: decimals written per dialect (mm and degrees): the usual input resolution of the control
DECIMALS = {"heidenhain": 4, "fanuc": 3, "siemens": 3, "linuxcnc": 6}
#: slots each dialect can hold
SLOTS = {
    "linuxcnc": ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"),
    "heidenhain": ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3"),
    "fanuc": ("G54", "G55", "G56", "G57", "G58", "G59"),
    "siemens": ("G54", "G55", "G56", "G57"),
}
_NOTES = {
    "fanuc": "Fanuc G10 L2 takes P1..P6 (G54..G59); G54.1 P.. extra offsets are not written here",
    "siemens": "Sinumerik settable frames G54..G57 are $P_UIFR[1..4]; G58/G59 are programmable offsets there",
}


class NcFormatError(ValueError):
    """A file that does not hold a work offset in the expected dialect; the message says what is wrong."""


@dataclass(frozen=True)
class NcFile:
    """One file to hand to the controller: suggested ``name`` and its ``text`` (ASCII, \\n line ends)."""

    name: str
    text: str


def rounding(dialect: str) -> float:
    """Resolution (mm and degrees) of values written in ``dialect``; read-back agrees within half of it."""
    return 10.0 ** -DECIMALS[_check_dialect(dialect)]


def _check_dialect(dialect: str) -> str:
    d = str(dialect).lower()
    if d not in DIALECTS:
        raise ValueError(f"unknown NC dialect {dialect!r}; use one of {', '.join(DIALECTS)}")
    return d


def _check_slot(dialect: str, slot: str) -> int:
    p = slot_number(slot)
    if slot.upper() not in SLOTS[dialect]:
        raise ValueError(f"{dialect} files cannot hold {slot}: {_NOTES.get(dialect, '')}; "
                         f"use one of {', '.join(SLOTS[dialect])}")
    return p


def _num(value: float, decimals: int, plus: bool = False) -> str:
    """Fixed-point text with ``decimals`` places; never "-0.000"; a leading "+" when ``plus``."""
    v = round(value, decimals)
    if v == 0:
        v = 0.0
    return f"{v:{'+' if plus else ''}.{decimals}f}"


def _comment_text(comment: str) -> str:
    """Comment text safe inside any dialect's comment (no brackets, semicolons or non-ASCII)."""
    return re.sub(r"[^A-Za-z0-9 .,:_/+-]", " ", comment).strip()[:60]


# --------------------------------------------------------------------------------- encoders --
def encode(dialect: str, slot: str, offset: WorkOffset, *, comment: str = "") -> list[NcFile]:
    """Files that set ``slot`` to ``offset`` on a ``dialect`` controller; the first one decodes back.

    Raises ValueError for an unknown dialect or a slot the dialect cannot hold.
    """
    d = _check_dialect(dialect)
    p = _check_slot(d, slot)
    n = DECIMALS[d]
    c = wrap_deg(offset.c_deg)
    note = _comment_text(comment or f"setupcam work offset {slot.upper()}")
    stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    x, y, z, r = (_num(v, n) for v in (offset.x_mm, offset.y_mm, offset.z_mm, c))
    s = slot.upper()
    if d == "linuxcnc":
        text = (f"({note})\n({stamp}; datum in machine coordinates, mm; R = rotation about Z, deg, CCW)\n"
                f"G21\nG10 L2 P{p} X{x} Y{y} Z{z} R{r}\nM2\n")
        return [NcFile(f"setupcam_{s}.ngc", text)]
    if d == "fanuc":
        prog = 9000 + 53 + p  # O9054 for G54 ...
        text = (f"%\nO{prog} ({note.upper()})\n({stamp})\n(CALL WITH M98 P{prog} AT THE START OF THE JOB)\n"
                f"G17 G21 G90\nG10 L2 P{p} X{x} Y{y} Z{z}\n{s}\nG68 X0. Y0. R{r}\n"
                "(G68 STAYS ACTIVE UNTIL G69 OR RESET)\nM99\n%\n")
        return [NcFile(f"O{prog}.nc", text)]
    if d == "siemens":
        text = (f"; {note}\n; {stamp}; datum in machine coordinates (mm), rotation about Z (deg, CCW)\n"
                f"G710 ; metric, frames included\n"
                f"$P_UIFR[{p}]=CTRANS(X,{x},Y,{y},Z,{z}):CROT(Z,{r})\n{s} ; activate the settable frame\nM17\n")
        return [NcFile(f"SETUPCAM_{s}.SPF", text)]
    # heidenhain
    hx, hy, hz, hr = (_num(v, n, plus=True) for v in (offset.x_mm, offset.y_mm, offset.z_mm, c))
    doc = _comment_text(note)[:16]
    table = ("BEGIN PRESET .PR MM\n"
             f"{'NR':<6}{'DOC':<18}{'X':<14}{'Y':<14}{'Z':<14}{'ROT':<14}\n"
             f"{p:<6}{doc:<18}{hx:<14}{hy:<14}{hz:<14}{hr:<14}\n"
             "[END]\n")
    pgm = f"SETUPCAM_{s.replace('.', '_')}"
    program = (f"0 BEGIN PGM {pgm} MM\n1 ; {note} ({stamp})\n"
               f"2 ; preset {p}: X{hx} Y{hy} Z{hz} ROT{hr} (load the row into PRESET.PR first)\n"
               f"3 CYCL DEF 247 DATUM SETTING ~\n  Q339=+{p} ;DATUM NUMBER\n4 END PGM {pgm} MM\n")
    return [NcFile(f"setupcam_{s.replace('.', '_')}.pr", table), NcFile(f"{pgm}.h", program)]


# --------------------------------------------------------------------------------- decoders --
_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)"


def _fanuc_value(text: str) -> float:
    """Fanuc: '12.5' is 12.5 mm; '12500' (no decimal point) is 12500 least increments = 12.5 mm."""
    return float(text) if "." in text else int(text) * 0.001


def _strip_comments(line: str, dialect: str) -> str:
    if dialect == "siemens":
        return line.split(";", 1)[0]
    if dialect == "heidenhain":
        return line.split(";", 1)[0]
    return re.sub(r"\([^)]*\)", " ", line).split(";", 1)[0]


def decode(dialect: str, text: str) -> tuple[str, WorkOffset]:
    """(slot, offset) held by ``text`` (the first file ``encode`` gives). Raises NcFormatError."""
    d = _check_dialect(dialect)
    lines = [_strip_comments(raw, d).strip().upper() for raw in text.splitlines()]
    if d in ("linuxcnc", "fanuc"):
        return _decode_g10(d, lines)
    if d == "siemens":
        return _decode_siemens(lines)
    return _decode_preset_table(lines)


def _words(line: str) -> dict[str, str]:
    return {m.group(1): m.group(2) for m in re.finditer(rf"([A-Z])\s*({_NUMBER})", line)}


def _decode_g10(d: str, lines: list[str]) -> tuple[str, WorkOffset]:
    scale, found, rot, rot_center, incremental = 1.0, None, 0.0, (0.0, 0.0), False
    value = _fanuc_value if d == "fanuc" else float
    for line in lines:
        if re.search(r"G20(?!\d)", line):
            scale = 25.4
        if re.search(r"G21(?!\d)", line):
            scale = 1.0
        if re.search(r"G90(?![.\d])", line):
            incremental = False
        if re.search(r"G91(?![.\d])", line):
            incremental = True
        if d == "fanuc" and incremental and "G10" in line:
            raise NcFormatError("G10 under G91 adds to the offset on Fanuc; this file is not an absolute work offset")
        if re.search(r"G10(?!\d)", line) and re.search(r"L0*2(?!\d)", line):
            w = _words(line.replace("G10", "").replace("L2", ""))
            if "P" not in w:
                raise NcFormatError(f"G10 L2 without P in {line!r}")
            missing = [a for a in "XYZ" if a not in w]
            if missing:
                raise NcFormatError(f"G10 L2 does not set {', '.join(missing)} in {line!r}")
            p = int(float(w["P"]))
            xyz = [value(w[a]) * scale for a in "XYZ"]
            r = float(w["R"]) if d == "linuxcnc" and "R" in w else 0.0
            found = (p, xyz, r)
        if d == "fanuc" and re.search(r"G68(?!\.)", line):
            w = _words(line.replace("G68", ""))
            if "R" not in w:
                raise NcFormatError(f"G68 without R in {line!r}")
            rot = _fanuc_value(w["R"])
            rot_center = (value(w.get("X", "0.")) * scale, value(w.get("Y", "0.")) * scale)
    if found is None:
        raise NcFormatError(f"no 'G10 L2 P.. X.. Y.. Z..' line in this {d} file")
    p, (x, y, z), r = found
    if d == "fanuc":
        # G68 about (cx, cy) of the work system: p_m = t + c + Rz(p - c)  ->  origin t + c - Rz c
        a = math.radians(rot)
        cx, cy = rot_center
        x += cx - (math.cos(a) * cx - math.sin(a) * cy)
        y += cy - (math.sin(a) * cx + math.cos(a) * cy)
        r = rot
    return slot_name(p), WorkOffset(x, y, z, r)


def _decode_siemens(lines: list[str]) -> tuple[str, WorkOffset]:
    metric = True
    result = None
    parts: dict[str, float] = {}
    frame_n = None
    for line in lines:
        if re.search(r"\bG70\b|\bG700\b", line):
            metric = False
        if re.search(r"\bG71\b|\bG710\b", line):
            metric = True
        m = re.match(r"\$P_UIFR\[\s*(\d+)\s*\]\s*=\s*(.+)$", line)
        if m:
            frame_n = int(m.group(1))
            expr = m.group(2).replace(" ", "")
            t = re.search(r"CTRANS\(([^)]*)\)", expr)
            if not t:
                raise NcFormatError(f"$P_UIFR[{frame_n}] is set without CTRANS in {line!r}")
            items = t.group(1).split(",")
            if len(items) % 2:
                raise NcFormatError(f"CTRANS needs axis,value pairs: {t.group(0)!r}")
            parts = {items[i]: float(items[i + 1]) for i in range(0, len(items), 2)}
            rot = re.search(r"CROT\(Z,(" + _NUMBER + r")\)", expr)
            if re.search(r"CROT\((?!Z,)", expr) or (re.search(r"CROT\(Z,[^)]*,", expr)):
                raise NcFormatError(f"rotations about X or Y cannot be a 3-axis work offset: {line!r}")
            parts["C"] = float(rot.group(1)) if rot else 0.0
            result = frame_n
            continue
        m = re.match(r"\$P_UIFR\[\s*(\d+)\s*,\s*([XYZ])\s*,\s*(TR|RT)\s*\]\s*=\s*(" + _NUMBER + r")$", line)
        if m:  # component form: $P_UIFR[1,X,TR]=12.5, $P_UIFR[1,Z,RT]=1.5
            frame_n = int(m.group(1))
            axis, comp, val = m.group(2), m.group(3), float(m.group(4))
            if comp == "RT" and axis != "Z":
                raise NcFormatError(f"rotation about {axis} cannot be a 3-axis work offset: {line!r}")
            parts["C" if comp == "RT" else axis] = val
            result = frame_n
    if result is None:
        raise NcFormatError("no '$P_UIFR[n]=CTRANS(...)' assignment in this Siemens file")
    if not 1 <= result <= 4:
        raise NcFormatError(f"$P_UIFR[{result}] is not G54..G57 (frames 1..4)")
    missing = [a for a in "XYZ" if a not in parts]
    if missing:
        raise NcFormatError(f"settable frame {result} does not set {', '.join(missing)}")
    k = 1.0 if metric else 25.4
    return slot_name(result), WorkOffset(parts["X"] * k, parts["Y"] * k, parts["Z"] * k, parts.get("C", 0.0))


def _decode_preset_table(lines: list[str]) -> tuple[str, WorkOffset]:
    head = next((i for i, l in enumerate(lines) if l.startswith("BEGIN") and ".PR" in l), None)
    if head is None:
        raise NcFormatError("no 'BEGIN ... .PR' line: not a HEIDENHAIN preset table")
    k = 25.4 if lines[head].split()[-1] == "INCH" else 1.0
    cols = lines[head + 1].split()
    for need in ("NR", "X", "Y", "Z"):
        if need not in cols:
            raise NcFormatError(f"preset table has no {need} column (columns: {' '.join(cols)})")
    rows = [l.split() for l in lines[head + 2:] if l and not l.startswith("[END]")]
    if len(rows) != 1:
        raise NcFormatError(f"expected one preset row, found {len(rows)}")
    row = rows[0]
    # DOC may be empty or hold spaces: read NR from the left, the numbers from the right
    numeric = cols[cols.index("DOC") + 1:] if "DOC" in cols else cols[1:]
    values = dict(zip(numeric, row[len(row) - len(numeric):]))
    try:
        p = int(row[0])
        x, y, z = (float(values[a]) * k for a in "XYZ")
        rot = float(values.get("ROT", "0"))
    except (ValueError, KeyError) as exc:
        raise NcFormatError(f"preset row is not readable: {' '.join(row)} ({exc})") from None
    if not 1 <= p <= 9:
        raise NcFormatError(f"preset {p} is not one of the rows 1..9 (G54..G59.3) setupcam writes")
    return slot_name(p), WorkOffset(x, y, z, rot)


# --------------------------------------------------------------------------- file controller --
class FileController:
    """'Controller' that drops NC files into a folder (a network share the control reads).

    ``write_offset`` writes the dialect's files atomically (temporary file + rename, so the control
    never sees half a file); ``read_offset`` decodes the file last written for that slot.
    """

    def __init__(self, dialect: str, folder: str | os.PathLike):
        self.dialect = _check_dialect(dialect)
        self.folder = Path(folder)
        self.rounding_mm = self.rounding_deg = rounding(self.dialect) / 2
        self.describe = f"{self.dialect} NC files in {self.folder}"

    def _fail(self, what: str) -> ControllerError:
        return ControllerError(f"{self.describe}: {what}")

    def files_for(self, slot: str, offset: WorkOffset) -> list[NcFile]:
        return encode(self.dialect, slot, offset)

    def write_offset(self, slot: str, offset: WorkOffset) -> None:
        files = self.files_for(slot, offset)
        if not self.folder.is_dir():
            raise self._fail("folder does not exist (or is not mounted)")
        for f in files:
            try:
                fd, tmp = tempfile.mkstemp(prefix=".setupcam-", dir=self.folder)
                with os.fdopen(fd, "w", newline="\n", encoding="ascii") as out:
                    out.write(f.text)
                    out.flush()
                    os.fsync(out.fileno())
                os.chmod(tmp, 0o644)
                os.replace(tmp, self.folder / f.name)
            except OSError as exc:
                raise self._fail(f"cannot write {f.name} ({exc.strerror or exc})") from None

    def read_offset(self, slot: str) -> WorkOffset:
        name = encode(self.dialect, slot, WorkOffset(0, 0, 0))[0].name
        path = self.folder / name
        try:
            text = path.read_text(encoding="ascii")
        except FileNotFoundError:
            raise NoOffsetYet(f"{self.describe}: no {name} written yet for {slot}") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise self._fail(f"cannot read {name} ({exc})") from None
        try:
            got_slot, offset = decode(self.dialect, text)
        except NcFormatError as exc:
            raise self._fail(f"{name} is not readable: {exc}") from None
        if got_slot != slot.upper():
            raise self._fail(f"{name} holds {got_slot}, not {slot}")
        return offset

    def read_position(self) -> MachinePosition:
        raise PositionUnavailable(f"{self.describe}: NC files in a folder are no live link, so the machine's "
                                  "position cannot be read here; type the position the controller shows")

    def read_axis_deg(self, name: str) -> float:
        raise PositionUnavailable(f"{self.describe}: NC files in a folder are no live link, so the {name} axis "
                                  "cannot be read here; set the machine's rotary axis to angle_from 'operator'")

    def pause(self) -> None:
        raise self._fail("a file drop cannot pause the machine")

    def stop(self) -> None:
        raise self._fail("a file drop cannot stop the machine")

    def close(self) -> None:
        pass
