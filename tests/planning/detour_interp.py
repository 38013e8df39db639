"""Small interpreters of the subset of each dialect that app/planning/detour_emit.py and
detour_program.py write: parse the text back and run it, so a test can compare the points a
controller would reach with the Python planner's path (as app/machine/nc_files.py's decoders do for
work offsets). Written from the controllers' manuals, independently of the emitters' code.

``run(dialect, text, start)`` -> list of (kind, (x, y, z)) for every motion block in execution order,
kind "rapid", "feed" or "probe" (a probe move is taken to reach its target; HEIDENHAIN's cycle 4
returns to where it started). Anything outside the subset raises ValueError naming the line.
"""

from __future__ import annotations

import re

NUM = r"[+-]?(?:\d+\.?\d*|\.\d+)"


def _expr(text: str, lookup, ops: dict[str, str], line: str) -> float | bool:
    """Evaluate an expression of numbers, references, + - and comparisons (tokens checked first)."""
    tokens = re.findall(r"#<[a-z_]+>|#\d+|\$P_EP\[[XYZ]\]|Q\d+|DT_[A-Z]+|\d+\.?\d*|\.\d+|[-+\[\]()]|>=|<=|>|<|[A-Z]{2}",
                        text)
    if re.sub(r"\s+", "", "".join(tokens)) != re.sub(r"\s+", "", text):
        raise ValueError(f"cannot read expression {text!r} in {line!r}")
    out = []
    for t in tokens:
        if t in ops:
            out.append(ops[t])
        elif t in "[]()+-" or t in (">=", "<=", ">", "<"):
            out.append({"[": "(", "]": ")"}.get(t, t))
        elif re.fullmatch(r"\d+\.?\d*|\.\d+", t):
            out.append(repr(float(t)))
        else:
            out.append(repr(float(lookup(t))))
    return eval(" ".join(out), {"__builtins__": {}}, {})


def _get(scope: dict, ref: str) -> float:
    """A variable's value; reading one never set is an error (a vacant #n on Fanuc)."""
    if ref not in scope:
        raise ValueError(f"{ref} is read before it is set")
    return scope[ref]


class _Machine:
    def __init__(self, start):
        self.pos = [float(v) for v in start]
        self.moves: list[tuple[str, tuple[float, float, float]]] = []

    def go(self, kind: str, vals: dict[str, float]) -> None:
        for k, a in enumerate("XYZ"):
            if a in vals:
                self.pos[k] = float(vals[a])
        self.moves.append((kind, tuple(self.pos)))

    def block(self, dialect: str, line: str, words: list, vals: dict, probe: str, feed: str, rapid: str) -> None:
        """A motion block: its kind from the motion word; coordinates without one are an error."""
        kind = "probe" if probe in words else "feed" if feed in words else "rapid" if rapid in words else None
        if kind:
            self.go(kind, vals)
        elif vals:
            raise ValueError(f"{dialect}: move without a motion word {line!r}")


# ------------------------------------------------------------------------------------------ LinuxCNC


def run_linuxcnc(text: str, start) -> list:
    lines = [re.sub(r"\([^)]*\)", "", ln).strip() for ln in text.splitlines()]
    m = _Machine(start)
    subs, main, k = {}, [], 0
    while k < len(lines):
        mm = re.fullmatch(r"o<(\w+)> sub", lines[k], re.IGNORECASE)
        if mm:
            end = next(j for j in range(k, len(lines)) if re.fullmatch(rf"o<{mm.group(1)}> endsub", lines[j], re.IGNORECASE))
            subs[mm.group(1)] = lines[k + 1 : end]
            k = end + 1
            continue
        main.append(lines[k])
        k += 1
    glob: dict[str, float] = {}
    ops = {"GE": ">=", "LE": "<=", "GT": ">", "LT": "<"}

    def execute(body, local):
        def look(ref):
            if ref in ("#5420", "#5421", "#5422"):
                return m.pos[int(ref[-1])]
            return _get(local if local is not None else glob, ref)

        pc = 0
        while pc < len(body):
            ln = body[pc]
            pc += 1
            if not ln or ln == "%":
                continue
            if mm := re.fullmatch(r"o(\d+) if \[(.*)\]", ln):
                if not _expr(mm.group(2), look, ops, ln):
                    n = mm.group(1)
                    depth_end = next(j for j in range(pc, len(body)) if body[j] in (f"o{n} else", f"o{n} endif"))
                    pc = depth_end + 1
                continue
            if mm := re.fullmatch(r"o(\d+) else", ln):
                pc = next(j for j in range(pc, len(body)) if body[j] == f"o{mm.group(1)} endif") + 1
                continue
            if re.fullmatch(r"o\d+ endif", ln):
                continue
            if mm := re.fullmatch(r"o<(\w+)> call((?: \[[^\]]*\])*)", ln):
                args = [_expr(a, look, ops, ln) for a in re.findall(r"\[([^\]]*)\]", mm.group(2))]
                execute(subs[mm.group(1)], {f"#{i + 1}": float(v) for i, v in enumerate(args)})
                continue
            if mm := re.fullmatch(r"(#<\w+>|#\d+) = (.*)", ln):
                (local if local is not None else glob)[mm.group(1)] = float(_expr(mm.group(2), look, ops, ln))
                continue
            if ln in ("M2", "M30"):
                return
            words = ln.split()
            vals = {w[0]: float(_expr(w[1:], look, ops, ln)) for w in words if w[0] in "XYZ"}
            g = [w for w in words if w[0] in "GMF" or w[0] in "XYZ"]
            if len(g) != len(words):
                raise ValueError(f"linuxcnc: cannot read {ln!r}")
            m.block("linuxcnc", ln, words, vals, "G38.2", "G1", "G0")

    execute(main, None)
    return m.moves


# -------------------------------------------------------------------------------------------- Fanuc


def run_fanuc(text: str, start) -> list:
    lines = [re.sub(r"\([^)]*\)", "", ln).strip() for ln in text.splitlines()]
    progs, cur = {}, None
    for ln in lines:
        if mm := re.fullmatch(r"O(\d{4})", ln):
            cur = int(mm.group(1))
            progs[cur] = []
        elif ln and ln != "%":
            progs[cur].append(ln)
    m = _Machine(start)
    common: dict[str, float] = {}
    letters = {"X": "#24", "Y": "#25", "Z": "#26"}
    ops = {"GE": ">=", "LE": "<=", "GT": ">", "LT": "<"}

    def execute(body, local):
        def look(ref):
            if ref in ("#5001", "#5002", "#5003", "#5061", "#5062", "#5063"):  # block end / skip position
                return m.pos[int(ref[-1]) - 1]
            return _get(local if int(ref[1:]) < 100 else common, ref)

        pc = 0
        while pc < len(body):
            ln = body[pc]
            pc += 1
            if mm := re.fullmatch(r"IF \[(.*)\] GOTO (\d+)", ln):
                if _expr(mm.group(1), look, ops, ln):
                    pc = body.index(f"N{mm.group(2)}") + 1
                continue
            if mm := re.fullmatch(r"GOTO (\d+)", ln):
                pc = body.index(f"N{mm.group(1)}") + 1
                continue
            if re.fullmatch(r"N\d+", ln):
                continue
            if mm := re.fullmatch(r"(#\d+)=(.*)", ln):
                val = float(_expr(mm.group(2), look, ops, ln))
                (common if int(mm.group(1)[1:]) >= 100 else local)[mm.group(1)] = val
                continue
            if ln in ("M30", "M99"):
                return
            words = ln.split()
            if words[0] == "G65":
                prog = int(words[1][1:])
                args = {letters[w[0]]: float(w[1:]) for w in words[2:]}
                execute(progs[prog], args)
                continue
            vals = {}
            for w in words:
                if w[0] in "XYZ":
                    if "." not in w and not w[1:].startswith("#"):
                        raise ValueError(f"fanuc: {w} without a decimal point is read in 0.001 mm")
                    vals[w[0]] = float(look(w[1:])) if w[1:].startswith("#") else float(w[1:])
                elif not re.fullmatch(r"G\d+(\.\d)?|F\d+", w):
                    raise ValueError(f"fanuc: cannot read {ln!r}")
            m.block("fanuc", ln, words, vals, "G31", "G01", "G00")

    execute(progs[min(progs)], {})
    return m.moves


# ---------------------------------------------------------------------------------------- HEIDENHAIN


def run_heidenhain(text: str, start) -> list:
    body = []
    for ln in text.splitlines():
        if ln.startswith(" "):
            continue  # continuation of a cycle definition
        mm = re.fullmatch(r"(\d+) (.*)", ln)
        if not mm or int(mm.group(1)) != len(body):
            raise ValueError(f"heidenhain: block number missing or out of order: {ln!r}")
        body.append(re.sub(r";.*", "", mm.group(2)).strip())
    m = _Machine(start)
    q: dict[str, float] = {}

    def val(t: str) -> float:
        t = t.lstrip("+")
        if t.startswith("-Q"):
            return -q[t[1:]]
        return q[t] if t.startswith("Q") else float(t)

    labels = {int(b.split()[1]): i for i, b in enumerate(body) if re.fullmatch(r"LBL \d+", b)}
    stack: list[int] = []
    pc = 0
    while pc < len(body):
        ln = body[pc]
        pc += 1
        if not ln or ln.startswith(("BEGIN PGM", "CYCL DEF", "TCH PROBE")):
            continue
        if ln.startswith("END PGM") or ln in ("M30", "M2"):
            break
        if mm := re.fullmatch(r"FN 0: (Q\d+) = (\S+)", ln):
            q[mm.group(1)] = val(mm.group(2))
        elif mm := re.fullmatch(r"FN ([12]): (Q\d+) = (\S+) ([+-]) (\S+)", ln):
            a, b = val(mm.group(3)), val(mm.group(5))
            q[mm.group(2)] = a + b if mm.group(1) == "1" else a - b
        elif mm := re.fullmatch(r"FN 18: SYSREAD (Q\d+) = ID270 NR1 IDX([123])", ln):
            q[mm.group(1)] = m.pos[int(mm.group(2)) - 1]
        elif mm := re.fullmatch(r"FN (9|10|11|12): IF (\S+) (EQU|NE|GT|LT) (\S+) GOTO LBL (\d+)", ln):
            a, b = val(mm.group(2)), val(mm.group(4))
            if {"EQU": a == b, "NE": a != b, "GT": a > b, "LT": a < b}[mm.group(3)]:
                pc = labels[int(mm.group(5))] + 1
        elif mm := re.fullmatch(r"CALL LBL (\d+)", ln):
            stack.append(pc)
            pc = labels[int(mm.group(1))] + 1
        elif ln == "LBL 0":
            pc = stack.pop()
        elif re.fullmatch(r"LBL \d+", ln):
            continue
        elif mm := re.fullmatch(r"L((?: [XYZ]\S+)+) (FMAX|F\d+)", ln):
            vals = {w[0]: val(w[1:]) for w in mm.group(1).split()}
            m.go("rapid" if mm.group(2) == "FMAX" else "feed", vals)
        else:
            raise ValueError(f"heidenhain: cannot read {ln!r}")
    return m.moves


# ------------------------------------------------------------------------------------------- Siemens


def run_siemens(text: str, start) -> list:
    files, cur = {}, None
    for ln in text.splitlines():
        if mm := re.fullmatch(r"%_N_(\w+)_(MPF|SPF)", ln):
            cur = (mm.group(1), mm.group(2))
            files[cur] = []
        elif not ln.startswith(";$PATH="):
            s = re.sub(r";.*", "", ln).strip()
            if s:
                files[cur].append(s)
    procs = {}
    for (name, kind), body in files.items():
        if kind == "SPF":
            mm = re.fullmatch(r"PROC (\w+)\(([^)]*)\)", body[0])
            assert mm and mm.group(1) == name, body[0]
            procs[name] = ([p.split()[1] for p in mm.group(2).split(",")], body[1:])
    main = next(b for (n, k), b in files.items() if k == "MPF")
    m = _Machine(start)
    rparams: dict[str, float] = {}

    def execute(body, local):
        def look(ref):
            if ref.startswith("$P_EP["):
                return m.pos["XYZ".index(ref[6])]
            return local[ref]

        pc = 0
        while pc < len(body):
            ln = body[pc]
            pc += 1
            if ln.startswith("DEF REAL "):
                continue
            if mm := re.fullmatch(r"IF (.*)", ln):
                if not _expr(mm.group(1), look, {}, ln):
                    depth, j = 0, pc
                    while True:  # to the matching ELSE or ENDIF
                        if body[j].startswith("IF "):
                            depth += 1
                        elif body[j] == "ENDIF" and depth:
                            depth -= 1
                        elif body[j] in ("ELSE", "ENDIF") and not depth:
                            break
                        j += 1
                    pc = j + 1
                continue
            if ln == "ELSE":
                depth, j = 0, pc
                while body[j] != "ENDIF" or depth:
                    depth += body[j].startswith("IF ") - (body[j] == "ENDIF")
                    j += 1
                pc = j + 1
                continue
            if ln == "ENDIF" or ln == "STOPRE":
                continue
            if ln in ("M17", "RET", "M30"):
                return
            if mm := re.fullmatch(r"(DT_[A-Z]+)=(.*)", ln):
                local[mm.group(1)] = float(_expr(mm.group(2), look, {}, ln))
                continue
            if mm := re.fullmatch(r"(R\d+)=\$AA_MW\[([XYZ])\]", ln):
                rparams[mm.group(1)] = m.pos["XYZ".index(mm.group(2))]
                continue
            if mm := re.fullmatch(r"(\w+)\((.*)\)", ln):
                names, sub = procs[mm.group(1)]
                args = [float(a) for a in mm.group(2).split(",")]
                execute(sub, dict(zip(names, args)))
                continue
            words = ln.split()
            vals = {}
            for w in words:
                if mm := re.fullmatch(r"([XYZ])=(DT_[A-Z]+)", w):
                    vals[mm.group(1)] = local[mm.group(2)]
                elif re.fullmatch(r"[XYZ]" + NUM, w):
                    vals[w[0]] = float(w[1:])
                elif not re.fullmatch(r"G\d+|F\d+|MEAS=1", w):
                    raise ValueError(f"siemens: cannot read {ln!r}")
            m.block("siemens", ln, words, vals, "MEAS=1", "G1", "G0")

    execute(main, {})
    return m.moves


RUN = {"linuxcnc": run_linuxcnc, "fanuc": run_fanuc, "heidenhain": run_heidenhain, "siemens": run_siemens}


def run(dialect: str, text: str, start) -> list:
    return RUN[dialect](text, start)


def corners(moves, start=None, tol_mm: float = 1e-9) -> list[tuple[float, float, float]]:
    """The points reached, consecutive duplicates (within ``tol_mm`` on every axis) dropped."""
    out = [tuple(start)] if start is not None else []
    for _, p in moves:
        if not out or max(abs(a - b) for a, b in zip(out[-1], p)) > tol_mm:
            out.append(tuple(p))
    return out
