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
    # clamped: its side against the fixed jaw's face (0.05 mm apart, so that the renderer does not
    # see two coplanar faces; until the twentieth stop 0.5 mm: a part that no jaw touched)
    objs = [SceneObject(name, mesh, _part_pose(mesh, T_vise, 0.5 * across + 0.05, 0.0, yaw, h_seat + h_par),
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


def spindle_mesh(radius_mm: float) -> trimesh.Trimesh:
    """A spindle with its tool (frame: the tool's tip, z up): tool d10 x 60, quill ``radius_mm`` x 250."""
    return trimesh.util.concatenate([
        trimesh.creation.cylinder(radius=5.0, height=60.0, sections=24, transform=make_pose(None, [0, 0, 30.0])),
        trimesh.creation.cylinder(radius=radius_mm, height=250.0, sections=48,
                                  transform=make_pose(None, [0, 0, 185.0]))])


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
    spindle = spindle_mesh(40.0)
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


# --------------------------------------------------------------------------------------------------
# the vise in shade: a family of its own (the devset's vise misses), the scenes above unchanged
# --------------------------------------------------------------------------------------------------

VISE_SHADE_N = 16
VISES = ("vise_150", "vise_125")
# per scene k: the part in the jaws cycles a tenon plate (a plate on a tenon held in the jaws, the
# plate over the jaws), the library's pin block, a tenon plate again
VISE_SHADE_PARTS = ("tenon_plate", "pin_block_32", "tenon_plate")


def vise_shade_entry(k: int) -> dict:
    """Scene k of the vise-in-shade family (:func:`vise_shade_scene`): the vise cycles vise_150 /
    vise_125, the part :data:`VISE_SHADE_PARTS`; every scene is a vise scene."""
    return {"source": "synth", "family": "vise_shade", "index": k, "scene_id": f"vshade_{k:03d}",
            "fixture_mode": "vise", "vise": VISES[k % 2],
            "workpiece": VISE_SHADE_PARTS[(k // 2) % len(VISE_SHADE_PARTS)]}


def tenon_plate(tenon_mm: tuple[float, float, float], plate_mm: tuple[float, float, float, float],
                chamfer_mm: float = 20.0, hole_d_mm: float = 14.0) -> trimesh.Trimesh:
    """A plate on a tenon, one body: the tenon a box ``tenon_mm`` = (across, along, high) from the
    origin (frame: its front-left bottom corner, x across the jaws, y along them, z up), the plate
    ``plate_mm`` = (over the -x side, over the +x side, over each y end, thickness) on its top, its
    (+x, +y) corner chamfered ``chamfer_mm`` and a hole ``hole_d_mm`` through it over the -x side:
    seen from above the plate hides the tenon, and without these a half turn would look the same.
    Held by the tenon in a vise, the plate overhangs the jaws and shades them. mm."""
    from shapely.geometry import Polygon

    w, L, h = tenon_mm
    ox0, ox1, oy, t = plate_mm
    x0, x1, y0, y1 = -ox0, w + ox1, -oy, L + oy
    c = chamfer_mm
    outline = Polygon([(x0, y0), (x1, y0), (x1, y1 - c), (x1 - c, y1), (x0, y1)])
    plate = trimesh.creation.extrude_polygon(outline, t)
    plate.apply_translation([0.0, 0.0, h])
    tenon = trimesh.creation.box(bounds=[[0.0, 0.0, 0.0], [w, L, h]])
    hole = trimesh.creation.cylinder(radius=0.5 * hole_d_mm, height=t + 2.0, sections=32,
                                     transform=make_pose(None, [0.5 * x0, y0 + 0.3 * (y1 - y0), h + 0.5 * t]))
    body = trimesh.boolean.union([tenon, plate], engine="manifold")
    return trimesh.boolean.difference([body, hole], engine="manifold")


# the share of the vise's top faces (upward, area-weighted, not under the part) the spindle and the
# part shade at least, unless 8 spindle places all fall short (the best of them is kept)
MIN_TOP_SHADE = 0.3


def _top_points(mesh: trimesh.Trimesh, T_table_obj: np.ndarray, rng, n: int = 1500) -> np.ndarray:
    """``n`` points (table frame, mm) spread over ``mesh``'s upward faces (normal z > 0.5) by area."""
    up = np.nonzero(mesh.face_normals[:, 2] > 0.5)[0]
    f = rng.choice(up, n, p=mesh.area_faces[up] / mesh.area_faces[up].sum())
    a, b = rng.random(n), rng.random(n)
    flip = a + b > 1.0
    a[flip], b[flip] = 1.0 - a[flip], 1.0 - b[flip]
    tri = mesh.triangles[f]
    P = tri[:, 0] + a[:, None] * (tri[:, 1] - tri[:, 0]) + b[:, None] * (tri[:, 2] - tri[:, 0])
    return transform_points(T_table_obj, P)


def _shaded(P: np.ndarray, light: np.ndarray, occluders: list[SceneObject]) -> np.ndarray:
    """Which of the points ``P`` (table frame, mm) the ``occluders`` shade from the directional
    ``light`` (unit, towards the lamp): rays cast from 0.2 mm off each point."""
    occ = trimesh.util.concatenate([o.mesh.copy().apply_transform(o.T_table_obj) for o in occluders])
    return occ.ray.intersects_any(P + 0.2 * light, np.tile(light, (len(P), 1)))


def vise_shade_objects(rng, k: int, lib: dict, vise_key: str, part_key: str, light: np.ndarray
                       ) -> list[SceneObject]:
    """The set of scene ``k``: the part on parallels in the vise (:func:`in_vise`; a tenon plate is
    placed by its tenon, the plate 4-12 mm above the jaw tops), and a spindle placed so that the
    shadow of its quill (low lamp ``light``, unit, table frame) falls across the vise's top
    (:data:`MIN_TOP_SHADE`). All poses
    in the table frame, mm; the workpiece first, then the vise, the parallels, the spindle."""
    v, par = lib[vise_key], lib["parallel_150x25x8"]
    seat = v.support_surfaces[0]
    xs = [p[0] for p in seat["outline_xy"]]
    opening = max(xs) - min(xs)
    jaw_top = float(v.mesh.bounds[1, 2])
    x, y = rng.uniform(300, 500), rng.uniform(160, 240)
    if part_key == "tenon_plate":
        h_par = float(par.mesh.bounds[1, 2])
        w = opening - rng.uniform(12.0, 30.0)                       # across the jaws, clear of the moving jaw
        L = rng.uniform(0.55, 0.9) * 2 * abs(seat["outline_xy"][0][1])
        h = jaw_top - (float(seat["z_mm"]) + h_par) + rng.uniform(4.0, 12.0)
        plate = (rng.uniform(30.0, 90.0), rng.uniform(30.0, 90.0), rng.uniform(0.0, 50.0), rng.uniform(12.0, 25.0))
        mesh = tenon_plate((w, max(L, w + 10.0), h), plate, chamfer_mm=rng.uniform(15.0, 25.0))
        # placed by its tenon (the same frame): in_vise sees a box as narrow as the tenon
        tenon = trimesh.creation.box(bounds=[[0.0, 0.0, 0.0], [w, max(L, w + 10.0), h]])
        objs = in_vise(rng, part_key, tenon, v.mesh, v.key, seat, par.mesh, par.key, x, y)
        objs[0] = SceneObject(part_key, mesh, objs[0].T_table_obj, albedo=objs[0].albedo)
    else:
        mesh = lib[part_key].mesh
        objs = in_vise(rng, part_key, mesh, v.mesh, v.key, seat, par.mesh, par.key, x, y)
    if k % 4 >= 2:                                                  # a dark part (oxide, cast iron)
        objs[0] = dataclasses.replace(objs[0], albedo=float(rng.uniform(0.15, 0.28)))
    # the spindle: its quill's shadow passes through a point p of the vise's top (between the fixed
    # jaw's back and the moving jaw's far side); from the low lamp it reaches far beyond the vise.
    # Drawn again (up to 8 times) until at least MIN_TOP_SHADE of the vise's top faces not under the
    # part are in shade (the part's and the spindle's shadows): the band may miss the vise or fall
    # where the part covers the vise anyway
    T_vise = objs[1].T_table_obj
    top = max(float(transform_points(objs[0].T_table_obj, mesh.vertices)[:, 2].max()), jaw_top)
    tops = _top_points(v.mesh, T_vise, np.random.default_rng(17000 + k))
    tops = tops[~_shaded(tops, np.array([0.0, 0.0, 1.0]), objs[:1])]    # not under the part: seen from above
    best = (-1.0, None)
    for _ in range(8):
        p_vise = np.array([rng.uniform(-40.0, opening + 60.0), rng.uniform(-40.0, 40.0), jaw_top + 1.0])
        hit, _, _ = v.mesh.ray.intersects_location(p_vise[None], np.array([[0.0, 0.0, -1.0]]))
        if len(hit):                                                # on the vise's top face there
            p_vise[2] = float(hit[:, 2].max())
        p = transform_points(T_vise, p_vise[None])[0]
        z0 = top + rng.uniform(40.0, 150.0)                          # the tool's tip
        z_hit = z0 + 60.0 + rng.uniform(0.0, 80.0)                    # the quill's height whose shadow falls on p
        axis = p[:2] + light[:2] / light[2] * (z_hit - p[2])
        spindle = SceneObject("spindle", spindle_mesh(float(rng.uniform(40.0, 60.0))),
                              make_pose(None, [axis[0], axis[1], z0]), albedo=0.6)
        share = float(np.mean(_shaded(tops, light, objs[:1] + objs[2:] + [spindle])))
        if share > best[0]:
            best = (share, spindle)
        if share >= MIN_TOP_SHADE:
            break
    objs.append(best[1])
    return objs


def shaded_fraction(objs: list[SceneObject], index: int, light: np.ndarray, depth_mm: np.ndarray,
                    labels: np.ndarray, K: np.ndarray, dist: np.ndarray, T_cam_table: np.ndarray,
                    n_samples: int = 3000, seed: int = 0) -> float:
    """Share of object ``index``'s visible pixels (label 2 + index) whose surface point is shaded from
    the directional ``light`` (unit, table frame) by another object of ``objs`` (the vise's own jaws
    shading its seat do not count): up to ``n_samples`` pixels, rays cast towards the light."""
    import cv2

    v, u = np.nonzero(labels == 2 + index)
    if len(v) == 0:
        return 0.0
    pick = np.random.default_rng(seed).choice(len(v), min(n_samples, len(v)), replace=False)
    v, u = v[pick], u[pick]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-10)
    xy = cv2.undistortPoints(np.column_stack([u, v]).astype(np.float64)[:, None], K, dist, criteria=crit).reshape(-1, 2)
    z = depth_mm[v, u].astype(np.float64)
    P = transform_points(inv(T_cam_table), np.column_stack([xy * z[:, None], z]))
    return float(np.mean(_shaded(P, light, [o for i, o in enumerate(objs) if i != index])))


def vise_shade_scene(entry: dict, width: int = 1920, height: int = 1200):
    """Render scene ``entry`` (:func:`vise_shade_entry`): (DevsetScene, image), the vise in the hard
    conditions of the devset's vise misses. A low lamp (20-35 deg above the table) with a spindle
    whose shadow falls across the vise, the part's own shadow (a tenon plate overhangs the jaws), a
    dim ambient (0.12-0.25), vignetting 20-50 %, every other scene a dark part, scenes k % 4 in (1, 2)
    a low camera (20-35 deg elevation, else 35-65), every third one JPEG (quality 80-92), the others
    PNG; all mono (our renderer draws grey), some under-exposed (exposure 0.55-1.0). The camera,
    550-1200 mm away, looks at the vise; up to 12 draws until >= 3 markers, the part (>= 2000 px) and
    >= 30 % of the vise are seen. Seeded per scene index; the other scenes of this module draw from
    generators of their own, so they are unchanged. The ground truth lists the vise (its visible and
    shaded share) and the parallels."""
    from app.geometry import parts
    from app.geometry.model_edges import render_depth
    from app.synth.devset import DevsetScene
    from app.synth.scene import Scene, look_at_pose, project_points, random_intrinsics, render_scene
    from app.vision.localize import Candidate

    k = int(entry["index"])
    rng = np.random.default_rng(13000 + k)
    lib = {m.key: m for m in parts.example_library()}
    vk, pk = entry["vise"], entry["workpiece"]
    el_l, az_l = np.radians(rng.uniform(20.0, 35.0)), rng.uniform(0.0, 2 * np.pi)
    light = np.array([np.cos(el_l) * np.cos(az_l), np.cos(el_l) * np.sin(az_l), np.sin(el_l)])
    objs = vise_shade_objects(rng, k, lib, vk, pk, light)
    part, vise = objs[0], objs[1]
    seat = lib[vk].support_surfaces[0]
    target = transform_points(vise.T_table_obj, np.array([[0.5 * seat["outline_xy"][2][0], 0.0, 0.0]]))[0]
    table, layout = parts.tslot_table(), parts.tslot_table_layout()
    low = k % 4 in (1, 2)
    scale = width / 1920.0                      # focal lengths as at 1920 px (a smaller test image)
    spindle_xy, spindle_top = objs[-1].T_table_obj[:2, 3], float(objs[-1].T_table_obj[2, 3]) + 310.0
    jpeg = int(rng.integers(80, 93)) if k % 3 == 0 else None
    common = dict(vignetting=float(rng.uniform(0.2, 0.5)), ambient=float(rng.uniform(0.12, 0.25)),
                  exposure=float(rng.uniform(0.55, 1.0)), table_albedo=0.3 if k % 4 >= 2 else 0.42,
                  noise_sigma=float(rng.uniform(1.0, 3.0)), blur_sigma_px=float(rng.uniform(0.4, 1.0)),
                  jpeg_quality=jpeg)
    unit_square = np.array([[-1, 1, 0], [1, 1, 0], [1, -1, 0], [-1, -1, 0]], float)
    for _ in range(12):
        K, dist = random_intrinsics(rng, width, height, focal_px=(1400.0 * scale, 2000.0 * scale))
        d = rng.uniform(550.0, 1200.0)
        el = np.radians(rng.uniform(20.0, 35.0) if low else rng.uniform(35.0, 65.0))
        az = rng.uniform(0, 2 * np.pi)
        pos = target + d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        T_cam_table = look_at_pose(pos, target + rng.uniform(-40, 40, 3) * [1, 1, 0], rng.uniform(-10, 10))
        if np.hypot(*(pos[:2] - spindle_xy)) < 90.0 and pos[2] < spindle_top:
            continue                                                 # the camera inside the spindle
        # cheap checks first: markers whose corners are all in the image (before occlusion)
        n_in = 0
        for m in layout["markers"]:
            uv = project_points(K, dist, T_cam_table, transform_points(np.asarray(m["T_table_marker"]),
                                                                          0.5 * float(m["size_mm"]) * unit_square))
            n_in += int(np.all((uv >= 0) & (uv <= [width - 1, height - 1])))
        if n_in < 3:
            continue
        scene = Scene(width=width, height=height, K=K, dist=dist, T_cam_table=T_cam_table, table_mesh=table,
                      table_layout=layout, objects=objs, light_dir_table=light, **common)
        r = render_scene(scene, rng)
        seen = [int(i) for i, vis in r.truth["marker_visible"].items() if vis]
        V = transform_points(T_cam_table @ vise.T_table_obj, vise.mesh.vertices)
        sil = int(np.isfinite(render_depth([(V, vise.mesh.faces)], K, width, height,
                                           max_pixel_tests=50_000_000)[0]).sum())
        vise_vis = float(min(1.0, np.count_nonzero(r.labels == 3) / max(sil, 1)))
        if len(seen) >= 3 and np.count_nonzero(r.labels == 2) > 2000 * scale ** 2 and vise_vis >= 0.3:
            break
    V = transform_points(T_cam_table @ part.T_table_obj, part.mesh.vertices)
    sil = int(np.isfinite(render_depth([(V, part.mesh.faces)], K, width, height, max_pixel_tests=50_000_000)[0]).sum())
    part_vis = float(min(1.0, np.count_nonzero(r.labels == 2) / max(sil, 1)))
    shade = shaded_fraction(objs, 1, light, r.depth_mm, r.labels, K, dist, T_cam_table, seed=k)
    gt = {"visible_marker_ids": seen, "fixture_mode": "vise", "light_dir_table": light.tolist(),
          "camera_elevation_deg": float(np.degrees(el)), "jpeg_quality": jpeg,
          "objects": [{"name": vise.name, "kind": "clamp", "subtype": "vise", "mesh_obj": vise.mesh,
                       "T_table_object": vise.T_table_obj.tolist(), "visible_fraction": vise_vis,
                       "shaded_fraction": shade}]
          + [{"name": o.name.replace("#", "_"), "kind": "support", "subtype": "parallel", "mesh_obj": o.mesh,
              "T_table_object": o.T_table_obj.tolist()} for o in objs if o.name.startswith("parallel")]}
    wpd = {"name": pk, "mesh_obj": part.mesh, "T_table_object": part.T_table_obj.tolist(), "visible_fraction": part_vis}
    fixtures = [Candidate(m.key, m.mesh, kind=m.kind, support_surfaces=m.support_surfaces)
                for m in (lib[vk], lib["parallel_150x25x8"])]
    sc = DevsetScene(gt=gt, K=K, dist=dist, layout=layout, workpiece=wpd,
                     table_candidate=Candidate("table", table, kind="table"), fixture_candidates=fixtures)
    return sc, r.image
