"""Everything setupcam prints, at true scale, in one place: fiducial marker sheets for a table's
layout (:mod:`.markers`), camera calibration boards (:mod:`.boards`) and rotary-axis targets
(:mod:`.rotary_target`). Each page carries a 100 mm check bar; print at 100 %."""

from app.vision.printables.boards import board_sheet_pdf
from app.vision.printables.markers import marker_sheet_pdf, marker_sheet_svg, sheet_pages
from app.vision.printables.rotary_target import target_pdf, target_svg

__all__ = ["board_sheet_pdf", "marker_sheet_pdf", "marker_sheet_svg", "sheet_pages", "target_pdf", "target_svg"]
