"""``setupcam rotary``: rotary-axis angle errors from images of a concentric-circle target.

    setupcam rotary --images a.png b.png ... --angles-deg 0 10 ... --intrinsics cam.json \
        --target target.json --json [--report DIR]
    setupcam rotary --print-target target.pdf [--target target.json]

Answer (``--json``): ``angles_deg`` (commanded), ``measured_deg`` (first commanded angle + measured
increment) and ``error_arcsec`` (commanded increment - measured increment, first image = 0) per
image. Exit code 0 measured, 1 measurement failed (reason printed), 2 bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("rotary", help="rotary-axis angle errors from images of a circle target",
                       description="Measure rotary-axis positioning errors (arc-seconds) from images of "
                                   "a concentric-circle target taken at commanded angles.")
    p.add_argument("--images", nargs="+", default=[], help="images in the order they were taken")
    p.add_argument("--angles-deg", nargs="+", type=float, default=[], help="commanded angle of each image, deg")
    p.add_argument("--directions", nargs="+", type=int, default=None,
                   help="approach direction of each image (+1/-1); default: from the angle sequence")
    p.add_argument("--intrinsics", help="camera intrinsics JSON (DESIGN format)")
    p.add_argument("--target", help="target JSON {groups: [{center_mm, circle_radii_mm}], mark_mm}; "
                                    "default: the built-in 150 mm disc")
    p.add_argument("--method", default="direct", choices=["direct", "reference"],
                   help="direct (ours, default) or reference (ellipse centres + 6 lines)")
    p.add_argument("--report", help="write CSV, PNG/SVG plot and compensation proposals to this folder")
    p.add_argument("--axis-name", default="C", help="axis letter used in the HEIDENHAIN proposal")
    p.add_argument("--overlay-dir", help="write one detection picture per image to this folder")
    p.add_argument("--print-target", help="write the printable target (.pdf or .svg) and exit")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def _fail(msg: str, as_json: bool, code: int) -> int:
    if as_json:
        print(json.dumps({"ok": False, "reason": msg}))
    else:
        print(f"error: {msg}", file=sys.stderr)
    return code


def run(args: argparse.Namespace) -> int:
    import cv2

    from app.vision.intrinsics import load_intrinsics
    from app.vision.rotary import RotaryError, draw_rotary, measure_run
    from app.services.rotary import rotary_report
    from app.vision.printables import target_pdf, target_svg
    from app.vision.rotary_target import TargetError, default_target, target_from_dict

    try:
        target = (target_from_dict(json.loads(Path(args.target).read_text())) if args.target
                  else default_target())
    except (OSError, json.JSONDecodeError, TargetError) as exc:
        return _fail(f"target {args.target}: {exc}", args.json, 2)
    if args.print_target:
        out = Path(args.print_target)
        if out.suffix.lower() == ".pdf":
            out.write_bytes(target_pdf(target))
        elif out.suffix.lower() == ".svg":
            out.write_text(target_svg(target))
        else:
            return _fail(f"--print-target {out}: use a .pdf or .svg file name", args.json, 2)
        print(json.dumps({"ok": True, "target_file": str(out)}) if args.json else f"wrote {out}")
        return 0
    if not args.images or not args.intrinsics:
        return _fail("--images, --angles-deg and --intrinsics are required (or --print-target)",
                     args.json, 2)
    if len(args.images) != len(args.angles_deg):
        return _fail(f"{len(args.images)} images but {len(args.angles_deg)} angles; give one commanded "
                     "angle per image", args.json, 2)
    if args.directions is not None and (len(args.directions) != len(args.images)
                                        or any(d not in (-1, 1) for d in args.directions)):
        return _fail("--directions needs one +1 or -1 per image", args.json, 2)
    try:
        cam = load_intrinsics(args.intrinsics)
    except (OSError, ValueError) as exc:
        return _fail(f"intrinsics {args.intrinsics}: {exc}", args.json, 2)
    images = []
    for path in args.images:
        img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
        if img is None:
            return _fail(f"{path}: not a readable image", args.json, 2)
        images.append(img)
    try:
        res = measure_run(images, args.angles_deg, cam, target, args.method)
    except RotaryError as exc:
        return _fail(str(exc), args.json, 2)
    if args.overlay_dir:
        od = Path(args.overlay_dir)
        od.mkdir(parents=True, exist_ok=True)
        for i, (img, r) in enumerate(zip(images, res.images)):
            cv2.imwrite(str(od / f"rotary_{i:03d}.png"), draw_rotary(img, r))
    if not res.ok:
        return _fail(res.reason, args.json, 1)
    answer = {"ok": True, "method": res.method, "angles_deg": list(res.angles_deg),
              "measured_deg": list(res.measured_deg), "error_arcsec": list(res.error_arcsec),
              "axis_cam": res.axis_cam,
              "images": [{"file": f, "rms_px": r.rms_px if r.rms_px == r.rms_px else None,
                          "n_edge_points": r.n_edge_points}
                         for f, r in zip(args.images, res.images)]}
    if args.report:
        rep, named = rotary_report(res.angles_deg, res.measured_deg, res.error_arcsec, args.directions,
                                   args.axis_name)
        out = Path(args.report)
        out.mkdir(parents=True, exist_ok=True)
        paths = []
        for name, data in named.items():
            (out / name).write_bytes(data)
            paths.append(out / name)
        answer["report"] = rep.to_dict()
        answer["report_files"] = [str(p) for p in paths]
    if args.json:
        print(json.dumps(answer))
    else:
        print(f"{'image':>5} {'commanded_deg':>14} {'measured_deg':>16} {'error_arcsec':>13}")
        for i, (a, m, e) in enumerate(zip(res.angles_deg, res.measured_deg, res.error_arcsec)):
            print(f"{i:>5} {a:>14.4f} {m:>16.6f} {e:>13.2f}")
        if args.report:
            print(f"report written to {args.report}")
    return 0
