"""The "upload" source: the camera has no way to be asked for an image; images arrive as uploads."""

from __future__ import annotations

import numpy as np

from app.sources.base import ImageSource, SourceError


class UploadSource(ImageSource):
    kind = "upload"

    def __init__(self, camera_name: str | None = None) -> None:
        self.camera_name = camera_name

    def describe(self) -> str:
        return "upload only"

    def grab(self) -> np.ndarray:
        who = f"camera {self.camera_name}" if self.camera_name else "this camera"
        raise SourceError(
            f"{who} only accepts uploaded images (source kind 'upload'); upload an image, or configure an "
            "http, folder or opencv source to take snapshots"
        )
