import re
import xml.etree.ElementTree as ET
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.geometry import parts
from app.vision.printables.markers import marker_cells, marker_sheet_pdf, marker_sheet_svg, plan_sheet, sheet_pages

SVG = "{http://www.w3.org/2000/svg}"
LIBRARY = Path(__file__).resolve().parents[2] / "models_library"


def layout_of(n, size=40.0):
    return {"dictionary": "DICT_5X5_100",
            "markers": [{"id": i, "size_mm": size, "T_table_marker": np.eye(4).tolist()} for i in range(n)]}


def rasterise_marker(group: ET.Element, px_per_mm: float = 10.0) -> tuple[np.ndarray, float]:
    """Paint the black square and white cells of one marker group, plus a white quiet zone."""
    black = group.find(f"{SVG}rect[@class='black']")
    size = float(black.get("width"))
    assert float(black.get("height")) == size
    pad = int(round(size / 7 * px_per_mm))
    n = int(round(size * px_per_mm))
    img = np.full((n + 2 * pad, n + 2 * pad), 255, np.uint8)
    img[pad:pad + n, pad:pad + n] = 0
    for r in group.findall(f"{SVG}rect[@class='white']"):
        x, y = float(r.get("x")) * px_per_mm, float(r.get("y")) * px_per_mm
        w, h = float(r.get("width")) * px_per_mm, float(r.get("height")) * px_per_mm
        img[pad + int(round(y)):pad + int(round(y + h)), pad + int(round(x)):pad + int(round(x + w))] = 255
    return img, size


def test_svg_is_in_millimetres_and_markers_have_their_true_size_and_ids():
    layout = parts.tslot_table_layout(parts.TSlotTableSpec())
    svg = marker_sheet_svg(layout)
    root = ET.fromstring(svg)
    assert root.get("width") == "297mm" and root.get("height") == "420mm"  # A3: 12 markers do not fit A4
    assert root.get("viewBox") == "0 0 297 420"  # user unit = 1 mm
    groups = [g for g in root.iter(f"{SVG}g") if (g.get("id") or "").startswith("marker-")]
    assert len(groups) == len(layout["markers"])
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100))
    for g in groups:
        img, size = rasterise_marker(g)
        assert size == pytest.approx(40.0)
        corners, ids, _ = detector.detectMarkers(img)
        assert ids is not None and ids.ravel().tolist() == [int(g.get("id").split("-")[1])]
        side = np.linalg.norm(corners[0][0][1] - corners[0][0][0]) / 10.0
        assert side == pytest.approx(40.0, abs=0.3)
        # corner 0 is top-left and corner 1 top-right: the drawing is not mirrored or turned
        assert corners[0][0][0][0] < corners[0][0][1][0] and corners[0][0][0][1] < corners[0][0][3][1]
    # the scale bar is 100 mm long
    bar = root.find(f".//{SVG}g[@id='scale-bar']/{SVG}rect")
    assert float(bar.get("width")) == 100.0


def test_marker_tiles_stay_on_the_page_and_do_not_overlap():
    plan = plan_sheet(parts.tslot_table_layout(parts.TSlotTableSpec()))
    boxes = []
    for t in plan.tiles:
        q = t.size_mm / t.cells.shape[0]
        x0, y0, x1, y1 = t.x_mm - q, t.y_mm - q, t.x_mm + t.size_mm + q, t.y_mm + t.size_mm + q + 8
        assert x0 >= 5 and y0 >= 5 and x1 <= plan.page_w_mm - 5 and y1 <= plan.page_h_mm - 25
        boxes.append((x0, y0, x1, y1))
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            assert a[2] <= b[0] or b[2] <= a[0] or a[3] <= b[1] or b[3] <= a[1]


def test_page_choice_and_pages():
    assert plan_sheet(layout_of(4)).page_name == "A4"
    assert plan_sheet(layout_of(12)).page_name == "A3"
    assert sheet_pages(layout_of(60)) > 1
    with pytest.raises(ValueError, match="page 5 does not exist"):
        marker_sheet_svg(layout_of(4), page=5)
    with pytest.raises(ValueError, match="do not fit on an A3 page"):
        plan_sheet(layout_of(1, size=400.0))
    a4 = plan_sheet(layout_of(12), page_size="A4")
    assert a4.page_name == "A4" and a4.n_pages == 2
    assert sorted(t.marker_id for t in a4.tiles) == list(range(12))
    with pytest.raises(ValueError, match="unknown page size 'letter'"):
        plan_sheet(layout_of(2), page_size="letter")


def test_pdf_is_valid_with_true_page_size():
    pdf = marker_sheet_pdf(layout_of(60))
    assert pdf.startswith(b"%PDF-") and pdf.rstrip().endswith(b"%%EOF")
    n = sheet_pages(layout_of(60))
    assert len(re.findall(rb"/Type /Page\b", pdf)) == n
    box = re.search(rb"/MediaBox \[\s*0 0 ([\d.]+) ([\d.]+)\s*\]", pdf)
    w_mm, h_mm = (float(v) * 25.4 / 72 for v in box.groups())
    assert (round(w_mm), round(h_mm)) == (297, 420)


def test_committed_sheets_are_current():
    layout = parts.tslot_table_layout(parts.TSlotTableSpec())
    title = "setupcam T-slot table 800 x 400 markers"
    assert (LIBRARY / "tslot_table_800x400.markers.svg").read_text() == marker_sheet_svg(layout, title=title)
    committed = (LIBRARY / "tslot_table_800x400.markers.pdf").read_bytes()
    fresh = marker_sheet_pdf(layout, title=title)
    # not byte-compared (another reportlab version writes other bytes): same pages, same drawing
    for pdf in (committed, fresh):
        assert pdf.startswith(b"%PDF-") and len(re.findall(rb"/Type /Page\b", pdf)) == 1
    n_rect = committed.count(b" re ")  # rectangle operators: cells, scale bar, cut lines
    assert n_rect == fresh.count(b" re ") and n_rect > 12 * 10
    assert rb"page 1/1 \(A3\)" in committed
    a4 = (LIBRARY / "tslot_table_800x400.markers_a4.pdf").read_bytes()
    assert len(re.findall(rb"/Type /Page\b", a4)) == 2 and rb"page 2/2 \(A4\)" in a4


def test_marker_cells_have_a_black_border():
    c = marker_cells("DICT_5X5_100", 7)
    assert c.shape == (7, 7)
    assert not c[0].any() and not c[-1].any() and not c[:, 0].any() and not c[:, -1].any()
