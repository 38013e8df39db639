"""Photo models (app/vision/photo_model/) on generated scenes: teach a plate from two pictures, locate
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
(a wrong acceptance is a located pose), and both pictures go through recognition among {A, B}
(``--skip-lookalikes``: not done, for the sigma only).

Sigma: per axis (x, y, rz) the share of errors within 1 and 3 sigma and the mean NEES per dof, on the
first half of the scenes (where the edge bias is fitted), the second half (held out) and both, for
the old sigma (the fit only), the committed one and the one with the bias fitted on the first half
(printed as a markdown table at the end; ``--json FILE`` keeps every row with its covariance parts).
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
    return pm.View.of(s.image, s.K, s.dist, tp, ign)


def turn_deg(T: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(T[1, 0], T[0, 0])))


def covs(rows: list[dict], bias_px: float | None) -> np.ndarray:
    """(n, 3, 3) covariances of (x mm, y mm, rz rad) of the located rows from the parts
    :func:`app.vision.photo_model.locate` reports: ``fit + table + bias_px^2 (teach px^2 + px^2)`` in x
    and y; bias_px None: the old sigma (the fit only, no table pose, no edge bias)."""
    F = np.array([r["fit"] for r in rows])
    if bias_px is None:
        return F
    T = np.array([r["table"] for r in rows])
    B = np.array([r["edge_bias_mm2"] for r in rows])[:, None, None] * np.diag([1.0, 1.0, 0.0])
    return F + T + bias_px ** 2 * B


def coverage(rows: list[dict], bias_px: float | None) -> dict:
    """Per axis (x, y, rz) the share of errors within 1 and 3 sigma, the mean NEES per degree of
    freedom (e^T C^-1 e / 3; 1 when sigma is right) and the PASS count (sigma under the gate)."""
    if not rows:
        return {}
    C = covs(rows, bias_px)
    E = np.array([r["e"] for r in rows])
    sd = np.sqrt(np.einsum("nii->ni", C))
    z = np.abs(E) / sd
    nees = float(np.mean([e @ np.linalg.solve(c, e) for e, c in zip(E, C)]) / 3)
    gate = (np.max(sd[:, :2], axis=1) <= 0.3) & (np.degrees(sd[:, 2]) <= 0.05)
    return {"n": len(rows), "within_1": [round(float(v), 3) for v in np.mean(z <= 1, axis=0)],
            "within_3": [round(float(v), 3) for v in np.mean(z <= 3, axis=0)], "nees_per_dof": round(nees, 3),
            "pass": int(gate.sum()), "median_sigma": [round(float(v), 4) for v in np.median(sd, axis=0)]}


def fit_bias(rows: list[dict], target: float = 0.6827) -> float:
    """The edge bias (px) that puts ``target`` of the x and y errors of ``rows`` within 1 sigma
    (bisection: the share grows with the bias; rz does not depend on it)."""
    E = np.abs(np.array([r["e"] for r in rows])[:, :2])
    lo, hi = 0.0, 2.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        sd = np.sqrt(np.einsum("nii->ni", covs(rows, mid))[:, :2])
        lo, hi = (mid, hi) if float(np.mean(E <= sd)) < target else (lo, mid)
    return 0.5 * (lo + hi)


def coverage_table(rows: list[dict], n_scenes: int) -> dict:
    """Coverage of the sigma before (fit only), as committed, and with the edge bias fitted on the
    first half of the scenes (placements of scenes < n/2), on each half and on both."""
    first = [r for r in rows if r["scene"] < n_scenes // 2]
    second = [r for r in rows if r["scene"] >= n_scenes // 2]
    fitted = fit_bias(first) if first else float("nan")
    out = {"fitted_edge_bias_px_first_half": round(fitted, 4), "committed_edge_bias_px": pm.EDGE_BIAS_PX}
    for label, bias in (("old (fit only)", None),
                        (f"committed (fit + table pose + edge bias {pm.EDGE_BIAS_PX:g} px)", pm.EDGE_BIAS_PX),
                        (f"edge bias fitted on first half ({fitted:.3f} px)", fitted)):
        out[label] = {half: coverage(rs, bias) for half, rs in (("first half", first), ("second half", second),
                                                                  ("both", rows))}
    return out


def print_coverage(tab: dict) -> None:
    """The coverage table as text (markdown rows)."""
    print("| sigma | half | n | x within 1 / 3 sigma | y within 1 / 3 sigma | rz within 1 / 3 sigma "
          "| NEES per dof | PASS |")
    print("|---|---|---|---|---|---|---|---|")
    for label, halves in tab.items():
        if not isinstance(halves, dict):
            continue
        for half, c in halves.items():
            if not c:
                continue
            ax = " | ".join(f"{100 * a:.0f} % / {100 * b:.0f} %" for a, b in zip(c["within_1"], c["within_3"]))
            print(f"| {label} | {half} | {c['n']} | {ax} | {c['nees_per_dof']:.2f} | {c['pass']} / {c['n']} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--teach-pictures", type=int, choices=(1, 2), default=2,
                    help="teach from the first picture only, or from both")
    ap.add_argument("--skip-lookalikes", action="store_true",
                    help="locate the right plate only (no wrong-plate search, no recognition): sigma only")
    ap.add_argument("--json", help="also write the result (with every row) to this file")
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
                parts = p.photo["cov_parts"]
                rows.append({"model": name, "scene": i, "x": round(x, 1), "y": round(y, 1), "c": round(c, 1),
                             "err_mm": float(np.hypot(*e)), "err_deg": abs(de), "sigma_x": p.sigma["x_mm"],
                             "sigma_y": p.sigma["y_mm"], "sigma_c": p.sigma["rz_deg"], "score": p.score,
                             "pass": p.uncertainty_ok, "e": [float(e[0]), float(e[1]), float(np.radians(de))],
                             "fit": parts["fit"], "table": parts["table"],
                             "edge_bias_mm2": parts["edge_bias_mm2"]})
            else:
                rows.append({"model": name, "x": round(x, 1), "y": round(y, 1), "c": round(c, 1), "failed": p.reason})
            if args.skip_lookalikes:
                continue
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
        "coverage": coverage_table(ok, args.scenes),
        "pass": int(sum(bool(r["pass"]) for r in ok)),
        "median_locate_s": float(np.median(located_s)),
        "wrong_model_accepted": len(wrong), "wrong_model_refused": len(refused_ok),
        "recognition_A_vs_B": recog, "wrong_details": wrong, "rows": rows,
    }
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    print(json.dumps({k: v for k, v in out.items() if k != "rows"}, indent=1))
    print_coverage(out["coverage"])


if __name__ == "__main__":
    main()
