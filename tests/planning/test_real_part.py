"""Planning and probing on a real machined part (featuretype.STL: pockets, slots, steps; see
external SOURCES.md): touch points, collision-free program, simulated probing by ray casting against
the displaced true mesh, least-squares offset; both planners between points in its pockets."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from app.geometry.mesh import load_mesh
from app.geometry.transforms import make_pose, transform_points
from app.planning.collision import BodyCylinder, ProbeBody, Scene, check_path
from app.planning.obstacles import LowestOf, height_grid_from_meshes, regions_from_meshes
from app.planning.path import AxisSpeeds, ProbeParams, path_time_s
from app.planning.probing import (
    ProbingParams,
    check_probing_program,
    choose_touch_points,
    gcode_positions,
    probing_gcode,
    refine_offset,
)
from app.planning.profile import ProfileOptions, plan_path_profile
from app.planning.reference import plan_path_reference

PARAMS = ProbingParams(ball_radius_mm=1.5, stylus_length_mm=40.0)
TRAVEL = ProbeParams(working_distance_mm=0.0, clearance_mm=5.0, radius_mm=15.0, length_mm=80.0)
BODY = ProbeBody((BodyCylinder(1.5, 0.0, 40.0), BodyCylinder(15.0, 40.0, 120.0)))
TOUCHING = ProbeBody((BodyCylinder(1.4, 0.1, 40.0), BodyCylinder(15.0, 40.0, 120.0)))


@pytest.fixture(scope="module")
def part(external_data):
    p = external_data / "trimesh_models" / "featuretype.STL"
    return load_mesh(p.read_bytes(), p.name, "inch")  # x +-63.5, y +-31.75, z 0..34.925 mm


def _rz(c_deg, t):
    c = np.radians(c_deg)
    return make_pose([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]], t)


def test_probing_a_real_part_recovers_its_true_pose(part):
    T_table_obj = _rz(4.0, (200, 150, 0))  # located
    T_obj_datum = make_pose(t=(-63.5, -31.75, 34.925))  # front-left top corner of the bounding box
    touches = choose_touch_points(part, T_table_obj, T_obj_datum, PARAMS)
    assert [t.name for t in touches] == ["x", "y1", "y2", "z"]
    grid = height_grid_from_meshes([part], [T_table_obj], uncertainty_mm=0.5)
    prog = probing_gcode(touches, grid, TRAVEL, (50, 50, 80), params=PARAMS, speeds=AxisSpeeds())
    dry = probing_gcode(touches, grid, TRAVEL, (50, 50, 80), params=PARAMS, speeds=AxisSpeeds(), dry_run=True)
    scene = Scene([part], [T_table_obj], ["featuretype"])
    assert check_probing_program(dry, scene, BODY, TOUCHING).ok
    assert check_probing_program(prog, scene, BODY, TOUCHING).ok

    # the part really sits 0.6 mm / -0.4 mm / 0.1 mm and 0.5 degrees away from where it was located
    T_true_obj = _rz(0.5, (0, 0, 0)) @ T_table_obj
    T_true_obj[:3, 3] = T_table_obj[:3, 3] + (0.6, -0.4, 0.1)
    true_mesh = trimesh.Trimesh(transform_points(T_true_obj, part.vertices), part.faces, process=False)
    r = PARAMS.ball_radius_mm
    tips = []
    pos = gcode_positions(prog.gcode)
    for (_, a), (g, b) in zip(pos[:-1], pos[1:]):
        if g != "G38.2":
            continue
        d = (b - a) / np.linalg.norm(b - a)
        lead = a + [0, 0, r] + r * d  # the ball's leading point
        loc, _, _ = true_mesh.ray.intersects_location([lead], [d])
        h = float(np.min(np.linalg.norm(loc - lead, axis=1)))
        assert h < np.linalg.norm(b - a)  # the probe trips before the end of its move
        tips.append(a + h * d)
    ref = refine_offset(touches, np.asarray(tips), T_table_obj @ T_obj_datum, ball_radius_mm=r)
    assert ref.ok, ref.reason
    assert np.allclose(ref.T_table_datum, T_true_obj @ T_obj_datum, atol=2e-3)
    assert ref.dc_deg == pytest.approx(0.5, abs=2e-3)


@pytest.mark.parametrize("kind", ["optical", "touch"])
def test_sensor_paths_between_pockets_of_a_real_part(part, kind):
    T = _rz(-20.0, (200, 150, 0))
    if kind == "optical":  # focal plane on the surface, sensor 30 mm above it
        optical, gap = ProbeParams(working_distance_mm=30.0, clearance_mm=5.0, radius_mm=10.0, length_mm=150.0), 0.0
    else:  # a thin touch probe 3 mm above the surface
        optical, gap = ProbeParams(working_distance_mm=0.0, clearance_mm=3.0, radius_mm=3.0, length_mm=150.0), 3.0
    scene = Scene([part], [T], ["featuretype"])
    body = ProbeBody.from_probe(optical)
    rng = np.random.default_rng(0)
    # measuring points on the part's surfaces (pocket floors, steps, top) that the sensor can occupy
    pts = []
    posed = trimesh.Trimesh(transform_points(T, part.vertices), part.faces, process=False)
    while len(pts) < 8:
        xy = transform_points(T, [[rng.uniform(-60, 60), rng.uniform(-29, 29), 0]])[0][:2]
        loc, _, _ = posed.ray.intersects_location([[xy[0], xy[1], 200.0]], [[0, 0, -1.0]])
        if len(loc) == 0:  # a through hole
            continue
        p = np.array([xy[0], xy[1], loc[:, 2].max() + gap])
        if scene.check_polyline([p], body).ok:
            pts.append(p)
    assert len({round(p[2], 1) for p in pts}) >= 3  # several surface levels
    speeds = AxisSpeeds(10000, 10000, 5000)
    regions = regions_from_meshes([part], [T], inflate_mm=optical.radius_mm, uncertainty_mm=0.5)
    both = LowestOf((height_grid_from_meshes([part], [T], uncertainty_mm=0.5),
                     regions_from_meshes([part], [T], uncertainty_mm=0.5)))
    ref = plan_path_reference(pts, regions, optical)
    prof = plan_path_profile(pts, both, optical, ProfileOptions(speeds=speeds))
    assert check_path(ref, scene, body, speeds).ok
    assert check_path(prof, scene, body, speeds).ok
    if kind == "optical":  # 30 mm working distance: everything on this 35 mm part is below the sensor
        assert path_time_s(prof, speeds) <= path_time_s(ref, speeds) + 1e-9
    else:
        assert path_time_s(prof, speeds) < 0.9 * path_time_s(ref, speeds)
