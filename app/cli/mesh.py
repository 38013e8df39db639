"""``setupcam mesh``: check a CAD file as the model library would read it, without the server.

    setupcam mesh PART.step [--units mm|inch] [--thumbnail OUT.png] [--glb OUT.glb] [--json]

Prints the bounding box (mm), face count, watertightness, volume and the resting poses on a plane
(probability, height). Exit code 0: readable; 1: rejected (the reason is printed, with the HTTP
status the service would answer); 2: bad arguments or unreadable path.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("mesh", help="read a CAD file (STL/OBJ/PLY/GLB/STEP) as the library would: size, poses, thumbnail",
                       description="Loads a CAD file into mm, prints its summary and resting poses, optionally "
                                   "writes a thumbnail PNG and the normalised GLB.")
    p.add_argument("file", help="CAD file: .stl .obj .ply .glb .gltf .step .stp")
    p.add_argument("--units", default="mm", choices=["mm", "inch"],
                   help="unit of the coordinates (ignored for STEP, which declares its own)")
    p.add_argument("--max-faces", type=int, default=2_000_000, help="largest accepted face count")
    p.add_argument("--thumbnail", help="write a PNG thumbnail here")
    p.add_argument("--size-px", type=int, default=256, help="thumbnail size in pixels")
    p.add_argument("--glb", help="write the normalised GLB (mm, CAD frame) here")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.geometry.mesh import MeshError, load_mesh, mesh_summary, resting_poses, to_glb
    from app.geometry.thumbnail import render_thumbnail

    path = Path(args.file)
    try:
        data = path.read_bytes()
    except OSError as exc:
        print(f"setupcam mesh: {exc}", file=sys.stderr)
        return 2
    try:
        mesh = load_mesh(data, path.name, args.units, max_faces=args.max_faces)
    except MeshError as exc:
        print(f"setupcam mesh: rejected ({exc.status}): {exc}", file=sys.stderr)
        return 1
    summary = mesh_summary(mesh)
    poses = resting_poses(mesh)
    if args.thumbnail:
        Path(args.thumbnail).write_bytes(render_thumbnail(mesh, size_px=args.size_px))
    if args.glb:
        Path(args.glb).write_bytes(to_glb(mesh))
    result = {"file": path.name, "units_source": mesh.metadata.get("units_source"), **summary,
              "resting_poses": [p.to_dict() for p in poses]}
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    ext = " x ".join(f"{v:.3f}" for v in summary["extents_mm"])
    vol = "-" if summary["volume_mm3"] is None else f"{summary['volume_mm3']:.1f} mm3"
    print(f"{path.name}: {ext} mm, {summary['faces']} faces, watertight {summary['watertight']}, volume {vol}")
    print(f"  bbox min {[round(v, 3) for v in summary['bbox_min_mm']]} max {[round(v, 3) for v in summary['bbox_max_mm']]} mm"
          f" (units from the {'file' if result['units_source'] == 'file' else 'caller'})")
    for i, p in enumerate(poses):
        print(f"  pose {i}: probability {p.probability:.3f}, height {p.height_mm:.3f} mm")
    return 0
