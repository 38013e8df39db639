"""Printable sheets of a fiducial layout's markers at true scale (SVG in mm, PDF via reportlab).

Markers are laid out in a grid on the page (NOT at their table positions); each tile holds the
black square at exactly ``size_mm`` (its border included, DESIGN format), a one-cell white quiet
zone bounded by a dashed grey cut line, and under it the marker id, size, dictionary and where it
goes on the table (x, y of its centre and its rotation about table z). Every page carries a
100 mm scale bar so the print can be checked with a ruler ("print at 100 %, no fit-to-page").
Page: the smallest of A4 / A3 portrait that holds all markers on one page; larger layouts get
several A3 pages (``sheet_pages``); or a fixed page size (``page_size="A4"``) over several pages.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from xml.sax.saxutils import escape

import cv2
import numpy as np

from app.geometry.fiducial_layout import FiducialLayout, parse_layout

PAGE_SIZES_MM = {"A4": (210.0, 297.0), "A3": (297.0, 420.0)}
MARGIN_MM = 12.0
HEADER_MM = 16.0
FOOTER_MM = 22.0
GAP_MM = 6.0
LABEL_MM = 11.0


@dataclass(frozen=True)
class SheetTile:
    """One marker on the sheet: page index, top-left of the black square on the page (mm, y down)."""

    marker_id: int
    size_mm: float
    page: int
    x_mm: float
    y_mm: float
    cells: np.ndarray  # (n+2, n+2) bool, True = white, row 0 = top edge (corner 0 -> corner 1)
    caption: tuple[str, str]  # ("id 7 - 40 mm", "table x 40 y 26.5")


@dataclass(frozen=True)
class SheetPlan:
    page_name: str
    page_w_mm: float
    page_h_mm: float
    n_pages: int
    tiles: tuple[SheetTile, ...]
    title: str


def _as_layout(layout: FiducialLayout | dict) -> FiducialLayout:
    return layout if isinstance(layout, FiducialLayout) else parse_layout(layout)


def marker_cells(dictionary: str, marker_id: int) -> np.ndarray:
    """Bit cells of one marker including its one-cell black border, True = white."""
    dic = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    n = dic.markerSize + 2
    img = cv2.aruco.generateImageMarker(dic, int(marker_id), n, borderBits=1)
    return img > 127


def plan_sheet(layout: FiducialLayout | dict, title: str = "setupcam fiducial markers",
               page_size: str = "auto") -> SheetPlan:
    """Place the layout's markers on pages (grid, ordered by id). ``page_size``: "A4", "A3" or
    "auto" (the smallest of A4 / A3 that holds all markers on one page, else A3 pages)."""
    if page_size not in ("auto", *PAGE_SIZES_MM):
        raise ValueError(f"unknown page size {page_size!r}; use 'auto', 'A4' or 'A3'")
    lay = _as_layout(layout)
    markers = sorted(lay.markers, key=lambda m: m.id)
    n_cells = marker_cells(lay.dictionary, markers[0].id).shape[0]
    s_max = max(m.size_mm for m in markers)
    quiet = s_max / n_cells
    tile_w = s_max + 2 * quiet + GAP_MM
    tile_h = s_max + 2 * quiet + LABEL_MM + GAP_MM

    def capacity(w: float, h: float) -> tuple[int, int]:
        cols = int((w - 2 * MARGIN_MM + GAP_MM) // tile_w)
        rows = int((h - 2 * MARGIN_MM - HEADER_MM - FOOTER_MM + GAP_MM) // tile_h)
        return max(cols, 0), max(rows, 0)

    for name in (("A4", "A3") if page_size == "auto" else (page_size,)):
        cols, rows = capacity(*PAGE_SIZES_MM[name])
        if cols * rows >= len(markers):
            break
    if cols * rows == 0:
        raise ValueError(f"markers of {s_max:g} mm do not fit on an {name} page; use a larger page, "
                         "split the layout or use smaller markers")
    page_w, page_h = PAGE_SIZES_MM[name]
    per_page = cols * rows
    x_off = (page_w - cols * tile_w + GAP_MM) / 2  # centre the grid horizontally
    tiles = []
    for k, m in enumerate(markers):
        page, slot = divmod(k, per_page)
        r, c = divmod(slot, cols)
        T = np.asarray(m.T_table_marker, dtype=float)
        rot_deg = math.degrees(math.atan2(T[1, 0], T[0, 0]))
        x0 = x_off + c * tile_w + quiet + (s_max - m.size_mm) / 2
        y0 = MARGIN_MM + HEADER_MM + r * tile_h + quiet + (s_max - m.size_mm) / 2
        where = (f"table x {T[0, 3]:g} y {T[1, 3]:g}" + (f" z {T[2, 3]:g}" if abs(T[2, 3]) > 1e-6 else "")
                 + (f" rot {rot_deg:.0f}" if abs(rot_deg) > 1e-6 else ""))
        caption = (f"id {m.id} - {m.size_mm:g} mm", where)
        tiles.append(SheetTile(marker_id=m.id, size_mm=m.size_mm, page=page, x_mm=x0, y_mm=y0,
                               cells=marker_cells(lay.dictionary, m.id), caption=caption))
    n_pages = (len(markers) + per_page - 1) // per_page
    return SheetPlan(page_name=name, page_w_mm=page_w, page_h_mm=page_h, n_pages=n_pages,
                     tiles=tuple(tiles), title=f"{title} - {lay.dictionary}")


def _white_runs(cells: np.ndarray) -> list[tuple[int, int, int]]:
    """Horizontal runs of white cells: (row, col_start, length)."""
    runs = []
    for r, row in enumerate(cells):
        c = 0
        while c < len(row):
            if row[c]:
                c0 = c
                while c < len(row) and row[c]:
                    c += 1
                runs.append((r, c0, c - c0))
            else:
                c += 1
    return runs


def sheet_pages(layout: FiducialLayout | dict, page_size: str = "auto") -> int:
    """Number of pages the layout needs."""
    return plan_sheet(layout, page_size=page_size).n_pages


def marker_sheet_svg(layout: FiducialLayout | dict, page: int = 0, title: str = "setupcam fiducial markers",
                     page_size: str = "auto") -> str:
    """One page of the marker sheet as an SVG document whose user unit is the millimetre
    (``width="297mm" viewBox="0 0 297 420"``). Each marker is a ``<g id="marker-<id>"
    data-size-mm="...">`` holding a black square of exactly ``size_mm`` and white cell rectangles."""
    plan = plan_sheet(layout, title, page_size)
    if not 0 <= page < plan.n_pages:
        raise ValueError(f"page {page} does not exist; the sheet has {plan.n_pages} page(s)")
    W, H = plan.page_w_mm, plan.page_h_mm
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" version="1.1" width="{W:g}mm" height="{H:g}mm" '
        f'viewBox="0 0 {W:g} {H:g}" shape-rendering="crispEdges">',
        f'<rect x="0" y="0" width="{W:g}" height="{H:g}" fill="#ffffff"/>',
        f'<text x="{MARGIN_MM:g}" y="{MARGIN_MM + 5:g}" font-family="Helvetica, Arial, sans-serif" '
        f'font-size="5">{escape(plan.title)} - page {page + 1}/{plan.n_pages} ({plan.page_name})</text>',
        f'<text x="{MARGIN_MM:g}" y="{MARGIN_MM + 11:g}" font-family="Helvetica, Arial, sans-serif" '
        'font-size="3.5">Print at 100 % (actual size, no fit-to-page); check the 100 mm bar with a ruler. '
        'Cut along the dashed line, keep the white border.</text>',
    ]
    for t in plan.tiles:
        if t.page != page:
            continue
        n = t.cells.shape[0]
        cell = t.size_mm / n
        out.append(f'<g id="marker-{t.marker_id}" data-size-mm="{t.size_mm:g}" '
                   f'transform="translate({t.x_mm:.4f} {t.y_mm:.4f})">')
        out.append(f'<rect x="{-cell:.4f}" y="{-cell:.4f}" width="{t.size_mm + 2 * cell:.4f}" '
                   f'height="{t.size_mm + 2 * cell:.4f}" fill="none" stroke="#999999" stroke-width="0.2" '
                   'stroke-dasharray="1.5 1.5" class="cut"/>')
        out.append(f'<rect x="0" y="0" width="{t.size_mm:g}" height="{t.size_mm:g}" fill="#000000" class="black"/>')
        for r, c0, length in _white_runs(t.cells):
            out.append(f'<rect x="{c0 * cell:.4f}" y="{r * cell:.4f}" width="{length * cell:.4f}" '
                       f'height="{cell:.4f}" fill="#ffffff" class="white"/>')
        for k, line in enumerate(t.caption):
            out.append(f'<text x="{t.size_mm / 2:.4f}" y="{t.size_mm + cell + 4 + 3.6 * k:.4f}" '
                       f'text-anchor="middle" font-family="Helvetica, Arial, sans-serif" '
                       f'font-size="{3.2 if k == 0 else 2.6}">{escape(line)}</text>')
        out.append("</g>")
    out.extend(_svg_scale_bar(W, H))
    out.append("</svg>")
    return "\n".join(out) + "\n"


def _svg_scale_bar(W: float, H: float) -> list[str]:
    x0, y0 = MARGIN_MM, H - MARGIN_MM - 8
    parts = [f'<g id="scale-bar"><rect x="{x0:g}" y="{y0:g}" width="100" height="2" fill="#000000"/>']
    for k in range(11):
        h = 5 if k % 5 == 0 else 3.5
        parts.append(f'<rect x="{x0 + 10 * k - 0.15:.2f}" y="{y0 - h + 2:g}" width="0.3" height="{h:g}" fill="#000000"/>')
    parts.append(f'<text x="{x0 + 104:g}" y="{y0 + 2:g}" font-family="Helvetica, Arial, sans-serif" '
                 'font-size="4">100 mm</text></g>')
    return parts


def pdf_scale_bar(pdf, x0_mm: float, y0_mm: float, page_h_mm: float) -> None:
    """A 100 mm bar with 10 mm ticks on a reportlab canvas; (x0, y0) its left end, page mm with y down."""
    from reportlab.lib.units import mm

    def Y(y_mm: float) -> float:
        return (page_h_mm - y_mm) * mm

    pdf.setFillGray(0.0)
    pdf.rect(x0_mm * mm, Y(y0_mm + 2), 100 * mm, 2 * mm, stroke=0, fill=1)
    for k in range(11):
        h = 5 if k % 5 == 0 else 3.5
        pdf.rect((x0_mm + 10 * k - 0.15) * mm, Y(y0_mm + 2), 0.3 * mm, h * mm, stroke=0, fill=1)
    pdf.setFont("Helvetica", 11)
    pdf.drawString((x0_mm + 104) * mm, Y(y0_mm + 2), "100 mm")


def marker_sheet_pdf(layout: FiducialLayout | dict, title: str = "setupcam fiducial markers",
                     page_size: str = "auto") -> bytes:
    """All pages of the marker sheet as a PDF at true scale (reportlab; 1 mm = 72/25.4 pt)."""
    from reportlab.lib.units import mm
    from reportlab.pdfgen import canvas

    plan = plan_sheet(layout, title, page_size)
    W, H = plan.page_w_mm, plan.page_h_mm
    buf = io.BytesIO()
    pdf = canvas.Canvas(buf, pagesize=(W * mm, H * mm), invariant=1, pageCompression=0)
    pdf.setTitle(plan.title)
    pdf.setCreator("setupcam")

    def Y(y_mm: float) -> float:  # page y (down, mm) -> PDF y (up, pt)
        return (H - y_mm) * mm

    for page in range(plan.n_pages):
        pdf.setFont("Helvetica", 14)
        pdf.drawString(MARGIN_MM * mm, Y(MARGIN_MM + 5), f"{plan.title} - page {page + 1}/{plan.n_pages} ({plan.page_name})")
        pdf.setFont("Helvetica", 10)
        pdf.drawString(MARGIN_MM * mm, Y(MARGIN_MM + 11), "Print at 100 % (actual size, no fit-to-page); check the "
                       "100 mm bar with a ruler. Cut along the dashed line, keep the white border.")
        for t in plan.tiles:
            if t.page != page:
                continue
            n = t.cells.shape[0]
            cell = t.size_mm / n
            pdf.setStrokeGray(0.6)
            pdf.setLineWidth(0.2 * mm)
            pdf.setDash(1.5 * mm, 1.5 * mm)
            pdf.rect((t.x_mm - cell) * mm, Y(t.y_mm + t.size_mm + cell), (t.size_mm + 2 * cell) * mm,
                     (t.size_mm + 2 * cell) * mm, stroke=1, fill=0)
            pdf.setDash()
            pdf.setFillGray(0.0)
            pdf.rect(t.x_mm * mm, Y(t.y_mm + t.size_mm), t.size_mm * mm, t.size_mm * mm, stroke=0, fill=1)
            pdf.setFillGray(1.0)
            for r, c0, length in _white_runs(t.cells):
                pdf.rect((t.x_mm + c0 * cell) * mm, Y(t.y_mm + (r + 1) * cell), length * cell * mm, cell * mm,
                         stroke=0, fill=1)
            pdf.setFillGray(0.0)
            for k, line in enumerate(t.caption):
                pdf.setFont("Helvetica", 9 if k == 0 else 7.4)
                pdf.drawCentredString((t.x_mm + t.size_mm / 2) * mm, Y(t.y_mm + t.size_mm + cell + 4 + 3.6 * k), line)
        pdf_scale_bar(pdf, MARGIN_MM, H - MARGIN_MM - 8, H)
        pdf.showPage()
    pdf.save()
    return buf.getvalue()
