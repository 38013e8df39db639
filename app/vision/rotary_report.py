"""ISO 230-2 style evaluation of a rotary-axis run, its plots and CSV files (as bytes).

Sign convention. The measurement (:mod:`app.vision.rotary`) gives per image
``E = commanded increment - measured increment`` (arc-seconds, first image = 0). ISO 230-2 works
with the positional deviation ``x = actual - target``, so here ``x_ij = -E_ij``: deviation of the
measured position from the commanded one, both counted from the run's first image.

Formulas (ISO 230-2:2014, clause 3; i = target position, j = run, n runs per direction,
arrows = approach direction):

* mean unidirectional deviation   ``x̄_i↑ = (1/n) Σ_j x_ij↑``             (same for ↓)
* reversal value                  ``B_i = x̄_i↑ - x̄_i↓``; axis ``B = max |B_i|``,
  mean ``B̄ = (1/m) Σ_i B_i``
* mean bidirectional deviation    ``x̄_i = (x̄_i↑ + x̄_i↓) / 2``
* standard uncertainty estimate   ``s_i↑ = sqrt(Σ_j (x_ij↑ - x̄_i↑)² / (n - 1))``
* unidirectional repeatability    ``R_i↑ = 4 s_i↑``; axis ``R↑ = max R_i↑``
* bidirectional repeatability     ``R_i = max(2 s_i↑ + 2 s_i↓ + |B_i|, R_i↑, R_i↓)``; ``R = max R_i``
* unidirectional systematic dev.  ``E↑ = max x̄_i↑ - min x̄_i↑``
* bidirectional systematic dev.   ``E = max(x̄_i↑, x̄_i↓) - min(x̄_i↑, x̄_i↓)``
* mean bidirectional dev. range   ``M = max x̄_i - min x̄_i``
* unidirectional accuracy         ``A↑ = max(x̄_i↑ + 2 s_i↑) - min(x̄_i↑ - 2 s_i↑)``
* bidirectional accuracy          ``A = max(x̄_i↑ + 2 s_i↑, x̄_i↓ + 2 s_i↓) - min(x̄_i↑ - 2 s_i↑, x̄_i↓ - 2 s_i↓)``

Quantities that need two runs (s, R, A) are NaN with one run; ISO 230-2 asks for 5 runs.
All values in arc-seconds, positions in degrees.

The corrections a compensation table takes are -(mean deviation) (:func:`correction_grid`); the
controllers' table formats are in :mod:`app.machine.compensation`.
"""

from __future__ import annotations

import csv
import html
import io
import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import cv2
import numpy as np

def infer_directions(angles_deg: Sequence[float]) -> list[int]:
    """Approach direction of each image: +1 if the angle rose from the previous image, -1 if it
    fell; a repeated angle is a turnaround (the opposite of the previous direction, as after the
    overrun of an ISO 230-2 cycle); the first image counts as +1."""
    a = np.asarray(angles_deg, dtype=float)
    out = [1]
    for k in range(1, len(a)):
        d = np.sign(a[k] - a[k - 1])
        out.append(int(d) if d != 0 else -out[-1])
    return out


@dataclass(frozen=True)
class PositionStats:
    """ISO 230-2 figures at one target position (arc-seconds; NaN where not measurable)."""

    position_deg: float
    n_up: int
    n_down: int
    mean_up_arcsec: float
    mean_down_arcsec: float
    mean_arcsec: float
    s_up_arcsec: float
    s_down_arcsec: float
    reversal_arcsec: float
    repeatability_up_arcsec: float
    repeatability_down_arcsec: float
    repeatability_arcsec: float


@dataclass(frozen=True)
class Iso230Report:
    """Axis figures (arc-seconds) and per-position statistics; see the module docstring."""

    positions: tuple[PositionStats, ...]
    reversal_B_arcsec: float
    mean_reversal_arcsec: float
    systematic_up_arcsec: float
    systematic_down_arcsec: float
    systematic_arcsec: float
    mean_range_M_arcsec: float
    repeatability_up_arcsec: float
    repeatability_down_arcsec: float
    repeatability_arcsec: float
    accuracy_up_arcsec: float
    accuracy_down_arcsec: float
    accuracy_arcsec: float
    runs_up: int
    runs_down: int

    def to_dict(self) -> dict[str, Any]:
        def clean(v: Any) -> Any:
            return None if isinstance(v, float) and not math.isfinite(v) else v
        d = {k: clean(v) for k, v in asdict(self).items() if k != "positions"}
        d["positions"] = [{k: clean(v) for k, v in asdict(p).items()} for p in self.positions]
        return d


def caption(report) -> str:
    """One line for a plot: A, E, B, R in arc seconds; a figure that needs more runs says so."""
    def f(v: float) -> str:
        return f'{v:.2f}"' if np.isfinite(v) else "n/a"
    text = (f"A = {f(report.accuracy_arcsec)}, E = {f(report.systematic_arcsec)}, "
            f"B = {f(report.reversal_B_arcsec)}, R = {f(report.repeatability_arcsec)}")
    if not np.isfinite(report.repeatability_arcsec):
        text += " (R needs 2+ runs each way)"
    return text


def _nanmax(v: list[float]) -> float:
    v = [x for x in v if math.isfinite(x)]
    return max(v) if v else float("nan")


def _nanmin(v: list[float]) -> float:
    v = [x for x in v if math.isfinite(x)]
    return min(v) if v else float("nan")


def iso230_evaluate(angles_deg: Sequence[float], error_arcsec: Sequence[float],
                    directions: Sequence[int] | None = None, decimals: int = 6) -> Iso230Report:
    """Evaluate a run (one entry per image) in the ISO 230-2 manner.

    angles_deg : commanded angles (deg); images at the same commanded angle (to ``decimals``)
        are the same target position. error_arcsec : ``E`` from the measurement (x = -E).
    directions : +1 / -1 per image (default :func:`infer_directions`).
    """
    a = np.asarray(angles_deg, dtype=float)
    x = -np.asarray(error_arcsec, dtype=float)
    if len(a) != len(x):
        raise ValueError(f"{len(a)} angles but {len(x)} errors; give one of each per image")
    d = np.asarray(directions if directions is not None else infer_directions(a), dtype=int)
    if len(d) != len(a) or not np.all(np.isin(d, (-1, 1))):
        raise ValueError("directions must be +1 or -1, one per image")
    keys = np.round(a, decimals)
    stats = []
    for p in sorted(set(keys.tolist())):
        sel = keys == p
        up, dn = x[sel & (d > 0)], x[sel & (d < 0)]
        mu = float(up.mean()) if up.size else float("nan")
        md = float(dn.mean()) if dn.size else float("nan")
        su = float(up.std(ddof=1)) if up.size > 1 else float("nan")
        sd = float(dn.std(ddof=1)) if dn.size > 1 else float("nan")
        both = [v for v in (mu, md) if math.isfinite(v)]
        B = mu - md
        Ri = _nanmax([2 * su + 2 * sd + abs(B), 4 * su, 4 * sd])
        stats.append(PositionStats(float(p), int(up.size), int(dn.size), mu, md,
                                   float(np.mean(both)) if both else float("nan"), su, sd, B,
                                   4 * su, 4 * sd, Ri))
    mu = [s.mean_up_arcsec for s in stats]
    md = [s.mean_down_arcsec for s in stats]
    su = [s.s_up_arcsec for s in stats]
    sd = [s.s_down_arcsec for s in stats]
    Bs = [s.reversal_arcsec for s in stats if math.isfinite(s.reversal_arcsec)]
    hi_up = [m + 2 * s for m, s in zip(mu, su)]
    lo_up = [m - 2 * s for m, s in zip(mu, su)]
    hi_dn = [m + 2 * s for m, s in zip(md, sd)]
    lo_dn = [m - 2 * s for m, s in zip(md, sd)]
    n_up = max((s.n_up for s in stats), default=0)
    n_dn = max((s.n_down for s in stats), default=0)
    return Iso230Report(
        positions=tuple(stats),
        reversal_B_arcsec=max((abs(b) for b in Bs), default=float("nan")),
        mean_reversal_arcsec=float(np.mean(Bs)) if Bs else float("nan"),
        systematic_up_arcsec=_nanmax(mu) - _nanmin(mu),
        systematic_down_arcsec=_nanmax(md) - _nanmin(md),
        systematic_arcsec=_nanmax(mu + md) - _nanmin(mu + md),
        mean_range_M_arcsec=_nanmax([s.mean_arcsec for s in stats]) - _nanmin([s.mean_arcsec for s in stats]),
        repeatability_up_arcsec=_nanmax([s.repeatability_up_arcsec for s in stats]),
        repeatability_down_arcsec=_nanmax([s.repeatability_down_arcsec for s in stats]),
        repeatability_arcsec=_nanmax([s.repeatability_arcsec for s in stats]),
        accuracy_up_arcsec=_nanmax(hi_up) - _nanmin(lo_up),
        accuracy_down_arcsec=_nanmax(hi_dn) - _nanmin(lo_dn),
        accuracy_arcsec=_nanmax(hi_up + hi_dn) - _nanmin(lo_up + lo_dn),
        runs_up=n_up, runs_down=n_dn)


# --------------------------------------------------------------------------- files

def run_csv(angles_deg: Sequence[float], measured_deg: Sequence[float], error_arcsec: Sequence[float],
            directions: Sequence[int] | None = None) -> str:
    """One row per image: index, commanded, measured, direction, E and x = -E (arc-seconds)."""
    d = directions if directions is not None else infer_directions(angles_deg)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["image", "commanded_deg", "measured_deg", "direction", "error_E_arcsec",
                "deviation_x_arcsec"])
    for i, (c, m, e, di) in enumerate(zip(angles_deg, measured_deg, error_arcsec, d)):
        w.writerow([i, f"{c:.6f}", f"{m:.8f}", int(di), f"{e:.3f}", f"{-e:.3f}"])
    return buf.getvalue()


def positions_csv(report: Iso230Report) -> str:
    """One row per target position with the ISO 230-2 statistics (arc-seconds)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    fields = list(asdict(report.positions[0]).keys()) if report.positions else []
    w.writerow(fields)
    for p in report.positions:
        w.writerow([f"{v:.4f}" if isinstance(v, float) else v for v in asdict(p).values()])
    return buf.getvalue()


def correction_grid(report: Iso230Report) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(positions on a uniform grid in degrees (spacing = the smallest step), corrections -x̄↑ and -x̄↓ in
    arc-seconds at them, the spacing in degrees): what a controller's compensation table takes
    (:mod:`app.machine.compensation`)."""
    pos = np.array([p.position_deg for p in report.positions])
    up = np.array([p.mean_up_arcsec for p in report.positions])
    dn = np.array([p.mean_down_arcsec for p in report.positions])
    up = np.where(np.isfinite(up), up, dn)
    dn = np.where(np.isfinite(dn), dn, up)
    if len(pos) < 2:
        return pos, -up, -dn, 0.0
    step = float(np.min(np.diff(pos)))
    n = int(round((pos[-1] - pos[0]) / step)) + 1
    grid = pos[0] + step * np.arange(n)
    return grid, -np.interp(grid, pos, up), -np.interp(grid, pos, dn), step


# --------------------------------------------------------------------------- plot

@dataclass(frozen=True)
class _Series:
    name: str
    x: np.ndarray
    y: np.ndarray
    color: tuple[int, int, int]  # RGB
    line: bool


def _series(angles_deg: Sequence[float], error_arcsec: Sequence[float], directions: Sequence[int],
            report: Iso230Report) -> list[_Series]:
    a = np.asarray(angles_deg, float)
    x = -np.asarray(error_arcsec, float)
    d = np.asarray(directions)
    pos = np.array([p.position_deg for p in report.positions])
    mu = np.array([p.mean_up_arcsec for p in report.positions])
    md = np.array([p.mean_down_arcsec for p in report.positions])
    out = [_Series("runs +", a[d > 0], x[d > 0], (31, 119, 180), False),
           _Series("runs -", a[d < 0], x[d < 0], (214, 39, 40), False)]
    if np.isfinite(mu).any():
        out.append(_Series("mean +", pos[np.isfinite(mu)], mu[np.isfinite(mu)], (31, 119, 180), True))
    if np.isfinite(md).any():
        out.append(_Series("mean -", pos[np.isfinite(md)], md[np.isfinite(md)], (214, 39, 40), True))
    return out


def _ticks(lo: float, hi: float, n: int = 6) -> np.ndarray:
    span = max(hi - lo, 1e-9)
    raw = span / n
    mag = 10 ** math.floor(math.log10(raw))
    step = min((m * mag for m in (1, 2, 5, 10) if m * mag >= raw), default=10 * mag)
    return np.arange(math.ceil(lo / step) * step, hi + 1e-9 * span, step)


def _layout(series: list[_Series], w: int, h: int):
    xs = np.concatenate([s.x for s in series]) if series else np.zeros(1)
    ys = np.concatenate([s.y for s in series]) if series else np.zeros(1)
    x0, x1 = float(xs.min()), float(xs.max())
    if x1 - x0 < 1e-9:
        x0, x1 = x0 - 1, x1 + 1
    y0, y1 = float(min(ys.min(), 0)), float(max(ys.max(), 0))
    pad = 0.1 * max(y1 - y0, 1.0)
    y0, y1 = y0 - pad, y1 + pad
    L, R, T, B = 80, 20, 40, 50

    def tx(v: np.ndarray) -> np.ndarray:
        return L + (np.asarray(v) - x0) / (x1 - x0) * (w - L - R)

    def ty(v: np.ndarray) -> np.ndarray:
        return h - B - (np.asarray(v) - y0) / (y1 - y0) * (h - T - B)
    return (x0, x1, y0, y1), tx, ty, (L, R, T, B)


def plot_svg(angles_deg: Sequence[float], error_arcsec: Sequence[float], report: Iso230Report,
             directions: Sequence[int] | None = None, title: str = "Rotary axis positioning deviation",
             width: int = 900, height: int = 500) -> str:
    """SVG plot of deviation x = -E (arc-seconds) against commanded angle (deg)."""
    d = directions if directions is not None else infer_directions(angles_deg)
    ser = _series(angles_deg, error_arcsec, d, report)
    (x0, x1, y0, y1), tx, ty, (L, R, T, B) = _layout(ser, width, height)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
           f'viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="12">',
           f'<rect width="{width}" height="{height}" fill="white"/>',
           f'<text x="{width / 2}" y="22" text-anchor="middle" font-size="15">{title}</text>']
    for v in _ticks(x0, x1):
        X = float(tx(v))
        out.append(f'<line x1="{X:.1f}" y1="{T}" x2="{X:.1f}" y2="{height - B}" stroke="#e5e5e5"/>')
        out.append(f'<text x="{X:.1f}" y="{height - B + 16}" text-anchor="middle">{v:g}</text>')
    for v in _ticks(y0, y1):
        Y = float(ty(v))
        out.append(f'<line x1="{L}" y1="{Y:.1f}" x2="{width - R}" y2="{Y:.1f}" stroke="#e5e5e5"/>')
        out.append(f'<text x="{L - 6}" y="{Y + 4:.1f}" text-anchor="end">{v:g}</text>')
    Y0 = float(ty(0.0))
    out.append(f'<line x1="{L}" y1="{Y0:.1f}" x2="{width - R}" y2="{Y0:.1f}" stroke="#888"/>')
    out.append(f'<rect x="{L}" y="{T}" width="{width - L - R}" height="{height - T - B}" '
               'fill="none" stroke="#333"/>')
    out.append(f'<text x="{width / 2}" y="{height - 12}" text-anchor="middle">commanded angle (deg)</text>')
    out.append(f'<text transform="translate(18,{height / 2}) rotate(-90)" text-anchor="middle">'
               'deviation x = measured - commanded (arcsec)</text>')
    for k, s in enumerate(ser):
        col = "rgb(%d,%d,%d)" % s.color
        if s.line:
            o = np.argsort(s.x)
            pts = " ".join(f"{float(tx(a)):.1f},{float(ty(b)):.1f}" for a, b in zip(s.x[o], s.y[o]))
            dash = "" if "+" in s.name else ' stroke-dasharray="6,4"'
            out.append(f'<polyline points="{pts}" fill="none" stroke="{col}" stroke-width="2"{dash}/>')
        else:
            for a, b in zip(s.x, s.y):
                out.append(f'<circle cx="{float(tx(a)):.1f}" cy="{float(ty(b)):.1f}" r="3" fill="{col}"/>')
        out.append(f'<text x="{width - R - 80}" y="{T + 16 + 16 * k}" fill="{col}">{s.name}</text>')
    out.append(f'<text x="{L + 6}" y="{T + 16}">{html.escape(caption(report))}</text>')
    out.append("</svg>")
    return "\n".join(out) + "\n"


def plot_png(angles_deg: Sequence[float], error_arcsec: Sequence[float], report: Iso230Report,
             directions: Sequence[int] | None = None, title: str = "Rotary axis positioning deviation",
             width: int = 900, height: int = 500) -> bytes:
    """The same plot as :func:`plot_svg`, drawn with OpenCV, PNG bytes."""
    d = directions if directions is not None else infer_directions(angles_deg)
    ser = _series(angles_deg, error_arcsec, d, report)
    (x0, x1, y0, y1), tx, ty, (L, R, T, B) = _layout(ser, width, height)
    img = np.full((height, width, 3), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for v in _ticks(x0, x1):
        X = int(round(float(tx(v))))
        cv2.line(img, (X, T), (X, height - B), (229, 229, 229), 1)
        cv2.putText(img, f"{v:g}", (X - 12, height - B + 18), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    for v in _ticks(y0, y1):
        Y = int(round(float(ty(v))))
        cv2.line(img, (L, Y), (width - R, Y), (229, 229, 229), 1)
        cv2.putText(img, f"{v:g}", (8, Y + 4), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    Y0 = int(round(float(ty(0.0))))
    cv2.line(img, (L, Y0), (width - R, Y0), (136, 136, 136), 1)
    cv2.rectangle(img, (L, T), (width - R, height - B), (51, 51, 51), 1)
    cv2.putText(img, title, (L, 24), font, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "commanded angle (deg)", (width // 2 - 90, height - 10), font, 0.45, (0, 0, 0), 1,
                cv2.LINE_AA)
    cv2.putText(img, "x = measured - commanded (arcsec)", (L + 6, T + 14), font, 0.4, (0, 0, 0), 1,
                cv2.LINE_AA)
    for k, s in enumerate(ser):
        bgr = s.color[::-1]
        if s.line:
            o = np.argsort(s.x)
            pts = np.stack([tx(s.x[o]), ty(s.y[o])], axis=1).round().astype(np.int32)
            cv2.polylines(img, [pts], False, bgr, 2, cv2.LINE_AA)
        else:
            for a, b in zip(s.x, s.y):
                cv2.circle(img, (int(round(float(tx(a)))), int(round(float(ty(b))))), 3, bgr, -1,
                           cv2.LINE_AA)
        cv2.putText(img, s.name, (width - R - 80, T + 16 + 16 * k), font, 0.45, bgr, 1, cv2.LINE_AA)
    cv2.putText(img, caption(report), (L + 6, T + 32), font, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    ok, buf = cv2.imencode(".png", img)
    return buf.tobytes()


def report_files(angles_deg: Sequence[float], measured_deg: Sequence[float], error_arcsec: Sequence[float],
                 directions: Sequence[int] | None = None) -> tuple[Iso230Report, dict[str, bytes]]:
    """The ISO 230-2 evaluation and its files as bytes: run.csv, positions.csv, error.svg, error.png.
    The caller stores or writes them (the controllers' compensation tables: app/machine/compensation.py)."""
    d = list(directions) if directions is not None else infer_directions(angles_deg)
    rep = iso230_evaluate(angles_deg, error_arcsec, d)
    return rep, {
        "run.csv": run_csv(angles_deg, measured_deg, error_arcsec, d).encode(),
        "positions.csv": positions_csv(rep).encode(),
        "error.svg": plot_svg(angles_deg, error_arcsec, rep, d).encode(),
        "error.png": plot_png(angles_deg, error_arcsec, rep, d),
    }
