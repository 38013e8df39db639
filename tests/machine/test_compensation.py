"""Compensation-table proposals (HEIDENHAIN .COM, Fanuc pitch) of a rotary-axis run: they cancel the
injected error curve; the service's report carries them as bytes beside the CSV and plots."""

from __future__ import annotations

import numpy as np
import pytest

from app.machine.compensation import PROPOSAL_BANNER, fanuc_pitch_proposal, heidenhain_com_proposal
from app.services.rotary import rotary_report
from app.synth.rotary_images import ErrorCurve, iso_bidirectional_angles
from app.vision.rotary_report import correction_grid, plot_svg


def test_compensation_proposals_cancel_the_injected_curve():
    a, d = iso_bidirectional_angles([float(v) for v in range(0, 361, 30)], repeats=2)
    curve = ErrorCurve(reversal_arcsec=4.0)
    e_inj = curve.error_arcsec(np.array(a), np.array(d))
    E = -(e_inj - e_inj[0])
    rep, named = rotary_report(a, np.array(a) - E / 3600.0, E, d, axis_name="B")
    assert rep.mean_reversal_arcsec == pytest.approx(4.0)
    assert sorted(named) == sorted(["run.csv", "positions.csv", "error.svg", "error.png", "B_proposal.COM",
                                    "fanuc_pitch_proposal.txt"])
    assert all(isinstance(v, bytes) for v in named.values()) and named["error.png"].startswith(b"\x89PNG")
    com = heidenhain_com_proposal(*correction_grid(rep), axis="B")
    assert named["B_proposal.COM"].decode() == com
    assert PROPOSAL_BANNER in com
    rows = [r.split() for r in com.splitlines() if r[:1] == " " and r.split()[0].isdigit()]
    assert len(rows) == 13
    # correction + deviation = 0 at every point (positive direction column)
    for r, p in zip(rows, rep.positions):
        assert float(r[2]) * 3600.0 == pytest.approx(-p.mean_up_arcsec, abs=0.002)
        assert float(r[3]) * 3600.0 == pytest.approx(-p.mean_down_arcsec, abs=0.002)
    fan = fanuc_pitch_proposal(*correction_grid(rep), detection_unit_deg=0.0001)
    assert PROPOSAL_BANNER in fan
    pts = [list(map(float, r.split(","))) for r in fan.splitlines() if not r.startswith(";")]
    assert len(pts) == 13 and sum(p[3] for p in pts) == 0  # a full turn closes
    assert "3625 (travel per turn) = 3600000" in fan
    svg = plot_svg(a, E, rep, d)
    assert svg.startswith("<svg") and svg.count("<circle") == len(a)
    csv_lines = named["run.csv"].decode().splitlines()
    assert len(csv_lines) == len(a) + 1 and csv_lines[0].startswith("image,commanded_deg")
