"""ISO 230-2 evaluation, CSV/plots and compensation proposals of a rotary-axis run."""

from __future__ import annotations

import numpy as np
import pytest

from app.synth.rotary_images import ErrorCurve, iso_bidirectional_angles
from app.vision.rotary_report import (PROPOSAL_BANNER, fanuc_pitch_proposal, heidenhain_com_proposal,
                                      infer_directions, iso230_evaluate, plot_svg, write_report)


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


def test_compensation_proposals_cancel_the_injected_curve(tmp_path):
    a, d = iso_bidirectional_angles([float(v) for v in range(0, 361, 30)], repeats=2)
    curve = ErrorCurve(reversal_arcsec=4.0)
    e_inj = curve.error_arcsec(np.array(a), np.array(d))
    E = -(e_inj - e_inj[0])
    rep, paths = write_report(tmp_path, a, np.array(a) - E / 3600.0, E, d, axis_name="B")
    assert rep.mean_reversal_arcsec == pytest.approx(4.0)
    names = sorted(p.name for p in paths)
    assert names == sorted(["run.csv", "positions.csv", "error.svg", "error.png", "B_proposal.COM",
                            "fanuc_pitch_proposal.txt"])
    assert (tmp_path / "error.png").read_bytes().startswith(b"\x89PNG")
    com = heidenhain_com_proposal(rep, "B")
    assert PROPOSAL_BANNER in com
    rows = [r.split() for r in com.splitlines() if r[:1] == " " and r.split()[0].isdigit()]
    assert len(rows) == 13
    # correction + deviation = 0 at every point (positive direction column)
    for r, p in zip(rows, rep.positions):
        assert float(r[2]) * 3600.0 == pytest.approx(-p.mean_up_arcsec, abs=0.002)
        assert float(r[3]) * 3600.0 == pytest.approx(-p.mean_down_arcsec, abs=0.002)
    fan = fanuc_pitch_proposal(rep, detection_unit_deg=0.0001)
    assert PROPOSAL_BANNER in fan
    pts = [list(map(float, r.split(","))) for r in fan.splitlines() if not r.startswith(";")]
    assert len(pts) == 13 and sum(p[3] for p in pts) == 0  # a full turn closes
    assert "3625 (travel per turn) = 3600000" in fan
    svg = plot_svg(a, E, rep, d)
    assert svg.startswith("<svg") and svg.count("<circle") == len(a)
    csv_lines = (tmp_path / "run.csv").read_text().splitlines()
    assert len(csv_lines) == len(a) + 1 and csv_lines[0].startswith("image,commanded_deg")
