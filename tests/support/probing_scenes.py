"""Random probing scenes (issue 18, item 5): a box part on the table, on parallels or in a vise,
strap clamps on its edges (located or not), a free-standing block; the truth as primitives for the
independent checker (app.planning.program_check), the located meshes for the planner.

Frames: table frame, top face of the table at z = 0, mm. Every mesh is built in table coordinates
at its TRUE place (so its true pose is the identity); the located pose is a small translation error
(at most ``error_mm``), the stated 1-sigma ``error_mm / 3`` (the planner grows by 3 sigma).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from app.geometry.transforms import inv, make_pose
from app.planning.program_check import Box, TrueObstacle, VCylinder

T_MACHINE_TABLE = make_pose(t=(-400.0, -200.0, -300.0))
TRAVEL_MM = {"x": [-500.0, 500.0], "y": [-300.0, 300.0], "z": [-400.0, 0.0]}
TABLE_XY_MM = (0.0, 0.0, 800.0, 400.0)


@dataclass(frozen=True)
class ProbingScene:
    truth: tuple[TrueObstacle, ...]          # everything, with the table
    meshes: tuple[trimesh.Trimesh, ...]      # located objects only (table coordinates at the true place)
    poses: tuple[np.ndarray, ...]            # located T_table_obj (true: identity)
    names: tuple[str, ...]
    workpiece_index: int
    T_obj_datum: np.ndarray
    sigma_mm: float
    unlocated: tuple[tuple[str, float], ...]  # (name, height as modelled) of clamps not located
    mount: str

    def T_prog_table(self) -> np.ndarray:
        """The datum slot's frame, as the export writes it (X, Y, Z, C; the scene has no tilt)."""
        T_machine_datum = T_MACHINE_TABLE @ self.poses[self.workpiece_index] @ self.T_obj_datum
        return inv(T_machine_datum) @ T_MACHINE_TABLE


def _rz(deg: float) -> np.ndarray:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _mesh(parts) -> trimesh.Trimesh:
    out = []
    for g in parts:
        h = g.z1 - g.z0
        if isinstance(g, Box):
            T = make_pose(_rz(g.yaw_deg), (g.centre_xy[0], g.centre_xy[1], (g.z0 + g.z1) / 2))
            out.append(trimesh.creation.box(extents=(2 * g.half_xy[0], 2 * g.half_xy[1], h), transform=T))
        else:
            # circumscribed 64-gon: the planner's model is never smaller than the true cylinder
            r = g.radius / np.cos(np.pi / 64)
            m = trimesh.creation.cylinder(radius=r, height=h, sections=64)
            m.apply_translation((g.centre_xy[0], g.centre_xy[1], (g.z0 + g.z1) / 2))
            out.append(m)
    return trimesh.util.concatenate(out)


def random_probing_scene(rng: np.random.Generator, error_mm: float = 0.3, p_located: float = 0.75,
                         mount: str | None = None, above_jaws_mm: tuple[float, float] | None = None) -> ProbingScene:
    """A random scene; ``mount`` forces table / parallels / vise, ``above_jaws_mm`` draws how far a
    part in a vise stands above its jaws (default: jaws 10 mm high up to 10 mm above the part)."""
    L, W, H = rng.uniform(60, 220), rng.uniform(40, 150), rng.uniform(12, 80)
    yaw = float(rng.uniform(-40, 40))
    R = _rz(yaw)[:2, :2]
    c = np.array([rng.uniform(150, 650), rng.uniform(120, 280)])
    mount = mount or str(rng.choice(["table", "parallels", "vise"], p=[0.55, 0.25, 0.2]))
    objs: list[tuple[str, str, tuple, bool]] = []  # name, role, parts, located
    base = 0.0
    if mount == "parallels":
        base = float(rng.uniform(8, 32))
        for k, s in enumerate((-1, 1)):
            xy = c + R @ (s * L / 3, 0.0)
            objs.append((f"parallel_{k}", "support", (Box(tuple(xy), (4.0, W / 2 + 10), 0.0, base, yaw),), True))
    elif mount == "vise":
        base = 30.0
        objs.append(("vise_base", "support", (Box(tuple(c), (L / 2 + 40, W / 2 + 60), 0.0, base, yaw),), True))
        jaw_h = float(rng.uniform(10, H + 10)) if above_jaws_mm is None else H - float(rng.uniform(*above_jaws_mm))
        jaws = tuple(Box(tuple(c + R @ (0.0, s * (W / 2 + 12.5))), (min(L / 2, 75) + 10, 12.5), base, base + jaw_h, yaw)
                     for s in (-1, 1))
        objs.append(("vise_jaws", "fixture", jaws, True))
    top = base + H
    part = Box(tuple(c), (L / 2, W / 2), base, top, yaw)
    wp_index = len(objs)
    objs.append(("workpiece", "workpiece", (part,), True))
    if mount != "vise":
        for k in range(int(rng.integers(0, 4))):
            axis = int(rng.integers(2))
            sgn = float(rng.choice([-1.0, 1.0]))
            half = (L / 2, W / 2)
            d_local = np.zeros(2)
            d_local[axis] = sgn
            along = np.zeros(2)
            along[1 - axis] = rng.uniform(-0.4, 0.4) * 2 * half[1 - axis]
            edge = c + R @ (d_local * half[axis] + along)
            d = R @ d_local
            strap_yaw = float(np.degrees(np.arctan2(d[1], d[0])))
            parts = (Box(tuple(edge + 25 * d), (50.0, 12.5), top, top + 12, strap_yaw),
                     Box(tuple(edge + 65 * d), (12.5, 12.5), 0.0, top, strap_yaw),
                     VCylinder(tuple(edge + 30 * d), 6.0, 0.0, top + 32))
            objs.append((f"strap_clamp_{k}", "fixture", parts, bool(rng.uniform() < p_located)))
    if rng.uniform() < 0.3:
        for _ in range(50):
            xy = rng.uniform([40, 40], [760, 360])
            if np.linalg.norm(xy - c) > np.hypot(L, W) / 2 + 100:
                h = float(rng.uniform(20, 120))
                objs.append(("block", "other", (Box(tuple(xy), (20.0, 20.0), 0.0, h, float(rng.uniform(0, 90))),), True))
                break
    truth = [TrueObstacle("table", "support", (Box((400.0, 200.0), (400.0, 200.0), -60.0, 0.0),))]
    truth += [TrueObstacle(n, role, parts) for n, role, parts, _ in objs]
    meshes, poses, names, unlocated = [], [], [], []
    k_wp = 0
    for k, (n, role, parts, located) in enumerate(objs):
        if not located:
            unlocated.append((n, float(max(g.z1 for g in parts) - min(g.z0 for g in parts))))
            continue
        if k == wp_index:
            k_wp = len(meshes)
        u = rng.normal(size=3)
        u *= rng.uniform(0, error_mm) / np.linalg.norm(u)
        meshes.append(_mesh(parts))
        poses.append(make_pose(t=u))
        names.append(n)
    T_obj_datum = make_pose(_rz(yaw), (*(c + R @ (-L / 2, -W / 2)), top))  # front-left top corner
    return ProbingScene(tuple(truth), tuple(meshes), tuple(poses), tuple(names), k_wp, T_obj_datum,
                        error_mm / 3.0, tuple(unlocated), mount)
