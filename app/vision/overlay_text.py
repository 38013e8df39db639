"""Text and strokes on the operator's pictures, sized to the picture so they stay legible at full HD.

The pages show an overlay scaled to the screen: a fixed 0.5 Hershey font is 11 px tall, readable on a
640 px picture but a smudge on a 1920 x 1200 one shown at half size. Sizes here grow with the image's
width (1 at 1000 px): at 1920 px a capital is about 24 px tall, drawn with a dark outline so it reads
on bright metal and on dark slots alike.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

FONT = cv2.FONT_HERSHEY_SIMPLEX
#: font scale per 1000 px of image width (Hershey simplex: a capital is ~22 px tall at scale 1)
FONT_PER_1000_PX = 0.55
MIN_FONT = 0.5


@dataclass(frozen=True)
class OverlayStyle:
    """Sizes for one picture: font scale, stroke thickness (px) and dot radius (px)."""

    font: float
    thickness: int
    dot_px: int

    @property
    def line_px(self) -> int:
        """Height of one line of text with its gap, px."""
        return int(round(30 * self.font / 0.55))


def style_for(image: np.ndarray) -> OverlayStyle:
    """The sizes that suit ``image`` (H x W [x 3])."""
    width = image.shape[1]
    font = max(MIN_FONT, FONT_PER_1000_PX * width / 1000.0)
    return OverlayStyle(font=font, thickness=max(1, int(round(font * 2))), dot_px=max(1, int(round(width / 1000))))


def put_label(image: np.ndarray, text: str, org: tuple[int, int], colour, style: OverlayStyle | None = None) -> None:
    """Draw ``text`` (baseline-left at ``org``, px) in ``colour`` with a dark outline, in place."""
    s = style or style_for(image)
    org = (int(org[0]), int(org[1]))
    cv2.putText(image, text, org, FONT, s.font, (0, 0, 0), s.thickness + 2 * max(1, s.thickness // 2), cv2.LINE_AA)
    cv2.putText(image, text, org, FONT, s.font, colour, s.thickness, cv2.LINE_AA)


def put_banner(image: np.ndarray, text: str, colour, line: int = 0) -> None:
    """A sentence at the top left (line 0, 1, ...), cut to what fits the width."""
    s = style_for(image)
    width_px = cv2.getTextSize("M", FONT, s.font, s.thickness)[0][0]
    fits = max(20, int(image.shape[1] * 0.95 / max(width_px, 1)))
    put_label(image, text[:fits], (10, s.line_px * (line + 1)), colour, s)
