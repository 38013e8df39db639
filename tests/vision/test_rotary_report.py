"""ISO 230-2 evaluation and CSV/plots of a rotary-axis run (the compensation tables: tests/machine)."""

from __future__ import annotations

import numpy as np
import pytest

from app.synth.rotary_images import ErrorCurve, iso_bidirectional_angles
from app.vision.rotary_report import infer_directions, iso230_evaluate, plot_svg, report_files


def test_infer_directions_turns_at_repeated_angle():
    assert infer_directions([0, 10, 20, 20, 10, 0, 0, 10]) == [1, 1, 1, -1, -1, -1, 1, 1]


def test_iso_figures_by_hand():
    """Two positions, two runs each way; deviations x = -E chosen so every figure is checkable."""
    angles = [0, 90, 90, 0, 0, 90, 90, 0]
    dirs = [1, 1, -1, -1, 1, 1, -1, -1]
    x = np.array([0.0, 4.0, 1.0, -2.0, 2.0, 6.0, 3.0, -4.0])  # deviations in arc-seconds
    rep = iso230_evaluate(angles, -x, dirs)
    p0, p90 = rep.positions
    assert (p0.mean_up_arcsec, p0.mean_down_arcsec) == (1.0, -3.0)
    assert (p90.mean_up_arcsec, p90.mean_down_arcsec) == (5.0, 2.0)
    assert p0.reversal_arcsec == 4.0 and p90.reversal_arcsec == 3.0
    s = np.sqrt(2.0)  # every pair differs by 2 -> s = sqrt(2)
    assert p0.s_up_arcsec == pytest.approx(s) and p90.s_down_arcsec == pytest.approx(s)
    assert p0.repeatability_arcsec == pytest.approx(max(4 * s + 4.0, 4 * s))
    assert rep.reversal_B_arcsec == 4.0 and rep.mean_reversal_arcsec == 3.5
    assert rep.systematic_up_arcsec == 4.0 and rep.systematic_arcsec == 8.0
    assert rep.mean_range_M_arcsec == pytest.approx(3.5 - (-1.0))
    assert rep.accuracy_arcsec == pytest.approx((5.0 + 2 * s) - (-3.0 - 2 * s))
    assert rep.runs_up == 2 and rep.runs_down == 2


def test_single_run_has_no_repeatability_but_valid_json():
    rep = iso230_evaluate([0, 10, 20], [0.0, 1.0, 2.0])
    assert np.isnan(rep.repeatability_up_arcsec)
    d = rep.to_dict()
    assert d["repeatability_up_arcsec"] is None and d["systematic_up_arcsec"] == 2.0
    from app.vision.rotary_report import caption
    text = caption(rep)          # what the plots print: no "nan", the reason instead
    assert "nan" not in text.lower() and "R = n/a (R needs 2+ runs each way)" in text


def test_report_files_are_bytes_and_nothing_is_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    a, d = iso_bidirectional_angles([float(v) for v in range(0, 91, 30)], repeats=1)
    E = np.linspace(0.0, 3.0, len(a))
    rep, named = report_files(a, np.array(a) - E / 3600.0, E, d)
    assert sorted(named) == ["error.png", "error.svg", "positions.csv", "run.csv"]
    assert all(isinstance(v, bytes) for v in named.values()) and named["error.png"].startswith(b"\x89PNG")
    assert named["error.svg"].decode() == plot_svg(a, E, rep, d) and list(tmp_path.iterdir()) == []
