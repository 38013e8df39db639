"""Benchmark: rotary-axis angle error from generated images, reference method vs ours (direct).

For each condition (camera tilt to the rotary axis, image noise, resolution) a bidirectional run
(0..315 deg step 45 up, then down) of the default 150 mm target is generated with a known injected
error curve (8" sinusoid + 3" second harmonic + 0.02"/deg slope + 4" reversal), lens distortion,
0.15 deg mounting tilt, 1.4 mm eccentricity, blur 0.8 px, gamma 2.2, 8 bit. Both methods measure
``E = commanded increment - measured increment``; the figure is the RMS over the images (first
excluded, it is the zero) of ``E_measured - E_true`` in arc-seconds, plus the reversal value the
ISO 230-2 evaluation recovers (true mean reversal 4.0").

    .venv/bin/python benchmarks/rotary.py            # full table (~10 min on 2 busy cores)
    .venv/bin/python benchmarks/rotary.py --quick    # 1280x960, noise 0.01 only
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from app.synth.rotary_images import (ErrorCurve, RotaryScene, generate_run, iso_bidirectional_angles,
                                     scaled_scene, true_errors_arcsec)
from app.vision.intrinsics import parse_intrinsics
from app.vision.rotary import measure_run
from app.vision.rotary_report import iso230_evaluate
from app.vision.rotary_target import default_target


def one(width: int, height: int, tilt_deg: float, noise: float, jpeg: int | None, seed: int) -> dict:
    scene = scaled_scene(RotaryScene(camera_tilt_deg=tilt_deg, noise_sigma=noise, jpeg_quality=jpeg),
                         width, height)
    angles, dirs = iso_bidirectional_angles([float(a) for a in range(0, 360, 45)], repeats=1)
    target = default_target()
    shots = generate_run(target, angles, dirs, scene=scene, curve=ErrorCurve(), seed=seed)
    truth = true_errors_arcsec(shots)
    intr = parse_intrinsics(scene.intrinsics_dict())
    images = [s.image for s in shots]
    row = {"res": f"{width}x{height}", "tilt": tilt_deg, "noise": noise, "jpeg": jpeg or "-"}
    for method in ("reference", "direct"):
        t0 = time.perf_counter()
        r = measure_run(images, angles, intr, target, method)
        dt = (time.perf_counter() - t0) / len(images)
        if not r.ok:
            row[method] = f"failed: {r.reason[:60]}"
            continue
        d = (np.array(r.error_arcsec) - truth)[1:]
        rep = iso230_evaluate(angles, r.error_arcsec, dirs)
        row[method] = (float(np.sqrt(np.mean(d ** 2))), float(np.abs(d).max()), rep.mean_reversal_arcsec, dt)
    return row


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    conds = []
    if args.quick:
        conds = [(1280, 960, t, 0.01, None) for t in (0.0, 15.0, 30.0)]
    else:
        for t in (0.0, 15.0, 30.0):
            for n in (0.005, 0.01, 0.02):
                conds.append((1280, 960, t, n, None))
        conds.append((1280, 960, 30.0, 0.01, 90))
        for t in (0.0, 15.0, 30.0):
            conds.append((2448, 2048, t, 0.01, None))
        conds.append((2448, 2048, 30.0, 0.02, 90))
    print("| image | tilt deg | noise | JPEG q | reference RMS \" | reference max \" | ours RMS \" "
          "| ours max \" | reversal ours \" (true 4.0) | s/image ref / ours |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for k, c in enumerate(conds):
        row = one(*c, seed=100 + k)
        ref, ours = row["reference"], row["direct"]
        if isinstance(ref, str) or isinstance(ours, str):
            print(f"| {row['res']} | {row['tilt']:g} | {row['noise']:g} | {row['jpeg']} | {ref} | | {ours} | | | |")
            continue
        print(f"| {row['res']} | {row['tilt']:g} | {row['noise']:g} | {row['jpeg']} | {ref[0]:.2f} | {ref[1]:.2f} "
              f"| **{ours[0]:.2f}** | {ours[1]:.2f} | {ours[2]:.2f} | {ref[3]:.2f} / {ours[3]:.2f} |",
              flush=True)


if __name__ == "__main__":
    main()
