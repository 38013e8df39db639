"""``setupcam localize``: locate table and objects in one image without the server (batch, tests)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("localize", help="locate the table and objects in one image (no server)",
                       description="Prints poses as 4x4 lists in mm; T_table_obj = inv(T_cam_table) @ T_cam_obj.")
    p.add_argument("--image", required=True, help="image of table and workpiece (JPEG/PNG)")
    p.add_argument("--intrinsics", required=True, help="camera intrinsics JSON (DESIGN format)")
    p.add_argument("--table", help="table mesh in the table frame (the table is located by its markers; its own "
                                   "edges - border, slots - are then kept from being taken for a part's)")
    p.add_argument("--layout", required=True, help="fiducial layout JSON of the table")
    p.add_argument("--model", action="append", default=[], help="a part to locate (STL/OBJ/PLY/GLB/STEP, mm); repeatable")
    p.add_argument("--clamp", action="append", default=[], help="a clamp/vise to locate (mesh file, mm); repeatable")
    p.add_argument("--support", action="append", default=[],
                   help="a support (parallel, fixture plate; mesh file, mm, standing as modelled); repeatable")
    p.add_argument("--riser", action="append", default=[], type=_height_mm, metavar="MM",
                   help="height of a parallel or riser the shop uses, without a model (mm); repeatable: a part "
                        "over a riser of unknown height is tested against these and the --support heights")
    p.add_argument("--library", help="a models_library folder: recognise its workpieces, clamps and supports")
    p.add_argument("--units", default="mm", choices=["mm", "inch"], help="units of --model/--clamp/--support files")
    p.add_argument("--overlay", help="write the overlay picture to this PNG")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def _height_mm(text: str) -> float:
    """A riser height from the command line: a positive number of mm, else a clear usage error."""
    try:
        h = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < h < 1e4:
        raise argparse.ArgumentTypeError(f"a riser is a positive height in mm, not {text}")
    return h


def _load_candidates(args) -> tuple[list, bool]:
    from app.geometry.mesh import load_mesh
    from app.vision.localize import Candidate

    cands = []
    for path, kind in ([(m, "workpiece") for m in args.model] + [(c, "clamp") for c in args.clamp]
                       + [(s, "support") for s in args.support]):
        p = Path(path)
        cands.append(Candidate(name=p.name, mesh=load_mesh(p.read_bytes(), p.name, args.units), kind=kind))
    recognise = False
    if args.library:
        import numpy as np

        from app.geometry.library_manifest import load_library_manifest

        lib = Path(args.library)
        entries = load_library_manifest(lib)
        key_of = {e.name: e.key for e in entries} | {e.key: e.key for e in entries}   # candidates go by key
        for e in entries:
            if e.kind in ("workpiece", "clamp", "support"):
                guide = None if e.guide is None else {**e.guide, "carrier": key_of[e.guide["carrier"]]}
                cands.append(Candidate(name=e.key, mesh=load_mesh((lib / e.file).read_bytes(), e.file, e.units),
                                       kind=e.kind, T_obj_datum=None if e.T_obj_datum is None else np.asarray(e.T_obj_datum),
                                       support_surfaces=e.support_surfaces, guide=guide))
        recognise = not (args.model or args.clamp or args.support)
    return cands, recognise


def run(args: argparse.Namespace) -> int:
    import cv2

    from app.vision.blas_threads import available_cores
    from app.vision.intrinsics import load_intrinsics
    from app.vision.localize import localize

    try:
        image = cv2.imread(args.image, cv2.IMREAD_COLOR)
        if image is None:
            raise ValueError(f"{args.image}: not a readable image")
        cam = load_intrinsics(args.intrinsics)
        layout = json.loads(Path(args.layout).read_text())
        candidates, recognise = _load_candidates(args)
        table = None
        if args.table:
            from app.geometry.mesh import load_mesh
            from app.vision.localize import Candidate

            table = Candidate(name=Path(args.table).stem, kind="table",
                              mesh=load_mesh(Path(args.table).read_bytes(), args.table, "mm"))
    except (OSError, ValueError) as exc:
        print(f"setupcam localize: {exc}", file=sys.stderr)
        return 2
    try:
        # named models: the support chain (fixtures first, the part on their surfaces or over risers);
        # one image at a time: its plane search may use every core
        result = localize(image, cam.K_array, cam.dist_array, layout, candidates, recognise=recognise,
                          table_model=table, chain=not recognise, riser_heights_mm=tuple(args.riser),
                          intrinsics_sigma=cam.sigma_tuple, search_threads=available_cores())
    except Exception as exc:  # noqa: BLE001 - an engine bug must still end with a sentence, not a traceback
        print(f"setupcam localize: internal error in localisation ({exc.__class__.__name__}: {exc}); "
              "please report it with the image", file=sys.stderr)
        return 3
    if args.overlay:
        cv2.imwrite(args.overlay, result.overlay)
    if args.json:
        print(json.dumps(result.to_dict(), indent=1))
    else:
        print(result.reason or "located")
        for o in result.objects:
            T = o["T_table_obj"]
            print(f"  {o['name']}: x {T[0][3]:.3f} mm, y {T[1][3]:.3f} mm, z {T[2][3]:.3f} mm, score {o['score']:.2f}"
                  + (f"; rests on {' on '.join(o['chain'])}" if o.get("chain") else ""))
    return 0 if result.ok else 1
