"""A located pose whose position sigma is a good share of the part's size is no place (``locate._place_not_fixed``)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from app.vision.object_pose.locate import MAX_PLACE_SIGMA_SHARE, _place_not_fixed

MODEL = SimpleNamespace(name="pin_block_32", diameter_mm=43.0)


def _pose(**sigma):
    return SimpleNamespace(score=0.58, sigma={"x_mm": 0.1, "y_mm": 0.1, "z_mm": 0.1, **sigma})


def test_a_sigma_of_most_of_the_part_is_no_place():
    """Our generator's synth_040: 31 mm in x for a 43 mm block."""
    why = _place_not_fixed(MODEL, _pose(x_mm=30.7, y_mm=15.4, z_mm=15.0))
    assert "does not fix its place" in why and "31 mm in x" in why and "43 mm" in why


@pytest.mark.parametrize("axis", ["x_mm", "y_mm", "z_mm"])
def test_every_axis_counts(axis):
    assert _place_not_fixed(MODEL, _pose(**{axis: 1.01 * MAX_PLACE_SIGMA_SHARE * 43.0}))


def test_a_broad_but_useful_sigma_is_a_place():
    """Devset setup_007: 2.6 mm for a 55 mm angle block, 0.31 mm off; the gate refuses it, not this."""
    assert _place_not_fixed(SimpleNamespace(name="angle_block", diameter_mm=55.0), _pose(z_mm=2.64)) == ""


def test_an_unknown_height_is_not_a_lost_place():
    """Height and tilt only assumed (NaN sigma): the gate refuses the pose, this rule does not."""
    assert _place_not_fixed(MODEL, _pose(z_mm=float("nan"))) == ""
