"""Build the example model library reproducibly: meshes (binary STL, mm), the table's fiducial
layout, the printable marker sheets (SVG and PDF on one A3 page, PDF on A4 pages) and library.json.

    .venv/bin/python models_library/build_library.py [--out models_library]

All geometry comes from app/geometry/parts.py (``example_library()``), so the scene generator and
tests can build the same models in memory. Running it twice gives byte-identical files.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from app.vision.printables.markers import marker_sheet_pdf, marker_sheet_svg, sheet_pages  # noqa: E402
from app.geometry.parts import ExampleModel, example_library  # noqa: E402

HERE = Path(__file__).resolve().parent
SHEET_TITLE = "setupcam T-slot table 800 x 400 markers"


def stl_bytes(mesh) -> bytes:
    """Binary STL with a fixed header (reproducible bytes)."""
    data = bytearray(mesh.export(file_type="stl"))
    data[:80] = b"setupcam example library, units mm".ljust(80, b" ")
    return bytes(data)


def manifest_entry(m: ExampleModel) -> dict:
    entry = {"key": m.key, "kind": m.kind, "name": m.name, "file": f"{m.key}.stl", "units": "mm",
             "fiducials": f"{m.key}.fiducials.json" if m.layout else None,
             "T_obj_datum": None if m.T_obj_datum is None else np.round(m.T_obj_datum, 6).tolist(),
             "description": m.description}
    if m.support_surfaces is not None:   # optional field: only fixtures that declare them
        entry["support_surfaces"] = m.support_surfaces
    return entry


def build(out: Path) -> list[dict]:
    out.mkdir(parents=True, exist_ok=True)
    manifest = []
    for m in example_library():
        entry = manifest_entry(m)
        (out / entry["file"]).write_bytes(stl_bytes(m.mesh))
        if m.layout:
            (out / entry["fiducials"]).write_text(json.dumps(m.layout, indent=1) + "\n")
            if sheet_pages(m.layout) != 1:
                raise SystemExit(f"{m.key}: the marker sheet no longer fits one page; write one SVG per page")
            (out / f"{m.key}.markers.svg").write_text(marker_sheet_svg(m.layout, title=SHEET_TITLE))
            (out / f"{m.key}.markers.pdf").write_bytes(marker_sheet_pdf(m.layout, title=SHEET_TITLE))
            # the same markers on A4 pages for printers without A3
            (out / f"{m.key}.markers_a4.pdf").write_bytes(marker_sheet_pdf(m.layout, title=SHEET_TITLE,
                                                                          page_size="A4"))
        manifest.append(entry)
    (out / "library.json").write_text(json.dumps({"models": manifest}, indent=1) + "\n")
    return manifest


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=HERE, help="output folder (default: models_library/)")
    args = ap.parse_args(argv)
    for m in build(args.out):
        print(f"{m['key']:22s} {m['kind']:9s} {m['file']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
