"""Emitters of the detour subroutine (app/planning/detour_subroutine.py) and of the few blocks a
program around it needs, one per controller dialect. Conventions (docs/controller-conventions.md,
"The detour as a controller subroutine"):

==============  ===========================  ==============================  ===========================
dialect         subroutine                   call (target X, Y, Z)           start = current position
==============  ===========================  ==============================  ===========================
``linuxcnc``    ``o<setupcam_detour> sub``   ``o<setupcam_detour> call       ``#5420 #5421 #5422``
                (same file, before use)      [x] [y] [z]`` (#1 #2 #3)
``heidenhain``  ``LBL 100`` .. ``LBL 0``     ``FN 0: Q1/Q2/Q3 =`` then       ``FN 18: SYSREAD ID270 NR1``
                after the program's end      ``CALL LBL 100``
``fanuc``       macro B ``O9100`` .. M99     ``G65 P9100 X.. Y.. Z..``       ``#5001 #5002 #5003``
                (second program in the file) (#24 #25 #26)
``siemens``     ``PROC SC_DETOUR(REAL DT_TX, ``SC_DETOUR(x, y, z)``            ``$P_EP[X] [Y] [Z]``
                REAL DT_TY, REAL DT_TZ)``
                (own SPF in the tape file)
==============  ===========================  ==============================  ===========================

Numbers are written with :data:`DECIMALS` places; the scene is quantised to that before the
subroutine is built (:func:`quantise_inputs`), so the text holds exactly the numbers the Python
planner was given. Travel is rapid (G0 / FMAX) in exact-stop mode, so each corner is reached.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from app.planning.detour_subroutine import (
    Assign,
    Bin,
    BoxObstacles,
    Comment,
    DetourSubroutine,
    If,
    Move,
    Num,
    Pos,
    Var,
)
from app.planning.path import ProbeParams
from app.planning.reference import ReferenceOptions

DETOUR_DIALECTS = ("linuxcnc", "heidenhain", "fanuc", "siemens")
#: decimals written per dialect (mm): the usual input resolution of the control
DECIMALS = {"linuxcnc": 4, "heidenhain": 4, "fanuc": 3, "siemens": 3}
#: file name suffix of the downloaded program
SUFFIX = {"linuxcnc": ".ngc", "heidenhain": ".h", "fanuc": ".nc", "siemens": ".mpf"}
SUB_NAME = {"linuxcnc": "o<setupcam_detour>", "heidenhain": "LBL 100", "fanuc": "O9100", "siemens": "SC_DETOUR"}

_VARS = {
    "linuxcnc": {"TX": "#1", "TY": "#2", "TZ": "#3", **{n: f"#<{n.lower()}>" for n in
                                                       ("SX", "SY", "SZ", "LX", "HX", "LY", "HY", "H", "S")}},
    "heidenhain": {n: f"Q{k}" for k, n in enumerate(("TX", "TY", "TZ", "SX", "SY", "SZ", "LX", "HX", "LY", "HY",
                                                      "H", "S"), 1)},
    "fanuc": {"TX": "#24", "TY": "#25", "TZ": "#26", **{n: f"#{k}" for k, n in
                                                        enumerate(("SX", "SY", "SZ", "LX", "HX", "LY", "HY", "H",
                                                                   "S"), 1)}},
    "siemens": {n: f"DT_{n}" for n in ("TX", "TY", "TZ", "SX", "SY", "SZ", "LX", "HX", "LY", "HY", "H", "S")},
}
_POS = {"linuxcnc": ("#5420", "#5421", "#5422"), "fanuc": ("#5001", "#5002", "#5003"),
        "siemens": ("$P_EP[X]", "$P_EP[Y]", "$P_EP[Z]")}
_OPS = {"linuxcnc": {">=": "GE", "<=": "LE", ">": "GT", "<": "LT"},
        "fanuc": {">=": "GE", "<=": "LE", ">": "GT", "<": "LT"},
        "siemens": {">=": ">=", "<=": "<=", ">": ">", "<": "<"}}
_NEGATE = {">=": "<", "<=": ">", ">": "<=", "<": ">="}


def check_dialect(dialect: str) -> str:
    """The dialect in lower case, or ValueError naming the ones there are."""
    d = str(dialect).lower()
    if d in DETOUR_DIALECTS:
        return d
    raise ValueError(f"no detour subroutine for dialect {dialect!r}; use one of {', '.join(DETOUR_DIALECTS)}")


def num(dialect: str, v: float) -> str:
    """A number as ``dialect`` writes it: fixed decimals, never -0, Heidenhain with its sign."""
    n = DECIMALS[dialect]
    r = round(float(v), n)
    r = 0.0 if r == 0 else r
    return f"{r:{'+' if dialect == 'heidenhain' else ''}.{n}f}"


def _clean(text: str) -> str:
    """Comment text that cannot end a comment early in any dialect."""
    import re

    return re.sub(r"[^A-Za-z0-9 .,:_/+=#<>*-]", " ", str(text)).strip()[:120]


def comment(dialect: str, text: str) -> str:
    t = _clean(text)
    if dialect == "fanuc":
        return f"({t.upper()})"
    return f"({t})" if dialect == "linuxcnc" else f"; {t}"


# ----------------------------------------------------------------------------------- quantising


def _up(v: float, n: int) -> float:
    return float(np.ceil(float(v) * 10.0**n - 1e-6) / 10.0**n)


def quantise_inputs(dialect: str, boxes: BoxObstacles, probe: ProbeParams, options: ReferenceOptions
                    ) -> tuple[BoxObstacles, ProbeParams, ReferenceOptions]:
    """Scene, probe and options rounded to what ``dialect`` writes, never less safe: boxes and tops
    outward, clearance and margin up, working distance down. Build the subroutine and run the Python
    planner on these, and both see the same numbers."""
    n = DECIMALS[check_dialect(dialect)]
    wd = float(np.floor(probe.working_distance_mm * 10.0**n + 1e-6) / 10.0**n)
    p = replace(probe, clearance_mm=_up(probe.clearance_mm, n), working_distance_mm=max(wd, 0.0))
    return boxes.quantised(n), p, replace(options, box_margin_mm=_up(options.box_margin_mm, n))


def quantise_point(dialect: str, p) -> tuple[float, float, float]:
    """A target as the dialect writes it (mm)."""
    n = DECIMALS[check_dialect(dialect)]
    return tuple(float(round(float(v), n)) + 0.0 for v in np.asarray(p, dtype=float).reshape(3))


# ----------------------------------------------------------------------------------- statements


class _Writer:
    """Turns IR statements into lines of one dialect."""

    def __init__(self, dialect: str):
        self.d = dialect
        self.lines: list[str] = []
        self.label = 100  # jump labels / o-word numbers inside the subroutine

    def next_label(self) -> int:
        self.label += 1
        return self.label

    def op(self, e) -> str:
        if isinstance(e, Num):
            return num(self.d, e.value)
        if isinstance(e, Var):
            return ("+" if self.d == "heidenhain" else "") + _VARS[self.d][e.name]
        raise TypeError(f"not an operand: {e!r}")

    def assign(self, s: Assign) -> None:
        d, v, e = self.d, _VARS[self.d][s.var.name], s.expr
        if isinstance(e, Pos):
            i = "xyz".index(e.axis)
            self.lines.append(f"FN 18: SYSREAD {v} = ID270 NR1 IDX{i + 1}" if d == "heidenhain"
                              else f"{v}={_POS[d][i]}" if d in ("fanuc", "siemens") else f"{v} = {_POS[d][i]}")
        elif isinstance(e, Bin):
            a, b = self.op(e.a), self.op(e.b)
            if d == "heidenhain":
                self.lines.append(f"FN {1 if e.op == '+' else 2}: {v} = {a} {e.op} {b}")
            elif d == "linuxcnc":
                self.lines.append(f"{v} = [{a} {e.op} {b}]")
            else:
                self.lines.append(f"{v}={a}{e.op}{b}")
        else:
            rhs = self.op(e)
            self.lines.append(f"FN 0: {v} = {rhs}" if d == "heidenhain" else
                              f"{v} = {rhs}" if d == "linuxcnc" else f"{v}={rhs}")

    def move(self, s: Move) -> None:
        words = []
        for axis, c in zip("XYZ", (s.x, s.y, s.z)):
            if c is None:
                continue
            ref = _VARS[self.d][c.name]
            words.append(f"{axis}+{ref}" if self.d == "heidenhain" else f"{axis}={ref}" if self.d == "siemens"
                         else f"{axis}{ref}")
        if self.d == "heidenhain":
            self.lines.append(f"L {' '.join(words)} FMAX")
        else:
            self.lines.append(f"{'G00' if self.d == 'fanuc' else 'G0'} {' '.join(words)}")

    def structured_if(self, s: If) -> None:
        a, b = self.op(s.cond.a), self.op(s.cond.b)
        if self.d == "linuxcnc":
            n = self.next_label()
            self.lines.append(f"o{n} if [{a} {_OPS['linuxcnc'][s.cond.op]} {b}]")
            self.block(s.then)
            if s.orelse:
                self.lines.append(f"o{n} else")
                self.block(s.orelse)
            self.lines.append(f"o{n} endif")
        else:
            self.lines.append(f"IF {a}{_OPS['siemens'][s.cond.op]}{b}")
            self.block(s.then)
            if s.orelse:
                self.lines.append("ELSE")
                self.block(s.orelse)
            self.lines.append("ENDIF")

    def jump(self, op: str, a: str, b: str, label: int) -> None:
        """Jump to ``label`` when ``a op b`` (Heidenhain has only GT/LT; the caller picks them)."""
        if self.d == "heidenhain":
            fn = {">": 11, "<": 12}[op]
            self.lines.append(f"FN {fn}: IF {a} {'GT' if op == '>' else 'LT'} {b} GOTO LBL {label}")
        else:
            self.lines.append(f"IF [{a} {_OPS['fanuc'][op]} {b}] GOTO {label}")

    def goto(self, label: int) -> None:
        self.lines.append(f"FN 9: IF +0 EQU +0 GOTO LBL {label}" if self.d == "heidenhain" else f"GOTO {label}")

    def mark(self, label: int) -> None:
        self.lines.append(f"LBL {label}" if self.d == "heidenhain" else f"N{label}")

    def jump_if(self, s: If) -> None:
        """If/else with conditional jumps: jump past the then-block when the condition fails (GE/LE:
        the negation is LT/GT), or jump to the then-block when it holds (GT/LT)."""
        a, b = self.op(s.cond.a), self.op(s.cond.b)
        end = self.next_label()
        if s.cond.op in (">=", "<="):
            other = self.next_label()
            self.jump(_NEGATE[s.cond.op], a, b, other)
            self.block(s.then)
            if s.orelse:
                self.goto(end)
            self.mark(other)
            self.block(s.orelse)
        else:
            then = self.next_label()
            self.jump(s.cond.op, a, b, then)
            self.block(s.orelse)
            self.goto(end)
            self.mark(then)
            self.block(s.then)
        self.mark(end)

    def block(self, stmts) -> None:
        for s in stmts:
            if isinstance(s, Assign):
                self.assign(s)
            elif isinstance(s, Move):
                self.move(s)
            elif isinstance(s, Comment):
                self.lines.append(comment(self.d, s.text))
            elif isinstance(s, If):
                (self.structured_if if self.d in ("linuxcnc", "siemens") else self.jump_if)(s)
            else:
                raise TypeError(f"not a statement: {s!r}")


def emit_subroutine(dialect: str, sub: DetourSubroutine) -> list[str]:
    """The subroutine's lines in ``dialect`` (without Heidenhain block numbers)."""
    d = check_dialect(dialect)
    w = _Writer(d)
    about = (f"setupcam detour: reference method, {len(sub.boxes.boxes)} obstacle boxes baked in, "
             f"margin {sub.margin_mm:g} mm")
    if d == "linuxcnc":
        w.lines += [f"{SUB_NAME[d]} sub", comment(d, about), comment(d, "#1 #2 #3 = target X Y Z")]
    elif d == "heidenhain":
        w.lines += ["LBL 100", comment(d, about), comment(d, "Q1 Q2 Q3 = target X Y Z; uses Q4..Q12")]
    elif d == "fanuc":
        w.lines += ["O9100 (SETUPCAM DETOUR)", comment(d, about), comment(d, "X Y Z = TARGET, #24 #25 #26")]
    else:
        names = _VARS[d]
        w.lines += ["PROC SC_DETOUR(REAL DT_TX, REAL DT_TY, REAL DT_TZ)",
                    "DEF REAL " + ", ".join(names[n] for n in ("SX", "SY", "SZ", "LX", "HX", "LY", "HY", "H", "S")),
                    comment(d, about)]
    w.block(sub.body)
    w.lines.append({"linuxcnc": f"{SUB_NAME[d]} endsub", "heidenhain": "LBL 0", "fanuc": "M99",
                    "siemens": "M17"}[d])
    return w.lines


def emit_call(dialect: str, target) -> list[str]:
    """The lines that run the subroutine to ``target`` (program frame, mm)."""
    d = check_dialect(dialect)
    x, y, z = (num(d, v) for v in np.asarray(target, dtype=float).reshape(3))
    if d == "linuxcnc":
        return [f"{SUB_NAME[d]} call [{x}] [{y}] [{z}]"]
    if d == "heidenhain":
        return [f"FN 0: Q1 = {x}", f"FN 0: Q2 = {y}", f"FN 0: Q3 = {z}", "CALL LBL 100"]
    if d == "fanuc":
        return [f"G65 P9100 X{x} Y{y} Z{z}"]
    return [f"SC_DETOUR({x}, {y}, {z})"]


def emit_rapid(dialect: str, p, axes: str = "XYZ") -> str:
    """A rapid to ``p`` on the given axes."""
    d = check_dialect(dialect)
    words = [f"{a}{num(d, p['XYZ'.index(a)])}" for a in axes]
    return f"L {' '.join(words)} FMAX" if d == "heidenhain" else f"{'G00' if d == 'fanuc' else 'G0'} {' '.join(words)}"


def emit_feed(dialect: str, p, feed_mm_min: float, axes: str = "XYZ") -> str:
    """A straight feed move to ``p``."""
    d = check_dialect(dialect)
    words = [f"{a}{num(d, p['XYZ'.index(a)])}" for a in axes]
    f = f"F{feed_mm_min:.0f}"
    return f"L {' '.join(words)} {f}" if d == "heidenhain" else f"{'G01' if d == 'fanuc' else 'G1'} {' '.join(words)} {f}"


def assemble(dialect: str, name: str, main: list[str], sub: list[str]) -> str:
    """One file: the main program and the subroutine where the dialect looks for it.

    linuxcnc: ``%``, the subroutine first (defined before its calls), the main program, ``%``.
    heidenhain: ``BEGIN PGM`` .. main .. ``M30``, the LBL after it, ``END PGM``, blocks numbered.
    fanuc: ``%``, main program ``O1000`` .. ``M30``, macro ``O9100`` .. ``M99``, ``%`` (one file of two
    programs, as a DNC or card load stores them). siemens: punched-tape format, the PROC as its own
    ``%_N_SC_DETOUR_SPF`` (in ``/_N_SPF_DIR``) followed by the main ``%_N_<NAME>_MPF``.
    """
    d = check_dialect(dialect)
    pgm = "".join(c for c in name.upper() if c.isalnum() or c == "_")[:24] or "SETUPCAM_PROBE"
    if d == "linuxcnc":
        return "\n".join(["%", *sub, *main, "M2", "%"]) + "\n"
    if d == "heidenhain":
        body = [f"BEGIN PGM {pgm} MM", *main, "M30", *sub, f"END PGM {pgm} MM"]
        out, k = [], 0
        for line in body:  # a continuation line (indented) belongs to the block above: no number
            if line.startswith(" "):
                out.append(line)
            else:
                out.append(f"{k} {line}")
                k += 1
        return "\n".join(out) + "\n"
    if d == "fanuc":
        return "\n".join(["%", f"O1000 ({pgm})", *main, "M30", *sub, "%"]) + "\n"
    return "\n".join([f"%_N_{SUB_NAME[d]}_SPF", ";$PATH=/_N_SPF_DIR", *sub,
                      f"%_N_{pgm}_MPF", ";$PATH=/_N_MPF_DIR", *main, "M30"]) + "\n"


__all__ = [
    "DECIMALS",
    "DETOUR_DIALECTS",
    "SUB_NAME",
    "SUFFIX",
    "assemble",
    "check_dialect",
    "comment",
    "emit_call",
    "emit_feed",
    "emit_rapid",
    "emit_subroutine",
    "num",
    "quantise_inputs",
    "quantise_point",
]
