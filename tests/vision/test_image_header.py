"""Image sizes read from headers only (app/vision/image_header.py), for every format an upload may be."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from app.vision.image_header import ImageHeaderError, check_image_size, image_size
from tests.api.test_bounded_input import png_bomb


@pytest.mark.parametrize("ext", [".png", ".jpg", ".tif", ".bmp", ".webp", ".ppm"])
def test_size_from_the_header_of_each_format(ext):
    data = cv2.imencode(ext, np.zeros((37, 53, 3), np.uint8))[1].tobytes()
    assert image_size(data) == (53, 37)
    assert check_image_size(data, 53 * 37) == (53, 37)
    with pytest.raises(ImageHeaderError) as err:
        check_image_size(data, 53 * 37 - 1)
    assert err.value.too_large and "53 x 37 px" in str(err.value)


def test_bomb_is_measured_not_decoded():
    with pytest.raises(ImageHeaderError) as err:
        check_image_size(png_bomb(), 50_000_000)
    assert err.value.too_large and str(err.value) == "is 900 MP; the limit is 50 MP"
    assert image_size(png_bomb(12000, 9000)) == (12000, 9000)   # under Pillow's own guard: read exactly


@pytest.mark.parametrize("data", [b"", b"GIF89a" + b"\0" * 50, b"\x89PNG\r\n\x1a\n", b"%PDF-1.4"])
def test_no_readable_header(data):
    with pytest.raises(ImageHeaderError) as err:
        image_size(data)
    assert not err.value.too_large


def test_camera_frames_are_measured_before_decoding():
    from app.sources.base import decode_bytes

    assert decode_bytes(png_bomb()) is None
    assert decode_bytes(cv2.imencode(".png", np.zeros((4, 6, 3), np.uint8))[1].tobytes()).shape == (4, 6, 3)
