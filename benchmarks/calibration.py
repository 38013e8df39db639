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


if __name__ == "__main__":
    main()
