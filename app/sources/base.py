"""The image-source interface: one method, ``grab() -> BGR uint8 image``, failures as SourceError."""

from __future__ import annotations

from abc import ABC, abstractmethod

import cv2
import numpy as np


class SourceError(RuntimeError):
    """A source could not deliver an image; the message is one sentence naming the source and why,
    e.g. "HTTP snapshot http://192.0.2.10/snap.jpg: connection refused"."""


class ImageSource(ABC):
    """Something that can be asked for one current image.

    Implementations keep no open handles between grabs (a device or connection is opened and released
    inside ``grab``), so a source object is cheap to make from its config and safe to throw away.
    """

    kind: str = ""

    @abstractmethod
    def grab(self) -> np.ndarray:
        """One image, ndarray shape (H, W, 3), BGR, uint8. Raises SourceError with the reason."""

    @abstractmethod
    def describe(self) -> str:
        """Short human name used in messages, e.g. "folder /srv/cam1"."""

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.describe()}>"


def to_bgr_uint8(image: np.ndarray) -> np.ndarray:
    """Any decoded frame (gray, BGRA, 16-bit) as a contiguous BGR uint8 array, shape (H, W, 3)."""
    if image.dtype != np.uint8:
        image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    if image.ndim == 2:
        image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    elif image.ndim == 3 and image.shape[2] == 1:
        image = cv2.cvtColor(image[:, :, 0], cv2.COLOR_GRAY2BGR)
    elif image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    return np.ascontiguousarray(image)


MAX_FRAME_PIXELS = 100_000_000  # no camera delivers more; a larger header is a broken or hostile source


def decode_bytes(data: bytes) -> np.ndarray | None:
    """Decode JPEG/PNG/... bytes to BGR uint8, or None when OpenCV cannot read them or the header says
    more than ``MAX_FRAME_PIXELS`` (read before decoding: a small file can say 30000 x 30000 px)."""
    from app.vision.image_header import ImageHeaderError, check_image_size

    if not data:
        return None
    try:
        check_image_size(data, MAX_FRAME_PIXELS)
    except ImageHeaderError:
        return None
    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    return None if image is None else to_bgr_uint8(image)
