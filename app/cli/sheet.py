"""``setupcam sheet``: find a sheet on a cutting bed in one image (batch use and tests, no server).

    setupcam sheet --image IMG --intrinsics CAM.json --bed-pose T_CAM_BED.json --thickness MM
                   [--margin-mm M] [--json] [--draw OUT.png] [--baseline]

``T_CAM_BED.json`` holds ``{"T_cam_bed": 4x4}`` (mm): the pose of the bed frame in the camera (bed
origin at a front-left corner of the slat field, x along the long side, z up, slat tips at z = 0).
The answer holds ``corners_px`` and ``corners_bed_mm`` (4 x 2, nearest to the bed origin first, then
counter-clockwise seen from above), ``angle_deg`` (edge corner 0 -> 1 against bed x), the work origin
and the offset (x_mm, y_mm, c_deg) in the bed frame. Exit code 0: found; 1: no sheet (the reason is
printed); 2: bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sheet", help="find a sheet on a laser/plasma bed: corners, angle, work origin",
                       description="Finds the sheet's four corners (subpixel), its angle and the work origin in the bed frame (mm, deg).")
    p.add_argument("--image", required=True, help="camera image of the bed (JPEG/PNG)")
    p.add_argument("--intrinsics", required=True, help="camera intrinsics JSON (DESIGN format)")
    p.add_argument("--bed-pose", required=True, help='JSON file {"T_cam_bed": 4x4} (mm)')
    p.add_argument("--thickness", required=True, type=float, help="sheet thickness in mm (its top is z = thickness)")
    p.add_argument("--margin-mm", type=float, default=0.0, help="work origin inset from the corner along both edges, 0..20 mm")
    p.add_argument("--min-side-mm", type=float, default=50.0, help="smallest sheet side accepted (mm)")
    p.add_argument("--draw", help="write the detection picture to this PNG")
    p.add_argument("--baseline", action="store_true", help="also report the reference corner finder (threshold + row scan)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def _load_bed_pose(path: str):
    from app.geometry.transforms import check_pose

    data = json.loads(Path(path).read_text())
    if not isinstance(data, dict) or "T_cam_bed" not in data:
        raise ValueError(f'{path}: expected a JSON object {{"T_cam_bed": 4x4}}')
    return check_pose(data["T_cam_bed"], "T_cam_bed", tol=1e-5)


def run(args: argparse.Namespace) -> int:
    import cv2

    from app.vision.bed_scale import BedPlane
    from app.vision.intrinsics import load_intrinsics
    from app.vision.sheet import baseline_corners, draw_sheet, find_sheet

    try:
        image = cv2.imread(args.image, cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"{args.image}: not a readable image")
        cam = load_intrinsics(args.intrinsics)
        if (image.shape[1], image.shape[0]) != (cam.width, cam.height):
            raise ValueError(f"image is {image.shape[1]} x {image.shape[0]} px but the intrinsics are for "
                             f"{cam.width} x {cam.height} px; use the calibration of this camera and resolution")
        plane = BedPlane.create(cam.K_array, cam.dist_array, _load_bed_pose(args.bed_pose), args.thickness)
        if not 0.0 <= args.margin_mm <= 20.0:
            raise ValueError(f"--margin-mm {args.margin_mm} is outside 0..20 mm")
    except (OSError, ValueError) as exc:
        print(f"setupcam sheet: {exc}", file=sys.stderr)
        return 2
    result = find_sheet(image, plane, margin_mm=args.margin_mm, min_side_mm=args.min_side_mm)
    answer = result.as_dict()
    if args.baseline:
        base = baseline_corners(image, plane)
        answer["baseline"] = (
            {"corners_px": base.corners_px.tolist(), "corners_bed_mm": base.corners_bed_mm.round(3).tolist(),
             "angle_deg": round(base.angle_deg, 5), "threshold": base.threshold} if base else base.as_dict())
    if args.draw:
        cv2.imwrite(args.draw, draw_sheet(image, result))
    if args.json:
        print(json.dumps(answer, indent=1))
    elif result:
        o = result.offset
        print(f"sheet found: angle {result.angle_deg:.4f} deg, origin X {o.x_mm:.3f} mm, Y {o.y_mm:.3f} mm (margin {result.margin_mm:g} mm)")
        for k, (p, q) in enumerate(zip(result.corners_px, result.corners_bed_mm)):
            print(f"  corner {k}: ({p[0]:.2f}, {p[1]:.2f}) px  ->  ({q[0]:.3f}, {q[1]:.3f}) mm")
    else:
        print(result.reason)
    return 0 if result else 1
