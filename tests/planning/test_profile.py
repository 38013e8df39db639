"""Profile planner: stays above the real profile, never longer than the reference, time-optimal
against a brute-force dynamic programme."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from app.planning.obstacles import PartTop, Region, RegionMap
from app.planning.path import AxisSpeeds, ProbeParams, path_length_mm, path_time_s, segment_times_s
from app.planning.profile import ProfileOptions, plan_path_profile, taut_path_sz, upper_hull
from app.planning.reference import ReferenceOptions, plan_path_reference

PROBE = ProbeParams(working_distance_mm=30.0, clearance_mm=5.0)
POINTS = [(20.0 * k, 10.0 * k, z) for k, z in enumerate([0.0, -6.0, -23.0, -33.0, -23.0, -6.0, 0.0])]


def _z_on_polyline(sz: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Lowest z of the (s, z) polyline at each s (vertical segments count with their lower end)."""
    out = np.full(len(s), np.inf)
    for (s0, z0), (s1, z1) in zip(sz[:-1], sz[1:]):
        if s1 == s0:
            continue
        inside = (s >= s0 - 1e-12) & (s <= s1 + 1e-12)
        out[inside] = np.minimum(out[inside], z0 + (s[inside] - s0) / (s1 - s0) * (z1 - z0))
    return out


def test_upper_hull_simple():
    s = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    z = np.array([0.0, 2.0, 1.0, 2.0, 0.0])
    assert upper_hull(s, z).tolist() == [[0, 0], [1, 2], [3, 2], [4, 0]]


@pytest.mark.parametrize("seed", range(20))
def test_taut_path_stays_above_every_step(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 40))
    L = float(rng.uniform(5, 300))
    Z = rng.uniform(-20, 40, n)
    z0, z1 = rng.uniform(-30, 50, 2)
    sz = taut_path_sz(L, z0, z1, Z)
    assert sz[0].tolist() == [0.0, z0] and sz[-1].tolist() == [L, z1]
    assert np.all(np.diff(sz[:, 0]) >= 0)
    edges = np.linspace(0, L, n + 1)
    for k in range(n):  # every point of step k (inner points and both ends) is above Z[k]
        s = np.linspace(edges[k], edges[k + 1], 7)
        assert np.all(_z_on_polyline(sz, s) >= Z[k] - 1e-9)


def _dp_min_time(L, z0, z1, Z, v_s, v_z):
    """Brute force: vertices at step edges, z from a fine grid of levels, then the best path."""
    n = len(Z)
    edges = np.linspace(0, L, n + 1)
    levels = np.unique(np.concatenate([Z, [z0, z1], np.linspace(min(Z.min(), z0, z1), max(Z.max(), z0, z1), 60)]))
    INF = np.inf
    # cost to be at edge 0 at level j: vertical climb from z0 (descending below z0 is never useful)
    best = np.where(levels >= z0 - 1e-12, np.abs(levels - z0) / v_z, INF)
    for k in range(n):
        ok_from = levels >= Z[k] - 1e-12
        step = np.maximum((edges[k + 1] - edges[k]) / v_s, np.abs(levels[None, :] - levels[:, None]) / v_z)
        cand = np.where(ok_from[:, None] & ok_from[None, :], best[:, None] + step, INF)
        best = cand.min(axis=0)
    end = best + np.where(levels >= z1 - 1e-12, (levels - z1) / v_z, INF)
    return float(end.min())


@pytest.mark.parametrize("seed", range(12))
def test_taut_path_time_is_not_beaten_by_brute_force(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(2, 12))
    L = float(rng.uniform(20, 200))
    Z = rng.uniform(0, 60, n) * (rng.uniform(size=n) < 0.5)
    z0, z1 = rng.uniform(-10, 40, 2)
    v_s, v_z = float(rng.uniform(50, 200)), float(rng.uniform(20, 200))
    sz = taut_path_sz(L, z0, z1, Z)
    d = np.abs(np.diff(sz, axis=0))
    t_hull = float(np.sum(np.maximum(d[:, 0] / v_s, d[:, 1] / v_z)))
    t_dp = _dp_min_time(L, z0, z1, Z, v_s, v_z)
    assert t_hull <= t_dp + 1e-9


def test_flat_profile_never_worse_than_the_reference():
    speeds = AxisSpeeds(6000, 6000, 3000)
    prof = plan_path_profile(POINTS, PartTop(6.0), PROBE)
    for opts in (ReferenceOptions(), ReferenceOptions(diagonal_down=True, up_diagonal=True)):
        ref = plan_path_reference(POINTS, PartTop(6.0), PROBE, opts)
        assert path_length_mm(prof) <= path_length_mm(ref) + 1e-9
        assert path_time_s(prof, speeds) <= path_time_s(ref, speeds) + 1e-9
    # below-safe ends climb vertically to the safe height -19 and never dip below it in between
    m = prof.moves[2]  # -23 -> -33
    assert m.waypoints[1][:2] == m.waypoints[0][:2] and m.waypoints[1][2] == pytest.approx(-19.0)
    assert min(w[2] for w in m.waypoints[1:-1]) == pytest.approx(-19.0)
    assert prof.coordinated


def test_ramps_over_a_single_narrow_obstacle():
    # a 10 mm wide wall of height 40 halfway along a 200 mm move at table level (touch probe, wd 0)
    wall = Region.rectangle(95, -50, 105, 50, 40.0, "wall")
    probe = ProbeParams(working_distance_mm=0.0, clearance_mm=2.0, radius_mm=3.0)
    pts = [(0.0, 0.0, 2.0), (200.0, 0.0, 2.0)]
    rm = RegionMap((wall,))
    prof = plan_path_profile(pts, rm, probe, ProfileOptions(step_mm=0.5))
    ref = plan_path_reference(pts, rm, probe, ReferenceOptions(box_margin_mm=3.0))
    assert ref.moves[0].pattern == "up_over_down" and ref.moves[0].safe_height_mm == 42.0
    W = np.asarray(prof.waypoints)
    assert len(W) == 4  # diagonal up, across the wall top, diagonal down
    # above the wall (within radius + one step), the path is at >= 42 mm
    top = W[(W[:, 0] >= 92 - 0.5) & (W[:, 0] <= 108 + 0.5)]
    assert len(top) == 2 and np.all(top[:, 2] >= 42.0 - 1e-9)
    assert path_length_mm(prof) < path_length_mm(ref) - 40  # the diagonals save most of the climb
    assert path_time_s(prof, AxisSpeeds()) < path_time_s(ref, AxisSpeeds())


def test_profile_ignores_obstacles_beside_the_corridor():
    # a tall block beside the move, inside the reference's box but 10 mm off the straight line
    block = Region.rectangle(80, 30, 120, 60, 80.0)
    probe = ProbeParams(working_distance_mm=0.0, clearance_mm=2.0, radius_mm=5.0)
    pts = [(0.0, 0.0, 2.0), (200.0, 100.0, 2.0)]  # at x = 100 the line is at y = 50: through it
    pts2 = [(0.0, 0.0, 2.0), (200.0, 60.0, 2.0)]  # at x = 100, y = 30: on its edge
    pts3 = [(0.0, 0.0, 2.0), (200.0, 40.0, 2.0)]  # at x = 100, y = 20: 10 mm clear, probe radius 5
    rm = RegionMap((block,))
    h = [plan_path_profile(p, rm, probe).moves[0].obstacle_height_mm for p in (pts, pts2, pts3)]
    assert h == [80.0, 80.0, 0.0]
    ref = plan_path_reference(pts3, rm, probe, ReferenceOptions(box_margin_mm=5.0))
    assert ref.moves[0].obstacle_height_mm == 80.0


def test_segment_times_use_the_slowest_axis():
    sp = AxisSpeeds(6000, 3000, 1200)  # 100, 50, 20 mm/s
    t = segment_times_s([(0, 0, 0), (100, 0, 0), (100, 100, 0), (100, 100, 10), (0, 0, 0)], sp)
    assert t.tolist() == pytest.approx([1.0, 2.0, 0.5, 2.0])


def test_single_and_vertical_moves():
    p = plan_path_profile([(0, 0, 0), (0, 0, 10)], PartTop(100.0), PROBE)
    assert p.waypoints == ((0, 0, 0), (0, 0, 10))
    for a, b in itertools.pairwise(p.waypoints):
        assert a != b


def test_detour_goes_around_a_tall_block_when_that_is_faster():
    # a tall block (80 mm) in the way of a move at table level; slow z axis -> around is faster
    from app.planning.obstacles import LowestOf
    from app.planning.profile import visibility_route

    block = RegionMap((Region.rectangle(90, -20, 110, 20, 80.0, "block"),))
    probe = ProbeParams(working_distance_mm=0.0, clearance_mm=2.0, radius_mm=3.0)
    pts = [(0.0, 0.0, 2.0), (200.0, 0.0, 2.0)]
    slow_z = AxisSpeeds(10000, 10000, 1000)
    over = plan_path_profile(pts, block, probe)
    around = plan_path_profile(pts, block, probe, ProfileOptions(speeds=slow_z))
    assert around.moves[0].pattern == "profile_detour"
    W = np.asarray(around.waypoints)
    assert np.all(W[:, 2] == 2.0)  # stays at table level
    assert np.max(np.abs(W[:, 1])) >= 20 + 3  # passes the block's side with the probe radius
    assert path_time_s(around, slow_z) < path_time_s(over, slow_z)
    # with a fast z axis, climbing over the block wins and the straight plan is kept
    fast_z = AxisSpeeds(10000, 10000, 100000)
    assert plan_path_profile(pts, block, probe, ProfileOptions(speeds=fast_z)).moves[0].pattern == "profile"
    # the route itself: one corner of the grown block, never inside it
    blocked = block.blocked_xy(0.0, 3.5)
    route = visibility_route((0, 0), (200, 0), blocked, slow_z)
    assert len(route) == 2 and all(not blocked.contains(__import__("shapely").Point(p)) for p in route)
    # LowestOf of two equal sources behaves like one
    both = LowestOf((block, block))
    assert plan_path_profile(pts, both, probe, ProfileOptions(speeds=slow_z)).waypoints == around.waypoints


def test_height_grid_bounds_the_mesh_and_blocks_around_it():
    import trimesh

    from app.geometry.transforms import make_pose
    from app.planning.obstacles import LowestOf, height_grid_from_meshes, regions_from_meshes

    box = trimesh.creation.box(extents=(40, 20, 30))
    T = make_pose(t=(100, 50, 15))
    grid = height_grid_from_meshes([box], [T], bounds_xy_mm=(0, 0, 60, 60), cell_mm=1.0, uncertainty_mm=0.5)
    x0, y0 = grid.origin_xy_mm
    H, W = grid.heights_mm.shape
    assert x0 + W * grid.cell_mm >= 122 and y0 <= 0  # grown to hold the mesh, keeps the asked bounds
    # an upper bound: every cell over the box is >= its top, and no more than 1.5 cells spill over
    assert grid.box_max_mm(0, (85, 45), (115, 55)) == pytest.approx(30.5)
    assert grid.box_max_mm(0, (0, 0), (75, 30)) == 0.0
    prof = grid.profile_mm(0, (60, 50), (140, 50), 5.0, 80)
    s = (np.arange(80) + 0.5)
    inside = (60 + s >= 80 - 5) & (60 + s <= 120 + 5)
    assert np.all(prof[inside] >= 30.5)
    assert np.all(prof[(60 + s < 80 - 5 - 4) | (60 + s > 120 + 5 + 4)] == 0.0)
    blocked = grid.blocked_xy(10.0, 5.0)
    lo = np.array(blocked.bounds)
    assert lo[0] <= 75 and lo[2] >= 125 and lo[0] >= 70 and lo[2] <= 130
    regions = regions_from_meshes([box], [T], uncertainty_mm=0.5)
    both = LowestOf((grid, regions))
    assert np.all(both.profile_mm(0, (60, 50), (140, 50), 5.0, 80) <= prof)
