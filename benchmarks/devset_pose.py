"""Benchmark: object pose on the independent devset (../shared/data/devset), per fixture mode.

    .venv/bin/python benchmarks/devset_pose.py [--methods baseline,engine] [--scenes setup_000,...]
                                               [--jobs 2] [--out var/devset] [--report-only]

The devset's scenes come from a renderer that is not ours (other lighting and noise, mono and JPEG
cameras, parts in a vise on parallels, on parallels, on the table under strap clamps). Each scene is
run end to end as the service runs it: table from the markers (``locate_table``), then the workpiece
with the library's fixtures (the devset's vise and parallels, read from its ``meshes/``) by
:func:`app.vision.localize.localize`. Nothing is tuned per scene: constants are fitted on
``setup_000``-``setup_019`` only and both halves are reported apart.

Methods, run in the same process on the same images:
* ``baseline``: the engine as it was before the support chain: the workpiece searched on the table
  plane only (``height_offsets_mm=(0,)``), no fixtures located;
* ``engine``: the current engine: fixtures located first, the workpiece searched on their support
  surfaces and over free height;
* ``clamped``: the engine with the scene's strap clamp sets in the library as well (the shop keeps
  its clamps as it keeps its vise): they are located before the part, and reported apart (located,
  right within 1 mm and 0.5 deg, wrong but passed).

Reported per method, mode and half: scenes, eligible (>= 2 markers seen and >= 50 % of the part
visible), located, wrong but accepted (> 1 mm or > 0.5 deg), position error median / p95 (mm, 3D, to
the nearest equivalent pose), rotation error median (deg), share of error components within 1 and 3
stated sigma (x, y, z, rx, ry, rz), NEES (mean of the 6-DoF chi-square, expected 6) and time per image.
Per-scene rows are written to ``OUT/<method>.json`` (the report is made from them).
"""

from __future__ import annotations

import argparse
import inspect
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from functools import lru_cache
from pathlib import Path

import numpy as np

# SETUPCAM_CODE: run another checkout's engine (the baseline: the commit before the support chain,
# e.g. `git worktree add /tmp/base <commit>`; copy app/synth/devset.py and app/vision/pose_errors.py in)
sys.path.insert(0, os.environ.get("SETUPCAM_CODE", str(Path(__file__).resolve().parent.parent)))

DEVSET = Path(os.environ.get("SETUPCAM_DEVSET", Path(__file__).resolve().parents[2] / "shared" / "data" / "devset"))
WRONG_MM, WRONG_DEG = 1.0, 0.5


def _is_wrong(err) -> bool:
    """A located result more than :data:`WRONG_MM` or :data:`WRONG_DEG` off (err: x, y, z mm, rx, ry, rz deg)."""
    return bool(np.linalg.norm(err[:3]) > WRONG_MM or np.nanmax(np.abs(err[3:])) > WRONG_DEG)


def _nearest(errs: list):
    """Of the 6-DoF errors to equivalent truths (a part's symmetric poses, interchangeable clamp sets),
    the smallest (1 deg counts as 0.1 mm)."""
    return min(errs, key=lambda e: np.linalg.norm(e[:3]) + 10 * np.linalg.norm(np.nan_to_num(e[3:])))


# the devset shop's parallels (every parallel_*.stl of its meshes, their heights) are declared as its
# risers; --no-risers leaves every riser of unknown height
RISERS = True
# threads of each scene's plane search (main: the cores shared among the jobs); 1 for a checkout
# whose localize does not take it
THREADS = 1


@lru_cache(maxsize=4)
def shop_riser_heights(root: Path) -> tuple[float, ...]:
    """Heights (mm) of the devset's parallels, as the library's supports would declare them."""
    import trimesh

    from app.vision.localize import Candidate, riser_heights

    return riser_heights([Candidate(f.stem, trimesh.load(f, force="mesh"), kind="support")
                          for f in (Path(root) / "meshes").glob("parallel_*.stl")])


def scenes(family: str = "setup") -> list[dict]:
    man = json.loads((DEVSET / "manifest.json").read_text())
    return man["families"][family]


# --perturb: the image degraded before the engine sees it (a stress test of the refusals and the sigma
# on pictures rougher than the devset's; deterministic per scene)
PERTURB = ""
PERTURBATIONS = ("jpeg60", "blur", "resample", "linear", "noise", "dark", "blur_noise", "dark_noise", "calib",
                 "chips", "layout", "calib_dist", "bright", "markers2", "markers3")
# ``layout``: the markers as a shop places them, told as designed: each one off its layout position by
# N(0, LAYOUT_MM) per axis in the table plane and turned by N(0, LAYOUT_DEG), its printed size off by
# N(0, LAYOUT_SCALE) (a printer's scaling); the engine is told the layout, the image shows them as placed
LAYOUT_MM = 0.2
LAYOUT_DEG = 0.2
LAYOUT_SCALE = 0.002
# ``chips``: CHIPS_N chips and coolant spots strewn over the picture (2-7 px polygons, any grey), as a
# table after machining shows them: edges that belong to nothing in the library
CHIPS_N = 1500
# ``calib``: the image as rendered, the engine told slightly wrong intrinsics, as a real calibration is
# wrong: focal length off by N(0, CALIB_F_REL) (both axes alike), principal point by N(0, CALIB_C_PX) px
# per axis. Careful calibrations of the same camera differ by 0.1-1 % in f and 1-5 px in c (BENCHMARKS.md,
# "Calibration on real image sets": 0.5 % and 1.0 % between our corner window and OpenCV's sample).
CALIB_F_REL = 0.004
CALIB_C_PX = 3.0


# ``markers2`` / ``markers3``: only the 2 or 3 markers nearest the workpiece (in the image) are in the
# layout the engine is told; the others are painted over where nothing hides them (hide_markers), as
# a camera that sees a corner of the table shows only a few. Our generator's scenes (no marker corners
# in their truth) keep the 2 or 3 seen markers nearest the workpiece on the table (few_markers_told);
# the others stay in the picture, left out of the layout only


# --placement: the markers' placement sigma the told layout declares (None: it declares none)
PLACEMENT = None


def told_layout(layout: dict, kind: str, seed: int) -> dict:
    """The marker layout the engine is told under ``kind``: for ``layout`` the markers where the image
    shows them are told where they were designed, i.e. the told layout is the true one moved back by
    each marker's placement error (the image stays as rendered)."""
    if PLACEMENT is not None:
        layout = {**layout, "placement_sigma": dict(zip(("position_mm", "rotation_deg", "scale_rel"), PLACEMENT))}
    if kind != "layout":
        return layout
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3000 + seed)
    markers = []
    for m in layout["markers"]:
        T = np.array(m["T_table_marker"], float)
        T[:3, :3] = T[:3, :3] @ Rotation.from_euler("z", LAYOUT_DEG * rng.standard_normal(), degrees=True).as_matrix()
        T[:2, 3] += LAYOUT_MM * rng.standard_normal(2)          # turned about its own centre, moved
        markers.append({**m, "T_table_marker": T.tolist(),
                        "size_mm": float(m["size_mm"]) * (1.0 + LAYOUT_SCALE * rng.standard_normal())})
    return {**layout, "markers": markers}


# ``calib_dist``: as ``calib``, and the radial distortion told off as well: k1 moved so that the image
# corner moves by N(0, DIST_CORNER_PX) px (env DIST_CORNER_PX; calibrations of one real camera differ
# by 2.8-7.4 px at its corners after the best f / c match: benchmarks/calibration.md)
DIST_CORNER_PX = float(os.environ.get("DIST_CORNER_PX", 2.0))


def told_dist(dist, K, kind: str, seed: int):
    """The distortion the engine is told under ``kind`` (``dist`` itself unless ``calib_dist``)."""
    if kind != "calib_dist":
        return dist
    rng = np.random.default_rng(4000 + seed)
    K = np.asarray(K, float)
    r_c = np.hypot(K[0, 2], K[1, 2]) / K[0, 0]             # the corner's normalised radius
    out = np.array(dist, float).ravel().copy()
    out[0] += DIST_CORNER_PX * rng.standard_normal() / (K[0, 0] * r_c ** 3)
    return out


def told_intrinsics(K, kind: str, seed: int):
    """The intrinsics the engine is told under ``kind`` (``K`` itself unless ``calib`` or ``calib_dist``)."""
    if kind not in ("calib", "calib_dist"):
        return K
    from app.vision.intrinsics import moved_intrinsics

    rng = np.random.default_rng(1000 + seed)
    df, dc = CALIB_F_REL * rng.standard_normal(), CALIB_C_PX * rng.standard_normal(2)
    return moved_intrinsics(moved_intrinsics(moved_intrinsics(K, 0, df), 1, dc[0]), 2, dc[1])


GAMMA = 2.2     # the devset's encoding gamma (every scene's ``sensor.gamma``)


def few_markers_told(gt: dict, layout: dict, T_table_part, keep: int) -> list[int]:
    """The ids of the ``keep`` markers seen (``gt["visible_marker_ids"]``) nearest the part's origin
    ``T_table_part`` on the table (table frame, mm)."""
    p = np.asarray(T_table_part, float)[:2, 3]
    seen = [m for m in layout["markers"] if m["id"] in set(gt["visible_marker_ids"])]
    seen.sort(key=lambda m: np.linalg.norm(np.asarray(m["T_table_marker"], float)[:2, 3] - p))
    return [m["id"] for m in seen[:keep]]


def hide_markers(image, gt: dict, layout: dict, keep: int):
    """A table that shows only a few of its markers: the ``keep`` visible markers nearest the workpiece
    (image distance to its bounding box's centre) are left; every other marker plate that nothing hides
    is painted over with the median grey of a ring just outside it. A plate partly hidden (by the vise,
    a part) stays, since painting its footprint would paint over what hides it; the caller leaves it
    out of the layout the engine is told. Returns (image, ids of the markers left)."""
    import cv2

    cam = gt["camera"]
    K, dist = np.asarray(cam["K"], float), np.asarray(cam["dist"], float).ravel()
    T = np.asarray(gt["T_cam_table"], float)
    rvec, tvec = cv2.Rodrigues(T[:3, :3])[0], T[:3, 3]
    wp = next(o for o in gt["objects"] if o["kind"] == "workpiece")
    centre = np.asarray(wp["bbox_centre_px"], float)
    visible = [m for m in gt["markers"] if m["id"] in gt["visible_marker_ids"]]
    kept = sorted(visible, key=lambda m: np.linalg.norm(np.mean(m["corners_px"], axis=0) - centre))[:keep]
    kept_ids = {m["id"] for m in kept}
    out = image.copy()
    h, w = out.shape[:2]
    unhidden = {m["id"] for m in gt["markers"] if m.get("visible_fraction", 0.0) >= 0.98}
    for lm in layout["markers"]:
        if lm["id"] in kept_ids or lm["id"] not in unhidden:
            continue
        half = float(lm.get("plate_half_size_mm", 0.7 * lm["size_mm"]))
        sq = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
        Tm = np.asarray(lm["T_table_marker"], float)
        # the plate's top and bottom outline (its sides show from a low camera)
        pts = [Tm[:3, :3] @ np.array([x, y, z]) + Tm[:3, 3] for x, y in sq for z in (-Tm[2, 3], 0.0)]
        px, _ = cv2.projectPoints(np.asarray(pts), rvec, tvec, K, dist)
        px = px.reshape(-1, 2)
        if not np.all(np.isfinite(px)) or (px[:, 0].max() < 0 or px[:, 1].max() < 0 or px[:, 0].min() >= w
                                            or px[:, 1].min() >= h):
            continue
        hull = cv2.convexHull(np.round(px).astype(np.int32))
        mask = np.zeros((h, w), np.uint8)
        cv2.fillConvexPoly(mask, hull, 255)
        mask = cv2.dilate(mask, np.ones((7, 7), np.uint8))
        ring = cv2.dilate(mask, np.ones((15, 15), np.uint8)) & ~mask
        if not ring.any():
            continue
        grey = np.median(out[ring > 0], axis=0)
        out[mask > 0] = np.round(grey).astype(out.dtype)
    return out, sorted(kept_ids)


def perturbed(image, kind: str, seed: int):
    """``image`` degraded as a shop camera might: ``jpeg60`` re-encoded at JPEG quality 60; ``blur``
    defocused (Gaussian, sigma 1.2 px, in linear light as a lens blurs, on top of the render's own
    0-1 px); ``resample`` the same Gaussian on the encoded grey levels (a camera's or a viewer's
    down-scaling; it moves each edge's 50 % point in linear light towards the bright side);
    ``linear`` encoded without gamma (``255 * L``: many machine-vision cameras' default), read by an
    engine that assumes the usual 2.2; ``noise`` read noise (sigma 4 grey levels); ``dark`` every grey
    level scaled by 0.45 (under-exposed: fewer grey levels per edge); ``blur_noise`` and ``dark_noise``
    both; ``bright`` one stop over-exposed (linear light doubled, then clipped at the sensor's top:
    every face brighter than mid-grey reads 255 at its edges); ``calib`` and ``layout`` leave the
    image as it is (:func:`told_intrinsics` and :func:`told_layout` change what the engine is told);
    ``chips`` strews :data:`CHIPS_N` small polygons of random grey over it (chips and coolant spots)."""
    import cv2

    if kind in ("calib", "layout", "calib_dist"):
        return image
    if kind == "chips":
        rng = np.random.default_rng(2000 + seed)
        out = image.copy()
        h, w = out.shape[:2]
        for _ in range(CHIPS_N):
            c = rng.uniform([0, 0], [w, h])
            n = int(rng.integers(3, 7))
            r = rng.uniform(1.0, 3.5, n)
            a = np.sort(rng.uniform(0, 2 * np.pi, n))
            poly = np.round(c + np.column_stack([r * np.cos(a), r * np.sin(a)])).astype(np.int32)
            grey = int(rng.integers(10, 250))
            cv2.fillPoly(out, [poly], (grey,) * (out.shape[2] if out.ndim == 3 else 1))
        return out
    if kind == "jpeg60":
        _, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 60])
        return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    if kind not in PERTURBATIONS:
        raise ValueError(f"unknown perturbation {kind!r}; known: {', '.join(PERTURBATIONS)}")
    img = image.astype(np.float32)
    if kind.startswith("blur"):
        linear = cv2.GaussianBlur((img / 255.0) ** GAMMA, (0, 0), 1.2)
        img = 255.0 * linear ** (1.0 / GAMMA)
    if kind == "resample":
        img = cv2.GaussianBlur(img, (0, 0), 1.2)
    if kind == "linear":
        img = 255.0 * (img / 255.0) ** GAMMA
    if kind.startswith("dark"):
        img = img * 0.45
    if kind == "bright":
        img = 255.0 * np.minimum(2.0 * (img / 255.0) ** GAMMA, 1.0) ** (1.0 / GAMMA)
    if kind.endswith("noise"):
        img = img + np.random.default_rng(seed).normal(0.0, 4.0, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def run_scene(entry: dict, method: str) -> dict:
    """One scene through one method -> a row (errors, sigma, time, reason)."""
    import cv2
    import trimesh

    from app.synth.devset import devset_scene
    from app.vision.localize import LOOKALIKE_SAME_MM, Candidate, localize
    from app.vision.pose_errors import pose_error_6dof

    if entry.get("source") == "synth":
        sc, image = _synth_cached(entry)
    else:
        sc = devset_scene(DEVSET, entry)
        image = cv2.imread(str(DEVSET / entry["image"]), cv2.IMREAD_UNCHANGED)
    K_told = told_intrinsics(sc.K, PERTURB, seed=int(entry.get("index", 0)))
    layout_told = told_layout(sc.layout, PERTURB, seed=int(entry.get("index", 0)))
    markers_seen = len(sc.gt["visible_marker_ids"])
    if PERTURB.startswith("markers"):
        if entry.get("source") == "synth":
            kept = few_markers_told(sc.gt, sc.layout, sc.workpiece["T_table_object"], int(PERTURB[len("markers"):]))
        else:
            image, kept = hide_markers(image, sc.gt, sc.layout, keep=int(PERTURB[len("markers"):]))
        markers_seen = len(kept)
        layout_told = {**layout_told, "markers": [m for m in layout_told["markers"] if m["id"] in kept]}
    elif PERTURB:
        image = perturbed(image, PERTURB, seed=int(entry.get("index", 0)))
    wp = sc.workpiece
    mesh = wp["mesh_obj"] if "mesh_obj" in wp else trimesh.load(DEVSET / wp["mesh"], force="mesh")
    cands = [Candidate(wp["name"], mesh, kind="workpiece")]
    if method in ("engine", "clamped"):
        cands += sc.fixture_candidates
    # clamped: the shop keeps its strap clamp sets in the library too (the scene's own, as it keeps its vise)
    clamps = {o["name"]: o for o in getattr(sc, "gt", {}).get("objects", [])
              if o["kind"] == "clamp" and o.get("subtype") == "strap_clamp"} if method == "clamped" else {}
    cands += [Candidate(n, o["mesh_obj"] if "mesh_obj" in o else trimesh.load(DEVSET / o["mesh"], force="mesh"),
                        kind="clamp") for n, o in clamps.items()]
    kw = {"height_offsets_mm": (0.0,)} if method == "baseline" else {"chain": True}
    if "search_threads" in inspect.signature(localize).parameters:
        kw["search_threads"] = THREADS
    if method in ("engine", "clamped") and entry.get("source") != "synth" and RISERS:
        kw["riser_heights_mm"] = shop_riser_heights(DEVSET)
    # the service prepares a model once per revision and keeps it (services/setups.py): the time per
    # image is taken with the models prepared, their preparation reported apart
    t = time.perf_counter()
    for c in cands + ([sc.table_candidate] if sc.table_candidate is not None else []):
        c.prepare()
    prep_ms = (time.perf_counter() - t) * 1e3
    t, cpu = time.perf_counter(), time.process_time()
    try:
        res = localize(image, K_told, told_dist(sc.dist, sc.K, PERTURB, seed=int(entry.get("index", 0))), layout_told,
                       cands, table_model=sc.table_candidate, **kw)
        err = None
    except Exception as e:  # noqa: BLE001 - a crash is a result here, reported as such
        res, err = None, f"{type(e).__name__}: {e}"
    ms = (time.perf_counter() - t) * 1e3
    cpu_ms = (time.process_time() - cpu) * 1e3     # CPU time of this process: steadier than ms on a shared machine
    row = {"scene": entry["scene_id"], "mode": entry["fixture_mode"], "workpiece": entry["workpiece"],
           "half": 0 if entry["index"] < 20 else 1, "pair": entry.get("pair"), "ms": ms, "cpu_ms": cpu_ms,
           "prep_ms": prep_ms, "threads": kw.get("search_threads", 1),
           "markers_seen": markers_seen,
           "visible_fraction": float(wp["visible_fraction"]), "crash": err,
           "gamma": (res.table or {}).get("gamma") if res is not None else None}
    obj = None if res is None else next((o for o in res.objects if o["kind"] == "workpiece"), None)
    row["located"] = obj is not None
    wp_fail = [] if res is None else [n["reason"] for n in res.not_found if n.get("name") == wp["name"]]
    row["reason"] = "" if obj is not None else (err or (wp_fail[0] if wp_fail else res.reason))
    row["fixtures"] = [] if res is None else [o["name"] for o in res.objects if o["kind"] != "workpiece"]
    # why each fixture of the library was not located (a missed vise: not found, ambiguous, ...)
    row["fixtures_reason"] = {} if res is None else {n["name"]: n["reason"] for n in res.not_found
                                                     if n.get("name") != wp["name"]}
    # each located fixture's 6-DoF error (x, y, z mm, rx, ry, rz deg) to the scene's true one of that
    # name, where the ground truth lists it (the devset's vise_body and vise_jaw, our vise_shade vises;
    # a pair of parallels, name_0 and name_1: the nearer)
    truth = getattr(sc, "gt", {}).get("objects", [])
    row["fixtures_err"] = {}
    for o in ([] if res is None else res.objects):
        cand = next((c for c in cands if c.name == o["name"]), None)
        same = [t for t in truth if t["name"] == o["name"] or t["name"].startswith(o["name"] + "_")]
        if o["kind"] != "workpiece" and same and cand is not None:
            row["fixtures_err"][o["name"]] = [float(v) for v in _nearest([pose_error_6dof(
                np.asarray(o["T_table_obj"]), np.asarray(t["T_table_object"]), cand.prepare()) for t in same])]
    # each located fixture's unexplained-edge share (a vise's outline holds the part it clamps)
    row["fixtures_unexplained"] = {} if res is None else {o["name"]: o.get("unexplained_fraction")
                                                          for o in res.objects if o["kind"] != "workpiece"}
    row["clamps"] = []
    for name, o in clamps.items():
        got = None if res is None else next((x for x in res.objects if x["name"] == name), None)
        c = {"name": name, "located": got is not None, "visible_fraction": float(o.get("visible_fraction", 1.0))}
        if got is not None:
            cand = next(k for k in cands if k.name == name)
            model = cand.prepare()
            # two sets whose meshes' boxes agree within LOOKALIKE_SAME_MM (straps 1-2 mm apart) are
            # interchangeable: the error is to the nearer of them
            same = [clamps[k.name] for k in cands
                    if k.name in clamps and np.abs(k.mesh.bounds - cand.mesh.bounds).max() <= LOOKALIKE_SAME_MM]
            errs = [pose_error_6dof(np.asarray(got["T_table_obj"]), np.asarray(q["T_table_object"]), model)
                    for q in same]
            e = _nearest(errs)
            c.update(err=[float(v) for v in e],
                     sigma=got["sigma"], pass_=got.get("uncertainty_ok"), score=got.get("score"))
        else:
            c["reason"] = next((n["reason"] for n in (res.not_found if res is not None else [])
                                if n.get("name") == name), "")
        row["clamps"].append(c)
    if obj is not None:
        prepared = next(c for c in cands if c.kind == "workpiece").prepare()
        listed = [np.asarray(obj["T_table_obj"])] + [np.asarray(T) for T in obj.get("equivalent_poses", [])]
        errs = [pose_error_6dof(T, np.asarray(wp["T_table_object"]), prepared) for T in listed]
        e = _nearest(errs)
        row.update(err=[float(v) for v in e], sigma=obj["sigma"], score=obj["score"], chain=obj.get("chain"),
                   unexplained=obj.get("unexplained_fraction"),
                   held_by=obj.get("held_by"),
                   T_table_obj=obj["T_table_obj"], equivalent_poses=obj.get("equivalent_poses", []),
                   cov6=obj.get("cov6"), cov6_table=obj.get("cov6_table"), cov6_intrinsics=obj.get("cov6_intrinsics"),
                   pass_=obj.get("uncertainty_ok"))
    return row


SYNTH_CACHE = Path(os.environ.get("SETUPCAM_SYNTH_CACHE", Path.home() / ".cache" / "setupcam" / "synth_fixtures"))


def _synth_cached(entry: dict):
    """A generated scene (app.synth.fixtures), rendered once and kept in SYNTH_CACHE (the vise_shade
    family's as vshade_*.pkl, the synth family's as synth_*.pkl)."""
    import pickle

    from app.synth.fixtures import synth_scene, vise_shade_scene

    f = SYNTH_CACHE / f"{entry['scene_id']}.pkl"
    if f.exists():
        return pickle.loads(f.read_bytes())
    out = vise_shade_scene(entry) if entry.get("family") == "vise_shade" else synth_scene(entry)
    f.parent.mkdir(parents=True, exist_ok=True)
    f.write_bytes(pickle.dumps(out))
    return out


# the error and sigma components, in the rows' order (x, y, z mm; rx, ry, rz deg)
AXES = ("x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg")


def _nees_per_dof(err: np.ndarray, C: np.ndarray, ok: np.ndarray) -> float | None:
    """The 6-DoF error (mm, deg) against its covariance ``C`` (mm, rad) over the axes ``ok``: the
    chi-square per degree of freedom (expected 1); None where fewer than 3 axes are known."""
    if ok.sum() < 3:
        return None
    e = err[ok] * np.where(np.arange(6)[ok] >= 3, np.pi / 180, 1.0)
    return float(e @ np.linalg.pinv(C[np.ix_(ok, ok)]) @ e) / ok.sum()


def _summary(rows: list[dict]) -> dict:
    n = len(rows)
    elig = [r for r in rows if r["markers_seen"] >= 2 and r["visible_fraction"] >= 0.5]
    loc = [r for r in rows if r["located"]]
    wrong = [r for r in loc if _is_wrong(r["err"])]
    wrong_pass = [r for r in wrong if r.get("pass_")]        # wrong and the gate would have let it through
    good = [r for r in loc if r not in wrong]
    pos = np.array([np.linalg.norm(r["err"][:3]) for r in good])
    rot = np.array([np.nanmax(np.abs(r["err"][3:])) if np.any(np.isfinite(r["err"][3:])) else 0.0 for r in good])
    keys = AXES
    ratios = []
    for r in loc:
        for k, e in zip(keys, r["err"]):
            s = r["sigma"].get(k)
            if s is not None and np.isfinite(s) and s > 0 and np.isfinite(e):  # None: undetermined
                ratios.append(abs(e) / s)
            elif np.isfinite(e):
                ratios.append(np.inf)           # an error with no stated sigma is never covered
    ratios = np.array(ratios)
    nees = []
    for r in loc:
        if r.get("cov6"):
            C = np.asarray(r["cov6"], float)
            e = np.asarray(r["err"], float)
            v = _nees_per_dof(e, C, np.isfinite(e) & np.isfinite(np.diag(C)))
            if v is not None:
                nees.append(v)
    return {"scenes": n, "eligible": len(elig), "located": len(loc),
            "located_eligible": sum(r["located"] for r in elig), "wrong": len(wrong), "wrong_pass": len(wrong_pass),
            "crashes": sum(1 for r in rows if r["crash"]),
            "pos_med": float(np.median(pos)) if len(pos) else None,
            "pos_p95": float(np.percentile(pos, 95)) if len(pos) else None,
            "rot_med": float(np.median(rot)) if len(rot) else None,
            "cov1": float(np.mean(ratios <= 1)) if len(ratios) else None,
            "cov3": float(np.mean(ratios <= 3)) if len(ratios) else None,
            "nees": float(np.mean(nees)) if nees else None,
            "ms_med": float(np.median([r["ms"] for r in rows])) if rows else None}


def per_axis_coverage(rows: list[dict]) -> str:
    """Share of the located results whose error is within 1 and 3 stated sigma, per axis."""
    keys = AXES
    loc = [r for r in rows if r["located"]]
    cells = []
    for i, k in enumerate(keys):
        rat = []
        for r in loc:
            e, sg = r["err"][i], r["sigma"].get(k)
            if not np.isfinite(e):
                continue                      # the spin of a round part: not an error
            rat.append(0.0 if abs(e) < 1e-9 else (abs(e) / sg if sg else np.inf))   # sigma 0 holds only if exact
        rat = np.asarray(rat)
        cells.append(f"{np.mean(rat <= 1):.0%} / {np.mean(rat <= 3):.0%}" if len(rat) else "-")
    return "| " + " | ".join(cells) + " |"


# cov6's units (mm, rad) to the errors' (mm, deg), squared
_VAR_TO_ERR = np.array([1.0, 1.0, 1.0] + [np.degrees(1.0) ** 2] * 3)


def without_intrinsics(rows: list[dict]) -> str:
    """Pooled share of the located results' error components within 1 and 3 stated sigma, and the NEES
    per dof, with the intrinsics' share of the covariance left out (``cov6_intrinsics``): what the
    devset as rendered can check, its intrinsics being exact. That share is checked apart
    (:func:`intrinsics_check`)."""
    cells = []
    for half in (0, 1, None):
        rat, nees = [], []
        for r in rows:
            if (not r["located"] or r.get("cov6") is None or r.get("cov6_intrinsics") is None
                    or (half is not None and r["half"] != half)):
                continue
            e = np.asarray(r["err"], float)
            C = np.asarray(r["cov6"], float) - np.asarray(r["cov6_intrinsics"], float)
            s_all = np.array([np.nan if r["sigma"].get(k) is None else r["sigma"][k] for k in AXES], float)
            ok = np.isfinite(e) & np.isfinite(s_all)
            s = np.sqrt(np.maximum(np.diag(C) * _VAR_TO_ERR, 1e-18))
            rat += list(np.abs(e[ok]) / s[ok])
            v = _nees_per_dof(e, C, ok)
            if v is not None:
                nees.append(v)
        rat = np.asarray(rat)
        hl = {0: "000-019", 1: "020-039", None: "both"}[half]
        if len(rat):
            cells.append(f"{hl}: {np.mean(rat <= 1):.0%} / {np.mean(rat <= 3):.0%}, NEES/dof {np.mean(nees):.2f}")
    return "; ".join(cells) or "-"


def intrinsics_check(rows: list[dict], rendered: list[dict]) -> str:
    """The intrinsics' share checked on its own: each scene of a ``--perturb calib`` run (told intrinsics
    off) against the same scene as rendered (told them exact). The difference of the two errors is
    what the told-off intrinsics moved the part; per axis, the 68th percentile of that move over the
    intrinsics' stated sigma (``cov6_intrinsics``; 1 when the share is right). Scenes whose two
    results are more than 0.5 mm apart are left out (another solution, not the intrinsics' move)."""
    base = {r["scene"]: r for r in rendered if r["located"]}
    q = []
    for r in rows:
        b = base.get(r["scene"])
        if not r["located"] or b is None or r.get("cov6_intrinsics") is None:
            continue
        d = np.asarray(r["err"], float) - np.asarray(b["err"], float)
        if np.linalg.norm(d[:3]) > 0.5:
            continue
        q.append(np.abs(d) / np.sqrt(np.maximum(np.diag(np.asarray(r["cov6_intrinsics"], float)) * _VAR_TO_ERR, 1e-18)))
    if not q:
        return "-"
    p68 = np.nanpercentile(np.asarray(q), 68, axis=0)
    return (f"{len(q)} scenes; 68th percentile of the move / its sigma, x y z rx ry rz: "
            + " ".join(f"{v:.2f}" for v in p68))


def _fmt(v, f="{:.3f}"):
    return "-" if v is None else f.format(v)


def report(results: dict[str, list[dict]]) -> str:
    lines = ["| method | mode | half | scenes | eligible | located (eligible) | wrong located / passed the gate | crashes | "
             "pos median / p95 mm | rot median deg | within 1 / 3 sigma | NEES/dof | time median s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for method, rows in results.items():
        for mode in ("table", "vise", "parallels", "all"):
            for half in (0, 1, None):
                sel = [r for r in rows if (mode == "all" or r["mode"] == mode) and (half is None or r["half"] == half)]
                if not sel:
                    continue
                s = _summary(sel)
                hl = {0: "000-019", 1: "020-039", None: "both"}[half]
                lines.append(
                    f"| {method} | {mode} | {hl} | {s['scenes']} | {s['eligible']} | {s['located']} "
                    f"({s['located_eligible']}) | {s['wrong']} / {s['wrong_pass']} | {s['crashes']} | {_fmt(s['pos_med'])} / "
                    f"{_fmt(s['pos_p95'])} | {_fmt(s['rot_med'])} | {_fmt(s['cov1'], '{:.0%}')} / "
                    f"{_fmt(s['cov3'], '{:.0%}')} | {_fmt(s['nees'], '{:.2f}')} | {_fmt(s['ms_med'] / 1e3 if s['ms_med'] else None, '{:.1f}')} |")
    return "\n".join(lines)


def two_view(rows: list[dict]) -> str:
    """The ``moved`` pairs (same setup, two camera poses): both located? their difference in x, y,
    z (mm) and rx, ry, rz (deg) against the combined stated sigma (agree: every axis within 2)."""
    from scipy.spatial.transform import Rotation

    keys = AXES
    lines = ["| pair | mode | both located | difference x, y, z mm / rx, ry, rz deg | in combined sigma | agree (2 sigma) |",
             "|---|---|---|---|---|---|"]
    for p in sorted({r["pair"] for r in rows if r.get("pair") is not None}):
        a, b = sorted((r for r in rows if r.get("pair") == p), key=lambda r: r["scene"])
        if not (a["located"] and b["located"]):
            lines.append(f"| {p} | {a['mode']} | no ({a['located']}, {b['located']}) | - | - | - |")
            continue
        Ta = np.asarray(a["T_table_obj"])

        def diff(Tb):
            return np.concatenate([Ta[:3, 3] - Tb[:3, 3],
                                   np.degrees(Rotation.from_matrix(Ta[:3, :3] @ Tb[:3, :3].T).as_rotvec())])

        # the nearest of the poses b lists as the same look (a symmetric part's datum is the operator's)
        d = min((diff(np.asarray(T)) for T in [b["T_table_obj"], *b.get("equivalent_poses", [])]),
                key=lambda d: np.linalg.norm(d[:3]) + 10 * np.linalg.norm(d[3:]))
        sc = np.array([np.hypot(a["sigma"].get(k) or np.nan, b["sigma"].get(k) or np.nan) for k in keys])
        ratio = np.abs(d) / sc
        agree = bool(np.all(np.nan_to_num(ratio, nan=np.inf) <= 2.0))
        lines.append(f"| {p} | {a['mode']} | yes | {', '.join(f'{v:.2f}' for v in d[:3])} / "
                     f"{', '.join(f'{v:.3f}' for v in d[3:])} | {', '.join(f'{v:.1f}' for v in ratio)} | {agree} |")
    return "\n".join(lines)


def clamp_report(rows: list[dict]) -> str:
    """The strap clamps of the scenes (method ``clamped``): located, right (within 1 mm and 0.5 deg),
    wrong but passed by their own sigma, and the right ones' position error median / max, per half."""
    lines = ["| half | clamps | located | right (<= 1 mm, 0.5 deg) | wrong / passed the gate "
             "| position median / max mm (right) |", "|---|---|---|---|---|---|"]
    for half, label in ((0, "000-019"), (1, "020-039"), (None, "both")):
        cl = [c for r in rows if half is None or r["half"] == half for c in r.get("clamps", [])]
        loc = [c for c in cl if c["located"]]
        bad = [c for c in loc if _is_wrong(c["err"])]
        good = [np.linalg.norm(c["err"][:3]) for c in loc if all(c is not b for b in bad)]
        passed = sum(bool(c.get("pass_")) for c in bad)
        lines.append(f"| {label} | {len(cl)} | {len(loc)} | {len(good)} | {len(bad)} / {passed} | "
                     + (f"{np.median(good):.3f} / {np.max(good):.3f} |" if good else "- |"))
    return "\n".join(lines)


def _cores_per_job(jobs: int) -> int:
    """The service's rule (``blas_threads.cores_per_job``); 1 for a checkout from before it (SETUPCAM_CODE)."""
    try:
        from app.vision.blas_threads import cores_per_job
    except ImportError:
        return 1
    return cores_per_job(jobs)


def _job(args):
    entry, method = args
    return method, run_scene(entry, method)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default="baseline,engine")
    ap.add_argument("--scenes", default="", help="comma-separated scene ids (default: all 40 setups)")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="var/devset")
    ap.add_argument("--report-only", action="store_true")
    ap.add_argument("--no-risers", action="store_true",
                    help="declare no risers: every parallel under a part is of unknown height")
    ap.add_argument("--family", default="setup", choices=("setup", "moved", "synth", "vise_shade"),
                    help="moved: the devset's two-view pairs (reports their agreement); synth: our own "
                         "generator's table / vise / parallels scenes (app.synth.fixtures); vise_shade: "
                         "our own scenes of a shaded, half-hidden vise (app.synth.fixtures.vise_shade_scene)")
    ap.add_argument("--n-synth", type=int, default=24, help="scenes of the synth family")
    ap.add_argument("--fixture-n-coarse", type=int, default=0,
                    help="coarse cells re-scored in a fixture's plane search (localize.FIXTURE_OPTIONS "
                         "n_coarse); default: the engine's")
    ap.add_argument("--perturb", default="", choices=("",) + PERTURBATIONS,
                    help="degrade each image first (a stress test; see perturbed())")
    ap.add_argument("--rendered", default="",
                    help="with --perturb calib: the OUT of a run of the same scenes as rendered; the report "
                         "then checks the intrinsics' share of the sigma against the parts' move between them")
    ap.add_argument("--placement", default="",
                    help="MM,DEG,REL: the layout declares its markers' placement sigma (position mm, "
                         "rotation deg, print scale relative); default: it declares none")
    a = ap.parse_args(argv)
    if a.placement:
        global PLACEMENT
        PLACEMENT = tuple(float(v) for v in a.placement.split(","))   # read by the workers, which fork after this
    if a.perturb:
        global PERTURB
        PERTURB = a.perturb      # read by the workers, which fork after this
    if a.fixture_n_coarse:
        from app.vision import localize as _localize
        _localize.FIXTURE_OPTIONS["n_coarse"] = a.fixture_n_coarse    # the workers fork after this
    if a.no_risers:
        global RISERS
        RISERS = False           # read by the workers, which fork after this
    global THREADS               # the service's rule (services.setups.search_threads): cores per job
    THREADS = _cores_per_job(a.jobs)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    methods = a.methods.split(",")
    if a.family == "synth":
        from app.synth.fixtures import synth_entry
        pool = [synth_entry(k) for k in range(a.n_synth)]
    elif a.family == "vise_shade":
        from app.synth.fixtures import VISE_SHADE_N, vise_shade_entry
        pool = [vise_shade_entry(k) for k in range(VISE_SHADE_N)]
    else:
        pool = scenes(a.family)
    todo = [e for e in pool if not a.scenes or e["scene_id"] in a.scenes.split(",")]
    if a.family != "setup":
        methods = [f"{m}_{a.family}" for m in methods]
    results: dict[str, list[dict]] = {}
    if not a.report_only:
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        jobs = [(e, m.split("_")[0]) for m in methods for e in todo]
        done: dict[str, list[dict]] = {m: [] for m in methods}
        with ProcessPoolExecutor(a.jobs) as ex:
            for method, row in ex.map(_job, jobs):
                method = method + ("" if a.family == "setup" else f"_{a.family}")
                done[method].append(row)
                fx_mm = {n: round(float(np.linalg.norm(e[:3])), 2) for n, e in row["fixtures_err"].items()}
                print(f"{method:9s} {row['scene']} {row['mode']:9s} located={row['located']} "
                      f"err={np.round(row.get('err', []), 3).tolist()} {row['ms'] / 1e3:.1f}s "
                      f"fixtures={row['fixtures']} off_mm={fx_mm} "
                      f"cpu {row['cpu_ms'] / 1e3:.1f}s "
                      f"{row['reason'][:160]}",
                      flush=True)
        for m, rows in done.items():
            old = {r["scene"]: r for r in (json.loads((out / f"{m}.json").read_text()) if (out / f"{m}.json").exists() else [])}
            old.update({r["scene"]: r for r in rows})
            (out / f"{m}.json").write_text(json.dumps(sorted(old.values(), key=lambda r: r["scene"]), indent=1))
    for m in ("baseline", "engine", "clamped", "baseline_synth", "engine_synth", "clamped_synth", "baseline_moved",
              "engine_moved", "baseline_vise_shade", "engine_vise_shade"):
        if (out / f"{m}.json").exists():
            results[m] = json.loads((out / f"{m}.json").read_text())
    print(report(results))
    print("\nwithin 1 / 3 sigma per axis (all located):\n| method | x | y | z | rx | ry | rz |\n|---|---|---|---|---|---|---|")
    for m, rows in results.items():
        print(f"| {m} " + per_axis_coverage(rows))
    print("\nwithin 1 / 3 sigma pooled, NEES per dof, the intrinsics' share left out (the devset's are exact):")
    for m, rows in results.items():
        print(f"* {m}: " + without_intrinsics(rows))
    if a.rendered:
        for m, rows in results.items():
            f = Path(a.rendered) / f"{m}.json"
            if f.exists():
                print(f"\nthe intrinsics' share, {m} against {f}: " + intrinsics_check(rows, json.loads(f.read_text())))
    for m, rows in results.items():
        if any(r.get("clamps") for r in rows):
            print(f"\n{m}, strap clamps:\n" + clamp_report(rows))
    for m, rows in results.items():
        if m.endswith("_moved"):
            print(f"\n{m}:\n" + two_view(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
