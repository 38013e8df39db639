"""Random scenes for the travel-path planners: blocks, cylinders and L-shaped parts on a table, and
a sequence of measuring points on their surfaces that the sensor can occupy without collision.

Pure and seeded: ``random_scene(rng)`` returns the true meshes and poses (what the collision check
uses), the *located* poses (true poses shifted by a random error within ``uncertainty_mm``, what the
planners see) and the points. Frames: table frame, top face of the table at z = 0, mm.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh
from shapely.geometry import Polygon

from app.geometry.transforms import make_pose
from app.planning.collision import ProbeBody, Scene
from app.planning.path import ProbeParams

TABLE_XY_MM = (400.0, 300.0)

# an optical sensor (focus 30 mm below its lower end) and a touch probe (tip = focal point)
OPTICAL = ProbeParams(working_distance_mm=30.0, clearance_mm=5.0, radius_mm=12.0, length_mm=150.0)
TOUCH = ProbeParams(working_distance_mm=0.0, clearance_mm=3.0, radius_mm=4.0, length_mm=150.0)


@dataclass(frozen=True)
class PlanningScene:
    """meshes[0] is the table (top at z = 0). ``poses``: true T_table_obj; ``located_poses``: what a
    localisation with error <= ``uncertainty_mm`` per axis reported. ``points``: (N, 3) focal points."""

    meshes: tuple[trimesh.Trimesh, ...]
    names: tuple[str, ...]
    poses: tuple[np.ndarray, ...]
    located_poses: tuple[np.ndarray, ...]
    points: np.ndarray
    probe: ProbeParams
    uncertainty_mm: float
    truth: Scene = field(compare=False, repr=False)  # collision scene of the true meshes


def _rot_z(yaw_rad: float) -> np.ndarray:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _random_part(rng: np.random.Generator) -> tuple[trimesh.Trimesh, str]:
    kind = rng.choice(["box", "box", "box", "cylinder", "L"])
    h = float(rng.uniform(5, 90))
    if kind == "box":
        m = trimesh.creation.box(extents=(rng.uniform(15, 120), rng.uniform(15, 120), h))
    elif kind == "cylinder":
        m = trimesh.creation.cylinder(radius=float(rng.uniform(8, 45)), height=h, sections=32)
    else:
        a, b = rng.uniform(40, 110, 2)
        t1, t2 = rng.uniform(12, 0.6 * a), rng.uniform(12, 0.6 * b)
        poly = Polygon([(0, 0), (a, 0), (a, t2), (t1, t2), (t1, b), (0, b)])
        m = trimesh.creation.extrude_polygon(poly, h)
        m.apply_translation((-a / 2, -b / 2, -h / 2))
    return m, str(kind)


def random_scene(
    rng: np.random.Generator,
    probe: ProbeParams = OPTICAL,
    n_parts: tuple[int, int] = (2, 7),
    n_points: tuple[int, int] = (4, 9),
    uncertainty_mm: float = 0.5,
    touch_gap_mm: float = 3.0,
) -> PlanningScene:
    """A random scene and a random point sequence (see the module doc).

    Parts stand on the table or (30 %) on top of an earlier part (a step). Measuring points are
    random xy positions on the top surface below them; their z is that surface height for a sensor
    with a working distance, or ``touch_gap_mm`` above it for a touch probe (working distance 0).
    Points where the body would collide are drawn again.
    """
    W, D = TABLE_XY_MM
    table = trimesh.creation.box(extents=(W, D, 20.0))
    meshes, names, poses = [table], ["table"], [make_pose(t=(W / 2, D / 2, -10.0))]
    tops: list[tuple[np.ndarray, float]] = []
    for k in range(int(rng.integers(*n_parts))):
        m, kind = _random_part(rng)
        ext = m.extents
        if tops and rng.uniform() < 0.3:
            base_xy, base_z = tops[int(rng.integers(len(tops)))]
            xy = base_xy + rng.uniform(-20, 20, 2)
        else:
            xy = rng.uniform([40, 40], [W - 40, D - 40])
            base_z = 0.0
        T = make_pose(_rot_z(rng.uniform(0, np.pi)), (xy[0], xy[1], base_z + ext[2] / 2))
        meshes.append(m)
        names.append(f"{kind}_{k}")
        poses.append(T)
        tops.append((xy, base_z + ext[2]))
    located = [poses[0]] + [
        make_pose(T[:3, :3], T[:3, 3] + rng.uniform(-uncertainty_mm, uncertainty_mm, 3) / np.sqrt(3)) for T in poses[1:]
    ]
    scene = Scene(meshes, poses, names)
    combined = trimesh.util.concatenate(scene.meshes)
    body = ProbeBody.from_probe(probe)
    n = int(rng.integers(*n_points))
    pts: list[np.ndarray] = []
    for _ in range(50 * n):
        if len(pts) == n:
            break
        xy = rng.uniform([10, 10], [W - 10, D - 10])
        loc, _, _ = combined.ray.intersects_location([[xy[0], xy[1], 500.0]], [[0, 0, -1.0]])
        if len(loc) == 0:
            continue
        z = float(loc[:, 2].max()) + (touch_gap_mm if probe.working_distance_mm == 0 else 0.0)
        p = np.array([xy[0], xy[1], z])
        if scene.check_polyline([p], body).ok:
            pts.append(p)
    if len(pts) < 2:
        raise RuntimeError("could not place two measuring points in this scene; use another seed")
    return PlanningScene(tuple(meshes), tuple(names), tuple(poses), tuple(located), np.asarray(pts), probe,
                         uncertainty_mm, scene)
