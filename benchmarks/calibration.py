"""Calibration on real image sets: our default corner refinement vs OpenCV's sample settings (baseline).

Method: ``calibrate`` with the default cornerSubPix half window (11 px capped at 40 % of the corner
spacing). Baseline: the same with ``subpix_half_window_px=11``, i.e. OpenCV samples/cpp/calibration.cpp.
Data and published references: ../shared/data/external (SOURCES.md). Prints a markdown table.

    .venv/bin/python benchmarks/calibration.py
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from app.vision.calibration import BoardSpec, calibrate

EXT = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "external"

SETS = [
    # name, files, board, options, published (fx, fy, cx, cy, rms)
    ("OpenCV left01-14 (fix aspect)", sorted((EXT / "opencv_samples_data").glob("left*.jpg")),
     BoardSpec(kind="chessboard", inner_corners=(9, 6), square_mm=25), {"fix_aspect_ratio": True},
     (535.916, 535.916, 342.283, 235.571, 0.3926)),
    ("ChArUco img_00-03", sorted((EXT / "opencv_contrib_aruco").glob("img_0*.jpg")),
     BoardSpec(kind="charuco", squares=(5, 7), square_mm=40, marker_mm=20, dictionary="DICT_6X6_250"), {},
     (452.511, 456.767, 317.703, 277.752, 0.1824)),
    ("BoofCV Sony chess (k1,k2 only)", sorted((EXT / "boofcv_data" / "Sony_DSC-HX5V_Chess").glob("frame*.jpg")),
     BoardSpec(kind="chessboard", squares=(5, 7), square_mm=30), {"zero_tangent_dist": True, "fix_k3": True},
     (701.012, 698.654, 308.455, 246.843, None)),
]


def main() -> None:
    print("| set | variant | fx | fy | cx | cy | RMS px | worst view px | max \\|Δf\\| vs published px | ms |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, files, board, opts, ref in SETS:
        images = [cv2.imread(str(f)) for f in files]
        for variant, window in (("ours (capped window)", None), ("baseline: OpenCV sample (11 px)", 11)):
            t0 = time.perf_counter()
            r = calibrate(images, board, names=[f.name for f in files], subpix_half_window_px=window, **opts)
            ms = 1000 * (time.perf_counter() - t0)
            if not r:
                print(f"| {name} | {variant} | failed: {r.reason} |")
                continue
            K = r.K
            worst = max(r.views, key=lambda v: v.rms_px or 0)
            df = max(abs(K[0, 0] - ref[0]), abs(K[1, 1] - ref[1]))
            print(f"| {name} | {variant} | {K[0, 0]:.2f} | {K[1, 1]:.2f} | {K[0, 2]:.2f} | {K[1, 2]:.2f} | "
                  f"{r.rms_px:.3f} | {worst.rms_px:.2f} ({worst.name}) | {df:.2f} | {ms:.0f} |")
        rms = "—" if ref[4] is None else f"{ref[4]:.3f}"
        print(f"| {name} | published | {ref[0]:.2f} | {ref[1]:.2f} | {ref[2]:.2f} | {ref[3]:.2f} | {rms} | | | |")


def distortion_field(KA, dA, KB, dB, size) -> np.ndarray:
    """(N, 2) px: where calibration B puts the pixels that calibration A maps to the same rays, over a
    33 x 25 grid of the image ``size`` (W, H)."""
    W, H = size
    uu, vv = np.meshgrid(np.linspace(0, W - 1, 33), np.linspace(0, H - 1, 25))
    px = np.stack([uu.ravel(), vv.ravel()], 1)
    n = cv2.undistortPoints(px.reshape(-1, 1, 2), KA, dA).reshape(-1, 2)
    q, _ = cv2.projectPoints(np.c_[n, np.ones(len(n))], np.zeros(3), np.zeros(3), KB, dB)
    return q.reshape(-1, 2) - px


def beyond_focal_and_centre(KA, dA, KB, dB, size) -> tuple[float, float, float]:
    """How far two calibrations disagree in the image (max, mean px), and what is left (max px) after
    the focal length and principal point of B are moved to match A best: the part of the difference
    that the engine's intrinsics sigma (f, cx, cy) does not describe."""
    from scipy.optimize import least_squares

    from app.vision.intrinsics import moved_intrinsics

    d = np.linalg.norm(distortion_field(KA, dA, KB, dB, size), axis=1)

    def res(x):
        K2 = moved_intrinsics(moved_intrinsics(moved_intrinsics(KB, 0, x[0]), 1, x[1]), 2, x[2])
        return distortion_field(KA, dA, K2, dB, size).ravel()

    left = np.linalg.norm(least_squares(res, np.zeros(3)).fun.reshape(-1, 2), axis=1)
    return float(d.max()), float(d.mean()), float(left.max())


PUBLISHED_LEFT_DIST = np.array([-0.266373, -0.0385889, 0.00178319, -0.000281221, 0.238392])


def distortion_agreement() -> None:
    """The left01-14 set: our calibration against the published one (its distortion too), OpenCV's
    sample settings, and itself without each view in turn (leave-one-out)."""
    name, files, board, opts, ref = SETS[0]
    images = [cv2.imread(str(f)) for f in files]
    size = images[0].shape[1], images[0].shape[0]
    ours = calibrate(images, board, names=[f.name for f in files], **opts)
    KA, dA = ours.K, np.asarray(ours.dist, float).ravel()[:5]
    K_pub = np.array([[ref[0], 0, ref[2]], [0, ref[1], ref[3]], [0, 0, 1.0]])
    sample = calibrate(images, board, names=[f.name for f in files], subpix_half_window_px=11, **opts)
    rows = [("published (its own distortion)", K_pub, PUBLISHED_LEFT_DIST),
            ("OpenCV sample settings (11 px)", sample.K, np.asarray(sample.dist, float).ravel()[:5])]
    loo = []
    for k in range(len(images)):
        r = calibrate([im for j, im in enumerate(images) if j != k], board,
                      names=[f.name for j, f in enumerate(files) if j != k], **opts)
        if r:
            loo.append(beyond_focal_and_centre(KA, dA, r.K, np.asarray(r.dist, float).ravel()[:5], size))
    print(f"\n{name}: our calibration against another of the same camera, px over the {size[0]} x {size[1]} image")
    print("| other calibration | max px | mean px | max px left after the best f, cx, cy match |")
    print("|---|---|---|---|")
    for label, K, d in rows:
        m, mean, left = beyond_focal_and_centre(KA, dA, K, d, size)
        print(f"| {label} | {m:.2f} | {mean:.2f} | {left:.2f} |")
    L = np.array(loo)
    cells = " | ".join(f"{np.median(L[:, k]):.2f} / {L[:, k].max():.2f}" for k in range(3))
    print(f"| leave one view out ({len(L)} calibrations): median / max | {cells} |")


if __name__ == "__main__":
    main()
    distortion_agreement()
