"""Printable targets the pages offer for download, at true scale: calibration boards (ChArUco or
chessboard, PDF) and the rotary check's circular target (PDF or SVG). The drawing is in
app/vision/printables/; this module checks the request and
answers bytes with their media type."""

from __future__ import annotations

from pydantic import ValidationError

from app.services.errors import Invalid, NotFound
from app.vision.printables import board_sheet_pdf
from app.vision.calibration import BoardSpec
from app.vision.printables import target_pdf, target_svg
from app.vision.rotary_target import default_target


def calibration_board_pdf(board) -> tuple[bytes, str]:
    """(PDF bytes, file name) of the calibration board described by ``board`` (as for a calibration
    run); Invalid naming the field when the description is wrong or the board is larger than A3."""
    try:
        spec = BoardSpec.model_validate(board)
        pdf = board_sheet_pdf(spec)
    except ValidationError as exc:
        e = exc.errors()[0]
        where = ".".join(["board", *map(str, e["loc"])])
        raise Invalid(f"{where}: {e['msg'].removeprefix('Value error, ')}") from None
    except ValueError as exc:
        raise Invalid(f"board: {exc}") from None
    return pdf, f"setupcam-{spec.kind}-board.pdf"


ROTARY_TARGET_FORMATS = {"pdf": ("application/pdf", target_pdf), "svg": ("image/svg+xml", target_svg)}


def rotary_target(fmt: str) -> tuple[bytes, str]:
    """(bytes, media type) of the default rotary target as PDF or SVG; NotFound for another format."""
    if fmt not in ROTARY_TARGET_FORMATS:
        raise NotFound("target format must be pdf or svg")
    media, draw = ROTARY_TARGET_FORMATS[fmt]
    data = draw(default_target())
    return (data.encode() if isinstance(data, str) else data), media
