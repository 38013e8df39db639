"""``setupcam markers``: print a fiducial layout's markers at true scale (PDF or SVG).

    setupcam markers LAYOUT.json --out SHEET.pdf [--page-size auto|A4|A3] [--title TEXT]
    setupcam markers LAYOUT.json --out SHEET.svg [--page N]

``LAYOUT.json`` is a fiducial layout in the DESIGN format. The markers are laid out in a grid (not
at their table positions); each carries its id and where it goes on the table, every page a 100 mm
scale bar. An SVG holds one page (``--page``, from 0). Exit code 0: written; 2: bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("markers", help="printable sheet (PDF/SVG, true scale) of a fiducial layout's markers",
                       description="Writes the markers of a fiducial layout at true scale with ids, table "
                                   "positions and a 100 mm scale bar.")
    p.add_argument("layout", help="fiducial layout JSON (DESIGN format)")
    p.add_argument("--out", required=True, help="output file, .pdf (all pages) or .svg (one page)")
    p.add_argument("--page-size", default="auto", choices=["auto", "A4", "A3"],
                   help="auto: the smallest of A4/A3 holding all markers on one page, else A3 pages")
    p.add_argument("--page", type=int, default=0, help="page to write for SVG output (from 0)")
    p.add_argument("--title", default="setupcam fiducial markers", help="title printed on each page")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from app.geometry.fiducial_layout import parse_layout
    from app.vision.printables.markers import marker_sheet_pdf, marker_sheet_svg, sheet_pages

    out = Path(args.out)
    try:
        layout = parse_layout(json.loads(Path(args.layout).read_text()))
        suffix = out.suffix.lower()
        if suffix == ".pdf":
            out.write_bytes(marker_sheet_pdf(layout, title=args.title, page_size=args.page_size))
        elif suffix == ".svg":
            out.write_text(marker_sheet_svg(layout, page=args.page, title=args.title, page_size=args.page_size))
        else:
            raise ValueError(f"output {out.name!r}: use a .pdf or .svg file name")
        pages = sheet_pages(layout, page_size=args.page_size)
    except (OSError, ValueError) as exc:  # json.JSONDecodeError is a ValueError
        print(f"setupcam markers: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out} ({len(layout.markers)} markers, {layout.dictionary}, {pages} page(s); "
          "print at 100 % and check the 100 mm bar)")
    return 0
