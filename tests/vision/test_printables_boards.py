"""Printable calibration boards: the project's own detector finds every corner of the drawn board at
the stated square size, and the PDF places the board at its true size in mm on a page that holds it."""

from __future__ import annotations

import re

import cv2
import numpy as np
import pytest

from app.vision.printables.boards import board_image, board_page, board_sheet_pdf, board_size_mm
from app.vision.calibration import BoardSpec, detect_board

PX_PER_MM = 10.0
BOARDS = [BoardSpec(kind="chessboard", inner_corners=(9, 6), square_mm=25.0),
          BoardSpec(kind="charuco", squares=(5, 7), square_mm=40.0, marker_mm=20.0, dictionary="DICT_6X6_250"),
          BoardSpec(kind="charuco", squares=(8, 6), square_mm=15.0, marker_mm=11.0, dictionary="DICT_4X4_50")]


@pytest.mark.parametrize("board", BOARDS, ids=lambda b: b.describe())
def test_detector_finds_every_corner_at_the_stated_size(board):
    img = board_image(board, PX_PER_MM)
    pad = int(2 * board.square_mm * PX_PER_MM)
    det = detect_board(cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255), board)
    assert det.found, det.reason
    assert len(det.uv_px) == board.corner_count
    # image = scale * board (mm) + shift: the scale is the drawing's px per mm, the same along x and y
    A = np.column_stack([det.xyz_mm[:, :2], np.ones(len(det.xyz_mm))])
    coef, *_ = np.linalg.lstsq(A, det.uv_px, rcond=None)
    scale = np.linalg.norm(coef[:2], axis=0)
    assert scale == pytest.approx([PX_PER_MM, PX_PER_MM], rel=2e-3)


@pytest.mark.parametrize("board", BOARDS, ids=lambda b: b.describe())
def test_pdf_places_the_board_at_true_size(board):
    pdf = board_sheet_pdf(board)
    assert pdf.startswith(b"%PDF-") and len(re.findall(rb"/Type /Page\b", pdf)) == 1
    name, W, H = board_page(board)
    box = [float(v) for v in re.search(rb"/MediaBox \[\s*0 0 ([\d.]+) ([\d.]+)\s*\]", pdf).groups()]
    assert box == pytest.approx([W * 72 / 25.4, H * 72 / 25.4], abs=0.01)
    w_mm, h_mm = board_size_mm(board)
    placed = re.search(rb"q\s+([\d.]+) 0 0 ([\d.]+) ([\d.]+) ([\d.]+) cm\s+/\S+ Do", pdf)
    assert placed, "the board image is drawn with its own placement"
    w_pt, h_pt, x_pt, y_pt = map(float, placed.groups())
    assert (w_pt, h_pt) == pytest.approx((w_mm * 72 / 25.4, h_mm * 72 / 25.4), abs=0.01)
    assert 0 < x_pt and x_pt + w_pt < box[0] and 0 < y_pt and y_pt + h_pt < box[1], "inside the page"


def test_a_board_larger_than_a3_is_refused_with_its_size():
    with pytest.raises(ValueError, match="does not fit on A3"):
        board_page(BoardSpec(kind="chessboard", inner_corners=(20, 15), square_mm=30.0))
