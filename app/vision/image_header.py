"""Read an encoded image's size from its header, before anything decodes it.

A 109 KB PNG can say 30000 x 30000 px: ``cv2.imdecode`` would then allocate 2.7 GB. Every upload is
measured here first (Pillow reads only the header: PNG IHDR, JPEG SOF, TIFF IFD, BMP, WebP) and
refused when its pixel count is over the limit, or when no header can be read at all.
"""

from __future__ import annotations

import io
import re
import warnings

from PIL import Image, UnidentifiedImageError

# what the header reader knows (and what cv2 then decodes); anything else is refused unread
FORMATS = ("PNG", "JPEG", "TIFF", "BMP", "WEBP", "PPM")


class ImageHeaderError(ValueError):
    """The bytes are not an image we can measure, or the image is too large; ``too_large`` tells which."""

    def __init__(self, message: str, too_large: bool = False, pixels: int | None = None):
        super().__init__(message)
        self.too_large = too_large
        self.pixels = pixels


def image_size(data: bytes) -> tuple[int, int]:
    """(width, height) in px from the header of a PNG/JPEG/TIFF/BMP/WebP/PPM file; nothing is decoded.

    Raises :class:`ImageHeaderError` when the header cannot be read, and with ``too_large`` when Pillow's
    own decompression-bomb guard (over 2 x ``Image.MAX_IMAGE_PIXELS``) fires while reading it.
    """
    if not data:
        raise ImageHeaderError("is empty")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data), formats=FORMATS) as im:  # lazy: header only
                return int(im.size[0]), int(im.size[1])
    except Image.DecompressionBombError as exc:
        m = re.search(r"\((\d+) pixels\)", str(exc))
        pixels = int(m.group(1)) if m else None
        raise ImageHeaderError(f"is {pixels / 1e6:.0f} MP" if pixels else "is far too large", too_large=True,
                               pixels=pixels) from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError):
        raise ImageHeaderError("is not a readable image (JPEG, PNG, TIFF, BMP or WebP expected)") from None


def check_image_size(data: bytes, max_pixels: int) -> tuple[int, int]:
    """(width, height) when the image's header is readable and ``width * height <= max_pixels``."""
    try:
        w, h = image_size(data)
    except ImageHeaderError as exc:
        if exc.too_large:
            raise ImageHeaderError(f"{exc}; the limit is {max_pixels / 1e6:.0f} MP", True, exc.pixels) from None
        raise
    if w <= 0 or h <= 0:
        raise ImageHeaderError(f"has no pixels ({w} x {h} px in its header)")
    if w * h > max_pixels:
        raise ImageHeaderError(f"is {w} x {h} px ({w * h / 1e6:.0f} MP); the limit is {max_pixels / 1e6:.0f} MP",
                               too_large=True)
    return w, h
