"""Feature edges: creases of clean CAD, coarse tessellations and scans, the edge model before and after.

    PYTHONPATH=. .venv/bin/python benchmarks/feature_edges.py [--out benchmarks/feature_edges.md] [--no-fit]

"Before" is ``app/geometry/model_edges.py`` as of commit a3bbe4e (every face adjacency above 30 deg a
crease), loaded from git; "after" is the working tree (``app/geometry/feature_edges.py``). For every
part: crease edges, crease length (crease samples x sample step), time of ``prepare_model``; for the
scans also the share of crease length more than 1 mm from a true crease of the clean part and the
share of the clean part's creases found (a crease sample within 1 mm). The fit check renders the
clean part (app/synth) and fits the edge model of its scan, started at the true pose: score (share
of the visible model edges supported by image edges) and pose error. Scans are marching cubes of the
part's signed distance on a 1 or 0.5 mm grid plus Gaussian vertex noise, seeded: the test part's
exact distance field (tests/geometry/test_feature_edges.py), the library parts' through
:func:`scan_of` (about a minute for the bracket).
"""

from __future__ import annotations

import argparse
import importlib.util
import platform
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

import numpy as np
import trimesh
from scipy import ndimage
from scipy.spatial import cKDTree
from skimage.measure import marching_cubes

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from app.geometry import parts
from app.geometry.mesh import load_mesh
from app.geometry.model_edges import PreparedModel, prepare_model
from tests.geometry.test_feature_edges import boss_and_hole, plate_scan

BEFORE_COMMIT = "a3bbe4e"
EXTERNAL = REPO.parent / "shared" / "data" / "external" / "trimesh_models"


def old_module():
    """model_edges.py before feature edges, imported under another name."""
    src = subprocess.run(["git", "-C", str(REPO), "show", f"{BEFORE_COMMIT}:app/geometry/model_edges.py"],
                         check=True, capture_output=True, text=True).stdout
    f = Path(tempfile.mkdtemp()) / "model_edges_before.py"
    f.write_text(src)
    spec = importlib.util.spec_from_file_location("model_edges_before", f)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["model_edges_before"] = mod
    spec.loader.exec_module(mod)
    return mod


def as_current(old) -> PreparedModel:
    """The old module's PreparedModel as this tree's class (same fields; no denoised normals)."""
    return PreparedModel(**{k: getattr(old, k) for k in old.__dataclass_fields__})


def scan_of(mesh: trimesh.Trimesh, pitch: float, noise: float, seed: int) -> trimesh.Trimesh:
    """A scan-like mesh: marching cubes of the signed distance (exact within 2 cells of the surface,
    from the voxel distance transform elsewhere) on a grid off the part's coordinates, plus noise."""
    lo = mesh.bounds[0] - 3.37 * pitch
    n = np.ceil((mesh.bounds[1] + 3 * pitch - lo) / pitch).astype(int) + 1
    vox = mesh.voxelized(pitch).fill()
    occ = np.zeros(n, bool)
    idx = np.round((vox.points - lo) / pitch).astype(int)
    ok = np.all((idx >= 0) & (idx < n), axis=1)
    occ[tuple(idx[ok].T)] = True
    sdf = np.where(occ, ndimage.distance_transform_edt(occ) * pitch - 0.5 * pitch,
                   -(ndimage.distance_transform_edt(~occ) * pitch - 0.5 * pitch))
    band = np.abs(sdf) < 2.5 * pitch
    grid = lo + pitch * np.argwhere(band)
    sdf[band] = trimesh.proximity.signed_distance(mesh, grid)
    v, f, _, _ = marching_cubes(sdf, 0.0, spacing=(pitch,) * 3)
    s = trimesh.Trimesh(v + lo, f[:, ::-1], process=True)
    if s.volume < 0:
        s.invert()
    s.vertices = s.vertices + np.random.default_rng(seed).normal(0, noise, s.vertices.shape)
    return s


def plate_with_block() -> trimesh.Trimesh:
    """The part of tests/geometry/test_feature_edges.py: 100 x 60 x 20 plate, R 10 vertical fillets,
    a sharp 40 x 30 x 15 block on top."""
    plate = parts._prism(parts._rounded_rect(0, 0, 100, 60, 10), 0, 20)
    blk = trimesh.creation.box(bounds=[[20, 15, 19.9], [60, 45, 35]])
    return trimesh.boolean.union([plate, blk], engine="manifold")


def crease_samples(m) -> np.ndarray:
    return m.samples_obj[m.edge_feature[m.sample_edge]]


def timed_prepare(fn, mesh, name, step):
    t = time.perf_counter()
    m = fn(mesh, name, sample_step_mm=step)
    return m, time.perf_counter() - t


def measure_part(old, name, mesh, clean_ref=None, step=None):
    """Row of figures for one mesh; ``clean_ref`` (prepared clean part) to score a scan against."""
    step = step or float(np.clip(np.linalg.norm(mesh.extents) / 300.0, 0.25, 4.0))
    mo, to = timed_prepare(old.prepare_model, mesh, name, step)
    mn, tn = timed_prepare(prepare_model, mesh, name, step)
    row = {"part": name, "faces": len(mesh.faces), "noisy": bool(mn.extra["edges"]["noisy"]),
           "old_creases": int(mo.edge_feature.sum()), "new_creases": int(mn.edge_feature.sum()),
           "old_len": len(crease_samples(mo)) * step, "new_len": len(crease_samples(mn)) * step,
           "old_s": to, "new_s": tn, "old_samples": len(mo.samples_obj), "new_samples": len(mn.samples_obj)}
    if clean_ref is not None:
        truth = crease_samples(clean_ref)
        tree = cKDTree(truth)
        row["true_len"] = len(truth) * clean_ref.sample_step_mm
        for tag, m in (("old", mo), ("new", mn)):
            P = crease_samples(m)
            row[f"{tag}_false"] = float(np.mean(tree.query(P)[0] > 1.0)) if len(P) else 0.0
            row[f"{tag}_found"] = float(np.mean(cKDTree(P).query(truth)[0] < 1.0)) if len(P) else 0.0
    return row, mo, mn


def fit_check(clean: trimesh.Trimesh, models: dict, seed: int = 0):
    """Render the clean part, fit each edge model from the true pose; returns {tag: (score, dxy, dz, drz, ms)}."""
    from app.synth.scene import (
        Scene,
        SceneObject,
        look_at_pose,
        place_on_table,
        render_scene,
    )
    from app.synth.table import box_table_layout, box_table_mesh
    from app.vision.object_pose import ObjectPose, locate_object

    W, H = 960, 600
    K = np.array([[950.0, 0, 478.0], [0, 950.0, 302.0], [0, 0, 1]])
    dist = np.array([-0.08, 0.05, 2e-4, -1e-4, 0.0])
    T_true = place_on_table(clean, 400.0, 200.0, 25.0)
    scene = Scene(width=W, height=H, K=K, dist=dist,
                  T_cam_table=look_at_pose(np.array([250.0, -150.0, 550.0]), np.array([400.0, 200.0, 0.0])),
                  table_mesh=box_table_mesh(), table_layout=box_table_layout(),
                  objects=[SceneObject("part", clean, T_true, albedo=0.65)], samples_per_axis=1,
                  noise_sigma=1.5, blur_sigma_px=0.6)
    r = render_scene(scene, np.random.default_rng(seed))
    out = {}
    for tag, m in models.items():
        t = time.perf_counter()
        res = locate_object(r.image, K, dist, scene.T_cam_table, m, gamma=scene.gamma, start_poses=[T_true])
        ms = (time.perf_counter() - t) * 1000
        if not isinstance(res, ObjectPose):
            out[tag] = (float("nan"),) * 4 + (ms, res.reason[:110])
            continue
        d = res.T_table_obj[:3, 3] - T_true[:3, 3]
        M = T_true[:3, :3] @ res.T_table_obj[:3, :3].T
        rz = abs(np.degrees(np.arctan2(M[1, 0] - M[0, 1], M[0, 0] + M[1, 1])))
        out[tag] = (res.score, float(np.hypot(d[0], d[1])), float(abs(d[2])), float(rz), ms, "")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "feature_edges.md"))
    ap.add_argument("--no-fit", action="store_true", help="skip the pose fit check")
    args = ap.parse_args()
    old = old_module()
    lib = REPO / "models_library"
    clean_parts = [(p.stem, load_mesh(p.read_bytes(), p.name, "mm")) for p in sorted(lib.glob("*.stl"))
                   if p.stem not in ("tslot_table_800x400",)]
    for f, unit in (("featuretype.STL", "inch"), ("featuretype.STEP", "mm"), ("plate_holes.STL", "mm"),
                    ("idler_riser.STL", "inch"), ("box_sides.STEP", "mm")):
        clean_parts.append((f, load_mesh((EXTERNAL / f).read_bytes(), f, unit)))
    clean_parts += [("boss+hole, 8 facets", boss_and_hole(8)), ("boss+hole, 10 facets", boss_and_hole(10))]
    rows = []
    for name, mesh in clean_parts:
        rows.append(measure_part(old, name, mesh)[0])
        print(name, rows[-1], file=sys.stderr)
    scans = []
    bracket = load_mesh((lib / "bracket_140.stl").read_bytes(), "b.stl", "mm")
    pin_block = load_mesh((lib / "pin_block_32.stl").read_bytes(), "p.stl", "mm")
    # (name, clean mesh, grid mm, noise mm, fit check)
    for name, mesh, pitch, noise, fit in (("plate+block", plate_with_block(), 1.0, 0.1, True),
                                          ("plate+block", plate_with_block(), 1.0, 0.3, False),
                                          ("plate+block", plate_with_block(), 0.5, 0.05, False),
                                          ("bracket_140", bracket, 1.0, 0.1, True),
                                          ("pin_block_32", pin_block, 0.5, 0.05, True)):
        step = float(np.clip(np.linalg.norm(mesh.extents) / 300.0, 0.25, 4.0))
        ref = prepare_model(mesh, name, sample_step_mm=step, detect_symmetry=False)
        t = time.perf_counter()
        # the test's part from its exact distance field (fast), library parts through scan_of
        s = plate_scan(pitch, noise, seed=7) if name == "plate+block" else scan_of(mesh, pitch, noise, seed=7)
        print(f"scan of {name}: {len(s.faces)} faces in {time.perf_counter() - t:.0f} s", file=sys.stderr)
        row, mo, mn = measure_part(old, f"{name} scan ({pitch} mm grid, noise {noise} mm)", s, ref, step)
        rows.append(row)
        if fit:
            scans.append((name, mesh, mo, mn, row))
        print(row, file=sys.stderr)
    fits = []
    if not args.no_fit:
        for name, mesh, mo, mn, row in scans:
            ref = prepare_model(mesh, name)
            f = fit_check(mesh, {"clean CAD": ref, "scan, before": as_current(mo), "scan, after": mn})
            fits.append((row["part"], f))
            print(name, f, file=sys.stderr)
    write(args.out, rows, fits)
    return 0


def write(path, rows, fits):
    cpu = next((ln.split(":", 1)[1].strip() for ln in Path("/proc/cpuinfo").read_text().splitlines()
                if ln.startswith("model name")), platform.processor())
    L = ["# Feature edges: creases from the part, not from its tessellation or scan noise", "",
         (f"`PYTHONPATH=. .venv/bin/python benchmarks/feature_edges.py` — {date.today()}, {cpu}, "
         f"Python {platform.python_version()}. Before: `app/geometry/model_edges.py` at {BEFORE_COMMIT} "
         "(every face adjacency above 30 deg a crease); after: `app/geometry/feature_edges.py`."), "",
         ("Crease length = crease samples x sample step (default step: diameter / 300 within 0.25-4 mm). "
         "Times are whole `prepare_model` calls (resting states and symmetry included) on a shared 2-core machine."), "",
         "| part | faces | creases before | creases after | crease length before (mm) | after (mm) | samples before | after | prepare before (s) | after (s) |",
         "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        L.append(f"| {r['part']} | {r['faces']} | {r['old_creases']} | {r['new_creases']} | {r['old_len']:.0f} | "
                 f"{r['new_len']:.0f} | {r['old_samples']} | {r['new_samples']} | {r['old_s']:.2f} | {r['new_s']:.2f} |")
    L += ["", ("Scans against the clean part's creases (false: share of the crease length more than 1 mm from a "
          "true crease; found: share of the true creases with a crease sample within 1 mm):"), "",
          "| scan | true crease length (mm) | before: length / false / found | after: length / false / found |",
          "| --- | ---: | --- | --- |"]
    for r in rows:
        if "true_len" in r:
            L.append(f"| {r['part']} | {r['true_len']:.0f} | {r['old_len']:.0f} mm / {r['old_false']:.0%} / "
                     f"{r['old_found']:.0%} | {r['new_len']:.0f} mm / {r['new_false']:.0%} / {r['new_found']:.0%} |")
    if fits:
        L += ["", ("Fit check: the clean part rendered on the table (app/synth, 960 x 600, camera 45 deg above), "
              "`locate_object` started at the true pose with each edge model. Score = share of the visible model "
              "edge samples supported by image edges."), "",
              "| part | edge model | score | error xy (mm) | error z (mm) | error rz (deg) | time (ms) | note |",
              "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |"]
        for part, f in fits:
            for tag, (sc, dxy, dz, drz, ms, note) in f.items():
                L.append(f"| {part} | {tag} | {sc:.2f} | {dxy:.2f} | {dz:.2f} | {drz:.2f} | {ms:.0f} | {note} |")
    Path(path).write_text("\n".join(L) + "\n")


if __name__ == "__main__":
    sys.exit(main())
