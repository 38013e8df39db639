"""Setups as a shop clamps them, for generated scenes: a part on the table, held in the vise on
parallels between the jaws, or lying on a pair of parallels on the table.

Each function returns the :class:`~app.synth.scene.SceneObject` list (the workpiece first) with
poses that are physically possible (the part stands on the parallels' top faces, the parallels on
the vise's seat or the table, nothing intersects); the library models they use are the example
library's (:func:`app.geometry.parts.example_library`). All poses ``T_table_obj``, mm.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import trimesh

from app.geometry.transforms import inv, make_pose, pose_from_xyz_euler, transform_points
from app.synth.scene import SceneObject, place_on_table

MODES = ("table", "vise", "parallels")


def _part_pose(mesh: trimesh.Trimesh, T_table_frame: np.ndarray, x_mm: float, y_mm: float, yaw_deg: float,
               z_mm: float) -> np.ndarray:
    """The part (CAD orientation, turned ``yaw_deg`` about its z) with its bounding-box centre at
    (x, y) and its lowest point at ``z_mm`` in the frame ``T_table_frame``; returned in the table frame."""
    return T_table_frame @ place_on_table(mesh, x_mm, y_mm, yaw_deg, z_mm)


def on_table(rng, name: str, mesh: trimesh.Trimesh, x: float, y: float) -> list[SceneObject]:
    return [SceneObject(name, mesh, place_on_table(mesh, x, y, rng.uniform(0, 360)),
                        albedo=float(rng.uniform(0.5, 0.75)))]


def on_parallels(rng, name: str, mesh: trimesh.Trimesh, parallel: trimesh.Trimesh, parallel_name: str,
                 x: float, y: float) -> list[SceneObject]:
    """Two parallels on the table under the part's long sides (a fifth in from its ends), the part on
    their tops; the whole set turned at random about the table normal."""
    c = rng.uniform(0, 360)
    T = pose_from_xyz_euler(x, y, 0.0, c_deg=c)
    ext = mesh.extents
    yaw = 0.0 if ext[0] >= ext[1] else 90.0                 # the part's long side along the set's x
    width = float(min(ext[0], ext[1]))
    h = float(parallel.bounds[1, 2])
    objs = [SceneObject(name, mesh, _part_pose(mesh, T, 0.0, 0.0, yaw, h), albedo=float(rng.uniform(0.5, 0.75)))]
    for k, side in enumerate((-1, 1)):
        off = side * max(0.5 * width - 0.2 * width, 6.0)    # under the part, inside its footprint
        Tp = T @ make_pose(None, [0.0, off, 0.0])
        objs.append(SceneObject(f"{parallel_name}#{k}", parallel, Tp @ place_on_table(parallel, 0.0, 0.0, 0.0),
                                albedo=0.38))
    return objs


def in_vise(rng, name: str, mesh: trimesh.Trimesh, vise: trimesh.Trimesh, vise_name: str, seat: dict,
            parallel: trimesh.Trimesh, parallel_name: str, x: float, y: float) -> list[SceneObject] | None:
    """The part between the vise's jaws against the fixed jaw (x = 0 of the vise frame), standing on two
    parallels on the seat; the vise turned at random. None when the part is wider than the opening."""
    xs = [p[0] for p in seat["outline_xy"]]
    opening = max(xs) - min(xs)
    ext = mesh.extents
    yaw = 0.0 if ext[0] <= ext[1] else 90.0                 # the part's narrow side across the jaws
    across = float(min(ext[0], ext[1]))
    if across > opening - 1.0:
        return None
    c = rng.uniform(0, 360)
    # the vise's seat centre at (x, y) on the table
    T_vise = pose_from_xyz_euler(x, y, 0.0, c_deg=c) @ make_pose(None, [-0.5 * opening, 0.0, 0.0])
    h_seat = float(seat["z_mm"])
    h_par = float(parallel.bounds[1, 2])
    objs = [SceneObject(name, mesh, _part_pose(mesh, T_vise, 0.5 * across + 0.5, 0.0, yaw, h_seat + h_par),
                        albedo=float(rng.uniform(0.5, 0.75))),
            SceneObject(vise_name, vise, T_vise, albedo=0.4)]
    t = float(parallel.extents[1])
    xps = (0.5 * t + 1.0, across - 0.5 * t - 1.0) if across > 2 * t + 4 else (0.5 * across + 0.5,)
    for k, xp in enumerate(xps):            # along the jaws, under the part's two edges
        Tp = T_vise @ pose_from_xyz_euler(xp, 0.0, h_seat, c_deg=90.0)
        objs.append(SceneObject(f"{parallel_name}#{k}", parallel, Tp, albedo=0.38))
    return objs


def under_strap_clamps(rng, part: SceneObject, max_clamps: int = 2) -> list[SceneObject]:
    """Strap clamp sets pressing ``part`` (lying on the table) onto the table from opposite sides: each
    set built for its place (``parts.strap_clamp``: 125 or 175 mm, its strap's nose 3 mm below the
    underside resting on the part's top 8 mm in from an edge), its heel block on the table outside
    the part. A side whose strap would cross a higher face of the part (a bracket's flange) gets no
    clamp. Returns the sets, at most ``max_clamps``."""
    from app.geometry import parts

    mesh, T = part.mesh, part.T_table_obj
    T_obj_table = inv(T)
    R = T[:3, :3]
    b = mesh.bounds
    c = transform_points(T, ((b[0] + b[1]) / 2)[None])[0]
    out: list[SceneObject] = []
    sides = [(R[:, 0], 0.5 * (b[1, 0] - b[0, 0])), (R[:, 1], 0.5 * (b[1, 1] - b[0, 1]))]
    k0 = int(rng.integers(0, 2))
    for a, half in (sides[k0], sides[1 - k0]):
        for sign in (1.0, -1.0):
            if len(out) >= max_clamps:
                return out
            d = sign * np.array([a[0], a[1], 0.0]) / max(np.hypot(a[0], a[1]), 1e-9)
            # the part's top along the strap's path, from 8 mm in from the edge outwards (rays cast down)
            path = np.array([c + d * (half - t) for t in (8.0, 6.0, 3.0, 1.0)])
            hit, ray, _ = mesh.ray.intersects_location(transform_points(T_obj_table, path + [0.0, 0.0, 1e3]),
                                                       np.tile(T_obj_table[:3, :3] @ [0.0, 0.0, -1.0], (len(path), 1)))
            z_hit = transform_points(T, hit)[:, 2] if len(hit) else np.zeros(0)
            tops = [float(z_hit[ray == i].max()) if np.any(ray == i) else -1.0 for i in range(len(path))]
            if tops[0] <= 0.0 or max(tops) > tops[0] + 0.5:
                continue
            length = float(rng.choice([125.0, 175.0]))
            clamp = parts.strap_clamp(length_mm=length, clamp_height_mm=tops[0] + 3.0,
                                      width_mm=25.0 if length < 150 else 32.0,
                                      thickness_mm=16.0 if length < 150 else 20.0)
            x_nose = 0.55 * length
            o = path[0] + d * (x_nose - 6.0)          # the stud; its +x (towards the nose) is -d
            yaw = float(np.degrees(np.arctan2(-d[1], -d[0])))
            out.append(SceneObject(f"strap_clamp#{len(out)}", clamp, pose_from_xyz_euler(o[0], o[1], 0.0, c_deg=yaw),
                                   albedo=float(rng.uniform(0.2, 0.35))))
            break
    return out


# --------------------------------------------------------------------------------------------------
# whole scenes for the benchmarks: the same shape as the devset's (app.synth.devset.DevsetScene)
# --------------------------------------------------------------------------------------------------

WORKPIECES = ("pin_block_32", "flange_plate_80", "bracket_140", "base_plate_300")


# Scenes from this index on add shop conditions (shop_conditions); the ones before keep theirs.
SHOP_FROM = 24
# Scenes from this index on are parts on the table under strap clamp sets (under_strap_clamps), with
# the shop conditions; the ones before keep theirs.
CLAMPS_FROM = 36


def shop_conditions(k: int, objs: list[SceneObject]) -> dict:
    """What scene ``k`` adds to the fixture set: a spindle with its tool above the part (in view
    from most angles), vignetting (30-60 % darker in the corners), a low lamp (hard long shadows),
    every other scene a dark part on a dark table, and every other one a low camera (20-35 deg).
    Drawn from a generator of their own, so the scene's other draws stay as they were."""
    rng = np.random.default_rng(9000 + k)
    part = objs[0]
    top = float(transform_points(part.T_table_obj, part.mesh.vertices)[:, 2].max())
    c = part.T_table_obj[:3, 3]
    z0 = top + rng.uniform(60.0, 200.0)
    spindle = trimesh.util.concatenate([
        trimesh.creation.cylinder(radius=5.0, height=60.0, sections=24, transform=make_pose(None, [0, 0, 30.0])),
        trimesh.creation.cylinder(radius=40.0, height=250.0, sections=48, transform=make_pose(None, [0, 0, 185.0]))])
    off = rng.uniform(-60.0, 60.0, 2)
    out = list(objs) + [SceneObject("spindle", spindle, make_pose(None, [c[0] + off[0], c[1] + off[1], z0]),
                                    albedo=0.6)]
    dark = bool(k % 2 == 0)
    if dark:
        out[0] = dataclasses.replace(part, albedo=float(rng.uniform(0.15, 0.28)))
    return {"objects": out, "rng": rng, "vignetting": float(rng.uniform(0.3, 0.6)), "low_view": bool(k % 4 < 2),
            "table_albedo": 0.28 if dark else 0.42}


def synth_entry(k: int) -> dict:
    """Scene k of the generated set: the fixture mode cycles table / vise / parallels, the workpiece
    cycles through the example library's four."""
    if k >= CLAMPS_FROM:                # on the table under strap clamps
        return {"source": "synth", "index": k, "scene_id": f"synth_{k:03d}", "fixture_mode": "table",
                "workpiece": WORKPIECES[k % len(WORKPIECES)], "clamps": True}
    return {"source": "synth", "index": k, "scene_id": f"synth_{k:03d}", "fixture_mode": MODES[k % 3],
            "workpiece": WORKPIECES[(k // 3) % len(WORKPIECES)]}


def synth_scene(entry: dict, width: int = 1920, height: int = 1200):
    """Render scene ``entry`` (:func:`synth_entry`): (DevsetScene, image). A camera 450-1300 mm from
    the part at 20-85 deg elevation (low views and top views), the example library's lens
    distortions, shadows, noise, blur, JPEG quality 80-95 or PNG, darker or brighter parts; parts
    that do not fit the vise go on parallels instead."""
    from app.geometry import parts
    from app.synth.devset import DevsetScene
    from app.synth.scene import Scene, look_at_pose, random_intrinsics, render_scene
    from app.vision.localize import Candidate

    k = int(entry["index"])
    rng = np.random.default_rng(7000 + k)
    lib = {m.key: m for m in parts.example_library()}
    wp = lib[entry["workpiece"]]
    x, y = rng.uniform(300, 500), rng.uniform(160, 240)
    mode = entry["fixture_mode"]
    par = lib["parallel_150x25x8"]
    objs = None
    if mode == "vise":
        v = lib["vise_150"]
        objs = in_vise(rng, wp.key, wp.mesh, v.mesh, v.key, v.support_surfaces[0], par.mesh, par.key, x, y)
        if objs is None:
            mode = "parallels"
    if mode == "parallels":
        objs = on_parallels(rng, wp.key, wp.mesh, par.mesh, par.key, x, y)
    if mode == "table":
        objs = on_table(rng, wp.key, wp.mesh, x, y)
    if entry.get("clamps"):
        objs = objs + under_strap_clamps(np.random.default_rng(11000 + k), objs[0])
    target = objs[0].T_table_obj[:3, 3] * [1, 1, 0]
    table, layout = parts.tslot_table(), parts.tslot_table_layout()
    # scenes from SHOP_FROM on add what a shop shows besides (own generator, so scenes 0.. keep theirs)
    shop = shop_conditions(k, objs) if k >= SHOP_FROM else None
    if shop is not None:
        objs = shop["objects"]
    for _ in range(30):
        K, dist = random_intrinsics(rng, width, height)
        d, el, az = rng.uniform(450, 1300), np.radians(rng.uniform(20, 85)), rng.uniform(0, 2 * np.pi)
        if shop is not None and shop["low_view"]:
            el = np.radians(shop["rng"].uniform(20, 35))
        pos = target + d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        T_cam_table = look_at_pose(pos, target + rng.uniform(-60, 60, 3) * [1, 1, 0], rng.uniform(-10, 10))
        light = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.3), rng.uniform(0.5, 1.0)])
        if shop is not None:
            light[2] = shop["rng"].uniform(0.3, 0.5)          # a low lamp: long hard shadows
        scene = Scene(width=width, height=height, K=K, dist=dist, T_cam_table=T_cam_table, table_mesh=table,
                      table_layout=layout, objects=objs, light_dir_table=light / np.linalg.norm(light),
                      noise_sigma=float(rng.uniform(1.0, 3.0)), blur_sigma_px=float(rng.uniform(0.4, 1.0)),
                      jpeg_quality=int(rng.integers(80, 96)) if rng.random() < 0.5 else None,
                      ambient=float(rng.uniform(0.2, 0.45)),
                      **({} if shop is None else {"vignetting": shop["vignetting"],
                                                  "table_albedo": shop["table_albedo"]}))
        r = render_scene(scene, rng)
        if np.count_nonzero(r.labels == 2) > 2000:
            break
    seen = [int(i) for i, v in r.truth["marker_visible"].items() if v]
    # visible share of the part's silhouette (pinhole silhouette of the part alone vs its pixels seen)
    from app.geometry.model_edges import render_depth
    from app.geometry.transforms import transform_points
    V = transform_points(T_cam_table @ objs[0].T_table_obj, wp.mesh.vertices)
    sil = int(np.isfinite(render_depth([(V, wp.mesh.faces)], K, width, height, max_pixel_tests=50_000_000)[0]).sum())
    vis_frac = float(min(1.0, np.count_nonzero(r.labels == 2) / max(sil, 1)))
    gt = {"visible_marker_ids": seen, "fixture_mode": mode,
          "objects": [{"name": o.name.replace("#", "_"), "kind": "clamp", "subtype": "strap_clamp", "mesh_obj": o.mesh,
                       "T_table_object": o.T_table_obj.tolist()} for o in objs if o.name.startswith("strap_clamp")]}
    wpd = {"name": wp.key, "mesh_obj": wp.mesh, "T_table_object": objs[0].T_table_obj.tolist(),
           "visible_fraction": vis_frac}
    fixtures = [Candidate(m.key, m.mesh, kind=m.kind, support_surfaces=m.support_surfaces)
                for m in (lib["vise_150"], par)]
    sc = DevsetScene(gt=gt, K=K, dist=dist, layout=layout, workpiece=wpd,
                     table_candidate=Candidate("table", table, kind="table"), fixture_candidates=fixtures)
    return sc, r.image
