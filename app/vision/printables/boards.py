"""Printable calibration boards (chessboard, ChArUco) at true scale: the image OpenCV's detectors are
made for, placed on an A4 or A3 page with a 100 mm check bar.

``board_image`` draws the board at ``px_per_mm`` with square edges on whole pixels, so the printed
squares are exactly ``square_mm``; ``board_sheet_pdf`` embeds that image at the board's size in mm
(1 mm = 72 / 25.4 pt). Lengths in mm.
"""

from __future__ import annotations

import io

import numpy as np

from app.vision.calibration import BoardSpec, _charuco_board
from app.vision.printables.markers import PAGE_SIZES_MM, pdf_scale_bar

MARGIN_MM = 12.0
HEADER_MM = 20.0    # title and printing note above the board
FOOTER_MM = 16.0    # the 100 mm check bar below it


def board_squares(board: BoardSpec) -> tuple[int, int]:
    """(columns, rows) of squares."""
    if board.kind == "chessboard":
        c, r = board.inner_corners  # type: ignore[misc]
        return c + 1, r + 1
    return tuple(board.squares)  # type: ignore[return-value]


def board_size_mm(board: BoardSpec) -> tuple[float, float]:
    cols, rows = board_squares(board)
    return cols * board.square_mm, rows * board.square_mm


def board_image(board: BoardSpec, px_per_mm: float = 10.0) -> np.ndarray:
    """The board as a uint8 image (255 white), ``square_mm * px_per_mm`` pixels per square (rounded;
    the PDF places the image at the true size, so rounding only resamples, never scales the board)."""
    cols, rows = board_squares(board)
    sq = max(8, int(round(board.square_mm * px_per_mm)))
    if board.kind == "chessboard":
        cells = (np.add.outer(np.arange(rows), np.arange(cols)) % 2 == 1)      # top-left square black
        return np.where(np.kron(cells, np.ones((sq, sq), bool)), 255, 0).astype(np.uint8)
    return _charuco_board(board).generateImage((cols * sq, rows * sq), marginSize=0, borderBits=1)


def board_page(board: BoardSpec) -> tuple[str, float, float]:
    """(name, width, height) in mm of the smallest A4 / A3 page, upright or turned, that holds the board.
    ValueError when even A3 is too small."""
    w, h = board_size_mm(board)
    for name in ("A4", "A3"):
        pw, ph = PAGE_SIZES_MM[name]
        for W, H in ((pw, ph), (ph, pw)):
            if w + 2 * MARGIN_MM <= W and h + 2 * MARGIN_MM + HEADER_MM + FOOTER_MM <= H:
                return name, W, H
    raise ValueError(f"the board is {w:g} x {h:g} mm and does not fit on A3 with margins; "
                     "choose fewer or smaller squares")


def board_sheet_pdf(board: BoardSpec) -> bytes:
    """One page: title, printing note, the board at true size, a 100 mm bar to check the print."""
    from PIL import Image
    from reportlab.lib.units import mm
    from reportlab.lib.utils import ImageReader
    from reportlab.pdfgen import canvas

    name, W, H = board_page(board)
    w, h = board_size_mm(board)
    img = Image.fromarray(board_image(board)).convert("1")
    buf = io.BytesIO()
    pdf = canvas.Canvas(buf, pagesize=(W * mm, H * mm), invariant=1, pageCompression=0)
    pdf.setTitle(f"setupcam calibration board: {board.describe()}")
    pdf.setCreator("setupcam")
    pdf.setFont("Helvetica", 13)
    pdf.drawString(MARGIN_MM * mm, (H - MARGIN_MM - 5) * mm, f"Calibration board: {board.describe()} ({name})")
    pdf.setFont("Helvetica", 9)
    pdf.drawString(MARGIN_MM * mm, (H - MARGIN_MM - 11) * mm, "Print at 100 % (actual size, no fit-to-page), check "
                   "the 100 mm bar with a ruler, mount the print flat on a rigid plate.")
    x0 = (W - w) / 2
    y_top = MARGIN_MM + HEADER_MM
    pdf.drawImage(ImageReader(img), x0 * mm, (H - y_top - h) * mm, width=w * mm, height=h * mm)
    pdf_scale_bar(pdf, MARGIN_MM, y_top + h + 8, H)
    pdf.showPage()
    pdf.save()
    return buf.getvalue()
