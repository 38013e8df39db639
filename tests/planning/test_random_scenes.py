"""Both planners on random scenes: no collision with the true meshes; the profile planner is faster;
the checker is not vacuous (straight lines between the points do collide)."""

from __future__ import annotations

import numpy as np
import pytest

from app.planning.collision import ProbeBody, check_path
from app.planning.obstacles import PartTop, height_grid_from_meshes, regions_from_meshes
from app.planning.path import AxisSpeeds, path_length_mm, path_time_s
from app.planning.profile import plan_path_profile
from app.planning.reference import plan_path_reference
from app.synth.planning_scenes import OPTICAL, TABLE_XY_MM, TOUCH, random_scene

SPEEDS = AxisSpeeds(10000, 10000, 5000)


@pytest.mark.slow
def test_random_scenes_collision_free_and_profile_faster():
    rng = np.random.default_rng(0)
    t_ref = t_prof = l_ref = l_prof = 0.0
    naive_hits = 0
    for k in range(16):
        sc = random_scene(rng, probe=OPTICAL if k % 2 == 0 else TOUCH)
        probe, parts, located = sc.probe, sc.meshes[1:], sc.located_poses[1:]
        truth = sc.truth
        body = ProbeBody.from_probe(probe)
        regions = regions_from_meshes(parts, located, inflate_mm=probe.radius_mm, uncertainty_mm=sc.uncertainty_mm)
        grid = height_grid_from_meshes(parts, located, bounds_xy_mm=(0, 0, *TABLE_XY_MM), uncertainty_mm=sc.uncertainty_mm)
        ref = plan_path_reference(sc.points, regions, probe)
        prof = plan_path_profile(sc.points, grid, probe)
        assert check_path(ref, truth, body, SPEEDS).ok, k
        assert check_path(prof, truth, body, SPEEDS).ok, k
        t_ref += path_time_s(ref, SPEEDS)
        t_prof += path_time_s(prof, SPEEDS)
        l_ref += path_length_mm(ref)
        l_prof += path_length_mm(prof)
        # the same points joined by straight lines (an obstacle height below everything)
        naive = plan_path_reference(sc.points, PartTop(-1000.0), probe)
        assert all(m.pattern == "straight" for m in naive.moves)
        naive_hits += not check_path(naive, truth, body, SPEEDS).ok
    assert t_prof < 0.9 * t_ref
    assert l_prof < 0.95 * l_ref
    assert naive_hits >= 4
