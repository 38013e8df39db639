"""Independent collision check of swept sensor bodies against meshes, compared with an analytic test."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.transforms import make_pose
from app.planning.collision import BodyCylinder, ProbeBody, Scene, check_path, executed_polyline
from app.planning.obstacles import height_grid_from_meshes, regions_from_meshes
from app.planning.path import AxisSpeeds, PlannedMove, PlannedPath, ProbeParams
from app.planning.profile import plan_path_profile
from app.planning.reference import ReferenceOptions, plan_path_reference

BOX_LO = np.array([80.0, 130.0, 0.0])
BOX_HI = np.array([120.0, 170.0, 60.0])


def _box_scene():
    box = trimesh.creation.box(extents=BOX_HI - BOX_LO)
    return Scene([box], [make_pose(t=(BOX_LO + BOX_HI) / 2)], ["block"])


def _analytic_distance(p, q, r, z_from, z_to):
    """Min over 2000 samples along p->q of a signed gap between a vertical cylinder and the box:
    > 0 clear, < 0 overlapping (xy distance of the axis to the box minus r, when the z ranges overlap)."""
    t = np.linspace(0, 1, 2000)[:, None]
    c = p + t * (q - p)
    zlo, zhi = c[:, 2] + z_from, c[:, 2] + z_to
    gap_z = np.where((zhi < BOX_LO[2]) | (zlo > BOX_HI[2]), np.maximum(BOX_LO[2] - zhi, zlo - BOX_HI[2]), -np.inf)
    dxy = np.linalg.norm(np.maximum(0, np.maximum(BOX_LO[:2] - c[:, :2], c[:, :2] - BOX_HI[:2])), axis=1) - r
    return float(np.min(np.maximum(dxy, gap_z)))


def test_random_segments_agree_with_the_analytic_test():
    scene = _box_scene()
    body = ProbeBody((BodyCylinder(8.0, 20.0, 120.0),))
    rng = np.random.default_rng(0)
    n_hit = n_clear = 0
    for _ in range(150):
        p = rng.uniform([0, 60, -40], [200, 240, 80])
        q = rng.uniform([0, 60, -40], [200, 240, 80])
        gap = _analytic_distance(p, q, 8.0, 20.0, 120.0)
        if abs(gap) < 1.0:  # the circumscribed 16-gon is up to 0.16 mm wider; sampling error ~0.2 mm
            continue
        hit = bool(scene.check_segment(p, q, body))
        assert hit == (gap < 0), (p, q, gap)
        n_hit += hit
        n_clear += not hit
    assert n_hit > 20 and n_clear > 20


def test_body_inside_a_mesh_counts_as_collision():
    big = trimesh.creation.box(extents=(200, 200, 200))
    scene = Scene([big], [np.eye(4)], ["big"])
    body = ProbeBody((BodyCylinder(2.0, 0.0, 10.0),))
    assert scene.check_segment((0, 0, 0), (10, 10, 10), body) == [0]
    small = trimesh.creation.box(extents=(2, 2, 2))
    scene2 = Scene([small], [np.eye(4)], ["small"])
    wide = ProbeBody((BodyCylinder(50.0, -20.0, 20.0),))
    assert scene2.check_segment((0, 0, 0), (1, 0, 0), wide) == [0]  # the mesh inside the body


def test_noncoordinated_rapid_leaves_the_straight_line():
    # a rapid from (0, 0) to (200, 100) at the same z: x and y run at 100 mm/s, so the machine goes
    # diagonally to (100, 100) and then along y = 100 -> the block at y 130..170 is missed, but a
    # block near (150, 100) that the straight line (y = x / 2 -> y = 75 at x = 150) misses is hit.
    block = trimesh.creation.box(extents=(20, 20, 60))
    scene = Scene([block], [make_pose(t=(150, 100, 30))], ["block"])
    probe = ProbeParams(0.0, 2.0, radius_mm=3.0, length_mm=50)
    body = ProbeBody.from_probe(probe)
    move = PlannedMove(0, (0, 0, 10), (200, 100, 10), "straight", ((0, 0, 10), (200, 100, 10)), 0, 0)
    speeds = AxisSpeeds(6000, 6000, 6000)
    straight = PlannedPath("test", (move,), coordinated=True)
    rapid = PlannedPath("test", (move,), coordinated=False)
    assert executed_polyline(rapid, speeds).tolist() == [[0, 0, 10], [100, 100, 10], [200, 100, 10]]
    assert check_path(straight, scene, body, speeds).ok
    report = check_path(rapid, scene, body, speeds)
    assert not report.ok and report.hits[0].obstacle == "block"
    assert "hits block" in report.reason()


def test_both_planners_clear_a_stepped_scene():
    table = trimesh.creation.box(extents=(400, 300, 20))
    low = trimesh.creation.box(extents=(120, 80, 20))
    high = trimesh.creation.box(extents=(30, 30, 45))
    meshes = [table, low, high]
    poses = [make_pose(t=(200, 150, -10)), make_pose(t=(200, 150, 10)), make_pose(t=(230, 150, 42.5))]
    scene = Scene(meshes, poses, ["table", "low", "high"])
    probe = ProbeParams(30.0, 5.0, radius_mm=10.0, length_mm=120.0)
    body = ProbeBody.from_probe(probe)
    # measuring points (focal plane on the surfaces): table, low step, top of the high block, table
    pts = [(60, 150, 0), (170, 150, 20), (230, 150, 65), (170, 120, 20), (340, 40, 0)]
    for p in pts:
        assert scene.check_polyline([p], body).ok
    grid = height_grid_from_meshes(meshes[1:], poses[1:], bounds_xy_mm=(0, 0, 400, 300))
    regions = regions_from_meshes(meshes[1:], poses[1:], inflate_mm=probe.radius_mm)
    speeds = AxisSpeeds()
    ref = plan_path_reference(pts, regions, probe, ReferenceOptions())
    prof = plan_path_profile(pts, grid, probe)
    assert check_path(ref, scene, body, speeds).ok
    assert check_path(prof, scene, body, speeds).ok
    # a path that ignores the high block collides
    naive = PlannedPath("naive", (PlannedMove(0, pts[1], pts[3], "straight", (pts[1], (260, 150, 20), pts[3]), 0, 0),), True)
    assert not check_path(naive, scene, body, speeds).ok


def test_scene_needs_one_pose_per_mesh():
    with pytest.raises(ValueError, match="one pose per mesh"):
        Scene([trimesh.creation.box()], [])
