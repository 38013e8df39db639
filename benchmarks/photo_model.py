"""Photo models (app/vision/photo_model.py) on generated scenes: teach a plate from two pictures, locate
repeat placements (other x, y, turn and camera pose) and tell two look-alike plates apart.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/photo_model.py [--scenes 6] [--seed 0]

Each plate (app/synth/photo_scenes.py: 140 x 90 x 12 mm with a corner notch; A with two holes, B
the same with a third) is taught from two pictures of one placement each (the second turned by
120 degrees, the camera elsewhere; ``--teach-pictures 1``: the first only), the table located from
its markers in every picture. Then
``--scenes`` repeat placements per plate at random x, y, turn and camera pose (distance 600-800 mm,
elevation 50-70 degrees, any azimuth in front of the table) are located: the error is that of the
plate's motion from the teach picture (truth) against the one found, at the taught frame's origin.
Look-alikes: every repeat picture of A is searched for B alone and every picture of B for A alone
(a wrong acceptance is a located pose), and both pictures go through recognition among {A, B}.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from app.geometry.model_edges import prepare_model
from app.synth.photo_scenes import plate_a, plate_b, shot
from app.vision import photo_model as pm
from app.vision.fiducials import locate_table
from app.vision.localize import marker_labels_table


def view_of(s, table_model) -> pm.View:
    tp = locate_table(s.image, s.K, s.dist, s.layout)
    if not tp:
        raise RuntimeError(tp.reason)
    ign = pm.known_edge_mask(s.image.shape, s.K, s.dist, tp.T_cam_table, [(table_model, np.eye(4))],
                             marker_labels_table(s.layout))
    return pm.View(s.image, s.K, s.dist, tp.T_cam_table, ign)


def turn_deg(T: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--teach-pictures", type=int, choices=(1, 2), default=2,
                    help="teach from the first picture only, or from both")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    meshes = {"A": plate_a(), "B": plate_b()}
    table_model = None
    models, teach_T = {}, {}
    t0 = time.perf_counter()
    for k, (name, mesh) in enumerate(meshes.items()):
        s1 = shot(mesh, 380, 200, 10, seed=100 + k)
        s2 = shot(mesh, 430, 180, 130, seed=200 + k, azimuth_deg=-60, elevation_deg=55)
        if table_model is None:
            table_model = prepare_model(s1.table_mesh, "table", detect_symmetry=False)
        views = [view_of(s1, table_model), view_of(s2, table_model)][:args.teach_pictures]
        model, _ = pm.teach(views, 12.0)
        models[name], teach_T[name] = model, s1.T_table_obj
    teach_s = time.perf_counter() - t0
    rows, wrong, refused_ok, located_s = [], [], [], []
    recog = {"right": 0, "refused": 0, "wrong": 0}
    for i in range(args.scenes):
        for name, mesh in meshes.items():
            x, y, c = rng.uniform(250, 550), rng.uniform(130, 270), rng.uniform(0, 360)
            s = shot(mesh, x, y, c, seed=1000 + 10 * i + (name == "B"), distance_mm=rng.uniform(600, 800),
                     elevation_deg=rng.uniform(50, 70), azimuth_deg=rng.uniform(-130, -50),
                     cam_target=(x + rng.uniform(-80, 80), y + rng.uniform(-40, 40)))
            v = view_of(s, table_model)
            m = models[name]
            truth = s.T_table_obj @ np.linalg.inv(teach_T[name]) @ m.T_table_obj_teach
            t = time.perf_counter()
            p = pm.locate(v, m, name)
            located_s.append(time.perf_counter() - t)
            if p:
                e = p.T_table_obj[:2, 3] - truth[:2, 3]
                de = (turn_deg(p.T_table_obj) - turn_deg(truth) + 180) % 360 - 180
                rows.append({"model": name, "x": round(x, 1), "y": round(y, 1), "c": round(c, 1),
                             "err_mm": float(np.hypot(*e)), "err_deg": abs(de), "sigma_x": p.sigma["x_mm"],
                             "sigma_y": p.sigma["y_mm"], "sigma_c": p.sigma["rz_deg"], "score": p.score,
                             "pass": p.uncertainty_ok})
            else:
                rows.append({"model": name, "x": round(x, 1), "y": round(y, 1), "c": round(c, 1), "failed": p.reason})
            other = "B" if name == "A" else "A"
            q = pm.locate(v, models[other], other)
            (wrong if q else refused_ok).append(f"{other} in a picture of {name}: "
                                                + (f"located (score {q.score:.2f})" if q else q.reason))
            located = [(n, models[n], r) for n, r in ((name, p), (other, q)) if r]
            acc, _ = pm.decide_lookalikes(v, located)
            names = [located[j][0] for j in acc]
            recog["right" if names == [name] else "refused" if not names else "wrong"] += 1
    ok = [r for r in rows if "err_mm" in r]
    out = {
        "teach_pictures": args.teach_pictures, "scenes": len(rows), "located": len(ok), "teach_s": round(teach_s, 1),
        "median_err_mm": float(np.median([r["err_mm"] for r in ok])) if ok else None,
        "max_err_mm": float(np.max([r["err_mm"] for r in ok])) if ok else None,
        "median_err_deg": float(np.median([r["err_deg"] for r in ok])) if ok else None,
        "max_err_deg": float(np.max([r["err_deg"] for r in ok])) if ok else None,
        "median_sigma_xy_mm": float(np.median([max(r["sigma_x"], r["sigma_y"]) for r in ok])) if ok else None,
        "median_sigma_c_deg": float(np.median([r["sigma_c"] for r in ok])) if ok else None,
        "within_2_sigma": int(sum(bool(r["err_mm"] <= 2 * np.hypot(r["sigma_x"], r["sigma_y"])) for r in ok)),
        "pass": int(sum(bool(r["pass"]) for r in ok)),
        "median_locate_s": float(np.median(located_s)),
        "wrong_model_accepted": len(wrong), "wrong_model_refused": len(refused_ok),
        "recognition_A_vs_B": recog, "wrong_details": wrong, "rows": rows,
    }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
