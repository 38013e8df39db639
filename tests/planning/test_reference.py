"""The reference method with the reference's own worked example (working distance 30, clearance 5,
obstacles at +6 -> safe height -19; points at heights 0, -6, -23, -33, -23, -6, 0)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import make_pose
from app.planning.obstacles import (
    PartTop,
    PerMoveHeights,
    Region,
    RegionMap,
    part_top_from_meshes,
    regions_from_meshes,
)
from app.planning.path import ProbeParams
from app.planning.reference import ReferenceOptions, choose_pattern, plan_path_reference

PROBE = ProbeParams(working_distance_mm=30.0, clearance_mm=5.0)
HEIGHTS = [0.0, -6.0, -23.0, -33.0, -23.0, -6.0, 0.0]
# the example gives heights only; the points sit 20 mm apart along x, 10 mm apart along y
POINTS = [(20.0 * k, 10.0 * k, z) for k, z in enumerate(HEIGHTS)]
OBST = PartTop(6.0)


def test_safe_height_of_the_worked_example():
    assert PROBE.safe_height_mm(6.0) == -19.0


def test_worked_example_patterns_and_waypoints():
    path = plan_path_reference(POINTS, OBST, PROBE)
    assert [m.pattern for m in path.moves] == [
        "straight",  # 0 -> -6: both above -19
        "over_then_down",  # -6 -> -23: start safe, target below
        "up_over_down",  # -23 -> -33: both below
        "up_over_down",  # -33 -> -23
        "up_then_over",  # -23 -> -6: start below, target safe
        "straight",  # -6 -> 0
    ]
    assert all(m.safe_height_mm == -19.0 and m.obstacle_height_mm == 6.0 for m in path.moves)
    wps = [m.waypoints for m in path.moves]
    assert wps[0] == ((0, 0, 0), (20, 10, -6))
    assert wps[1] == ((20, 10, -6), (40, 20, -6), (40, 20, -23))
    assert wps[2] == ((40, 20, -23), (40, 20, -19), (60, 30, -19), (60, 30, -33))
    assert wps[3] == ((60, 30, -33), (60, 30, -19), (80, 40, -19), (80, 40, -23))
    assert wps[4] == ((80, 40, -23), (80, 40, -6), (100, 50, -6))
    assert wps[5] == ((100, 50, -6), (120, 60, 0))
    assert path.waypoints[0] == (0, 0, 0) and path.waypoints[-1] == (120, 60, 0)
    assert len(path.waypoints) == 1 + sum(len(w) - 1 for w in wps)
    assert path.coordinated is False


def test_worked_example_shortening_variants():
    path = plan_path_reference(POINTS, OBST, PROBE, ReferenceOptions(diagonal_down=True, up_diagonal=True))
    assert [m.pattern for m in path.moves] == [
        "straight",
        "diagonal_then_down",
        "up_over_down",
        "up_over_down",
        "up_then_diagonal",
        "straight",
    ]
    assert path.moves[1].waypoints == ((20, 10, -6), (40, 20, -19), (40, 20, -23))
    assert path.moves[4].waypoints == ((80, 40, -23), (80, 40, -19), (100, 50, -6))
    plain = plan_path_reference(POINTS, OBST, PROBE)
    for k in (1, 4):  # the variants are shorter than the patterns they replace
        L = lambda w: np.sum(np.linalg.norm(np.diff(np.asarray(w), axis=0), axis=1))  # noqa: E731
        assert L(path.moves[k].waypoints) < L(plain.moves[k].waypoints)


def test_each_variant_alone():
    only_down = plan_path_reference(POINTS, OBST, PROBE, ReferenceOptions(diagonal_down=True))
    assert only_down.moves[1].pattern == "diagonal_then_down" and only_down.moves[4].pattern == "up_then_over"
    only_up = plan_path_reference(POINTS, OBST, PROBE, ReferenceOptions(up_diagonal=True))
    assert only_up.moves[1].pattern == "over_then_down" and only_up.moves[4].pattern == "up_then_diagonal"


def test_worked_example_orthogonal():
    path = plan_path_reference(POINTS, OBST, PROBE, ReferenceOptions(orthogonal=True))
    assert path.moves[0].waypoints == ((0, 0, 0), (20, 10, 0), (20, 10, -6))  # xy first, then down
    assert path.moves[5].waypoints == ((100, 50, -6), (100, 50, 0), (120, 60, 0))  # up first, then xy
    for a, b in zip(path.waypoints[:-1], path.waypoints[1:]):
        moves_xy = a[:2] != b[:2]
        moves_z = a[2] != b[2]
        assert not (moves_xy and moves_z), (a, b)
    with pytest.raises(ValueError, match="orthogonal moves exclude"):
        ReferenceOptions(orthogonal=True, diagonal_down=True)


def test_choose_pattern_boundary_counts_as_safe():
    assert choose_pattern(-19.0, -19.0, -19.0) == "straight"
    assert choose_pattern(-19.0, -19.001, -19.0) == "over_then_down"


def test_per_move_heights():
    heights = [6.0, 6.0, 0.0, -20.0, 6.0, 6.0]
    path = plan_path_reference(POINTS, PerMoveHeights(tuple(heights)), PROBE)
    assert [m.safe_height_mm for m in path.moves] == [h - 25.0 for h in heights]
    # move 3 (-33 -> -23) under an obstacle at -20: S = -45, both points safe -> straight
    assert path.moves[3].pattern == "straight"
    # move 2 (-23 -> -33) under an obstacle at 0: S = -25, start safe, target below
    assert path.moves[2].pattern == "over_then_down" and path.moves[2].safe_height_mm == -25.0
    with pytest.raises(ValueError, match="6 heights given"):
        plan_path_reference(POINTS + [(0, 0, 0)], PerMoveHeights(tuple(heights)), PROBE)


def _pocket_maps():
    plate = Region.rectangle(0, 0, 100, 100, 20.0, "plate")
    pocket = Region.rectangle(40, 40, 60, 60, 5.0, "pocket")
    return plate, pocket


@pytest.mark.parametrize(
    "order, rule, expected",
    [
        ("plate_first", "later_wins", 5.0),
        ("pocket_first", "later_wins", 20.0),
        ("plate_first", "narrower_wins", 5.0),
        ("pocket_first", "narrower_wins", 5.0),
        ("pocket_first", "highest", 20.0),
    ],
)
def test_priority_rules_contained_region(order, rule, expected):
    plate, pocket = _pocket_maps()
    regions = (plate, pocket) if order == "plate_first" else (pocket, plate)
    m = RegionMap(regions, rule, base_height_mm=0.0)
    assert m.box_max_mm(0, (45, 45), (55, 52)) == expected
    assert m.height_at_mm([(50, 50)])[0] == expected
    # a move leaving the pocket sees the plate; one leaving the plate sees the base and the plate
    assert m.box_max_mm(0, (45, 45), (80, 45)) == 20.0
    assert m.box_max_mm(0, (150, 150), (160, 170)) == 0.0
    # the reference's safe height for a pocket-only move
    path = plan_path_reference([(45, 45, 5), (55, 52, 5)], m, ProbeParams(0.0, 2.0))
    assert path.moves[0].safe_height_mm == expected + 2.0


def test_narrower_wins_on_partial_overlap():
    wide = Region.rectangle(0, 0, 60, 60, 10.0, "wide")  # min width 60
    strip = Region.rectangle(50, -20, 58, 100, 30.0, "strip")  # min width 8, sticks out on both sides
    for regions in ((wide, strip), (strip, wide)):
        m = RegionMap(regions, "narrower_wins")
        assert m.height_at_mm([(55, 30)])[0] == 30.0
        assert m.box_max_mm(0, (52, 20), (56, 40)) == 30.0
    lw = RegionMap((strip, wide), "later_wins")
    assert lw.height_at_mm([(55, 30)])[0] == 10.0
    assert lw.box_max_mm(0, (52, 20), (56, 40)) == 10.0
    assert lw.box_max_mm(0, (52, 20), (56, 80)) == 30.0  # the strip still holds outside the wide region


def test_box_margin_grows_the_box():
    m = RegionMap((Region.rectangle(10, 10, 20, 20, 40.0),), "later_wins")
    assert m.box_max_mm(0, (0, 0), (0, 30)) == 0.0
    assert m.box_max_mm(0, (0, 0), (0, 30), margin_mm=10.0) == 40.0


def test_obstacles_from_meshes():
    box = trimesh.creation.box(extents=(40, 20, 30))  # centred on its origin
    T = make_pose(t=(100, 50, 15))  # standing on the table, top at z = 30
    top = part_top_from_meshes([box], [T], uncertainty_mm=0.5)
    assert top.height_mm == pytest.approx(30.5)
    rm = regions_from_meshes([box], [T], inflate_mm=5.0, uncertainty_mm=0.5)
    assert rm.regions[0].height_mm == pytest.approx(30.5)
    # footprint x 80..120 grown by 5.5 -> a move along x = 74 touches it, x = 74.4 + anything beyond not
    assert rm.box_max_mm(0, (74.6, 0), (74.6, 100)) == pytest.approx(30.5)
    assert rm.box_max_mm(0, (74.4, 0), (74.4, 100)) == 0.0
    with pytest.raises(ValueError, match="one pose per mesh"):
        regions_from_meshes([box], [])
