"""A fixture's guide (app/geometry/guides.py): parsed and refused with the reason; the search starts
along it and how far a pose is from it."""

from __future__ import annotations

import numpy as np
import pytest

from app.geometry.guides import (
    GUIDE_CAPTURE_DEG,
    GUIDE_CAPTURE_MM,
    GUIDE_STEP_MM,
    OFF_GUIDE_DEG,
    OFF_GUIDE_MM,
    guide_deviation,
    guide_start_poses,
    parse_guide,
    pose_at_travel,
)
from app.geometry.transforms import make_pose

T70 = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 70], [0, 0, 0, 1]]
JAW = {"carrier": "vise_body", "T_carrier_obj": T70, "axis": [1, 0, 0], "travel_mm": [-95, 100]}


def _rot_z(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])


def test_a_good_guide_is_read_as_floats_with_a_unit_axis():
    g = parse_guide({**JAW, "carrier": " vise_body ", "axis": [0, 2, 0]}, "clamp")
    assert g == {"carrier": "vise_body", "T_carrier_obj": [[float(x) for x in r] for r in T70],
                 "axis": [0.0, 1.0, 0.0], "travel_mm": [-95.0, 100.0]}
    assert parse_guide(None, "clamp") is None
    assert parse_guide(JAW, "support")["travel_mm"] == [-95.0, 100.0]


@pytest.mark.parametrize("value, message", [
    ([1, 2], "guide: expected an object {carrier, T_carrier_obj, axis, travel_mm} (or null), got list"),
    ({**JAW, "carrier": "  "}, "guide.carrier: carrier must not be empty"),
    ({k: v for k, v in JAW.items() if k != "axis"}, "guide.axis: Field required"),
    ({**JAW, "extra": 1}, "guide.extra: Extra inputs are not permitted"),
    ({**JAW, "T_carrier_obj": [[1, 0, 0]]}, "guide.T_carrier_obj: T_carrier_obj: expected shape (4, 4), got (1, 3)"),
    ({**JAW, "T_carrier_obj": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
     "T_carrier_obj: rotation not orthonormal"),
    ({**JAW, "T_carrier_obj": np.diag([1.0, 1.0, -1.0, 1.0]).tolist()}, "rotation is a reflection"),
    ({**JAW, "axis": [0, 0, 0]}, "guide.axis: axis is zero"),
    ({**JAW, "axis": [1, 0]}, "guide.axis: axis must be [x, y, z] (three numbers), got [1, 0]"),
    ({**JAW, "axis": [1, "x", 0]}, "guide.axis[1]: Input should be a valid number"),
    ({**JAW, "travel_mm": [100, -95]}, "guide.travel_mm: [100, -95]: lo must be less than hi"),
    ({**JAW, "travel_mm": [5, 5]}, "lo must be less than hi"),
    ({**JAW, "travel_mm": [0]}, "guide.travel_mm: travel_mm must be [lo, hi] (two numbers, mm), got [0]"),
    ({**JAW, "travel_mm": [0, 5000]}, "guide.travel_mm: spans 5000 mm; at most 2000 mm"),
    ({**JAW, "travel_mm": [0, float("nan")]}, "guide.travel_mm[1]: Input should be a finite number"),
])
def test_a_bad_guide_is_refused_with_the_reason(value, message):
    with pytest.raises(ValueError) as e:
        parse_guide(value, "clamp")
    assert message in str(e.value)


@pytest.mark.parametrize("kind", ["workpiece", "table"])
def test_only_fixtures_are_guided(kind):
    with pytest.raises(ValueError, match=f"guide: a {kind} is not guided; only clamp and support models"):
        parse_guide(JAW, kind)


def test_starts_cover_the_travel_at_most_a_step_apart_on_the_carrier():
    """On a carrier turned 30 deg and moved: every start lies on the guide (at the carrier's rotation
    and height), the ends are included and neighbours are at most GUIDE_STEP_MM apart."""
    T_table_carrier = make_pose(_rot_z(30.0), [400.0, 200.0, 0.0])
    starts = guide_start_poses(JAW, T_table_carrier)
    assert len(starts) == 11                      # 195 mm in steps of at most 20 mm
    travel = [guide_deviation(JAW, T_table_carrier, T).travel_mm for T in starts]
    assert travel[0] == pytest.approx(-95) and travel[-1] == pytest.approx(100)
    assert np.max(np.diff(travel)) <= GUIDE_STEP_MM + 1e-9
    for T, s in zip(starts, travel):
        assert np.allclose(T[:3, :3], _rot_z(30.0)) and T[2, 3] == pytest.approx(70.0)
        # the jaw's origin moves along the carrier's x axis, turned 30 deg in the table
        assert np.allclose(T[:3, 3], [400, 200, 70] + s * np.array([np.cos(np.pi / 6), np.sin(np.pi / 6), 0]))
    assert len(guide_start_poses(JAW, T_table_carrier, step_mm=100.0)) == 3
    # each start is searched locally: neighbours' windows overlap (the capture reaches past half a
    # step) and reach across the guide further than a pose may lie off it
    assert GUIDE_STEP_MM / 2 < GUIDE_CAPTURE_MM and OFF_GUIDE_MM < GUIDE_CAPTURE_MM and OFF_GUIDE_DEG < GUIDE_CAPTURE_DEG


def test_deviation_from_the_guide():
    T_table_carrier = make_pose(_rot_z(-50.0), [100.0, 50.0, 0.0])
    on = pose_at_travel(JAW, T_table_carrier, 40.0)
    d = guide_deviation(JAW, T_table_carrier, on)
    assert d.travel_mm == pytest.approx(40.0) and d.across_mm < 1e-9 and d.angle_deg < 1e-6 and d.on_guide()
    # 6 mm across the guide (carrier y), in the table frame
    side = make_pose(None, T_table_carrier[:3, :3] @ [0, 6.0, 0]) @ on
    d = guide_deviation(JAW, T_table_carrier, side)
    assert d.across_mm == pytest.approx(6.0) and d.travel_mm == pytest.approx(40.0) and not d.on_guide()
    # beyond the travel's end, and turned
    d = guide_deviation(JAW, T_table_carrier, pose_at_travel(JAW, T_table_carrier, 110.0))
    assert d.beyond_mm == pytest.approx(10.0) and not d.on_guide()
    turned = on @ make_pose(_rot_z(3.0))
    d = guide_deviation(JAW, T_table_carrier, turned)
    assert d.angle_deg == pytest.approx(3.0) and d.across_mm < 1e-9 and not d.on_guide()
    assert guide_deviation(JAW, T_table_carrier, on @ make_pose(_rot_z(1.0))).on_guide()
