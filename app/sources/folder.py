"""The "folder" source: the newest image file in a folder another program writes into."""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from app.sources.base import ImageSource, SourceError, decode_bytes

IMAGE_SUFFIXES = frozenset({".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp"})


class FolderSource(ImageSource):
    """Newest matching file by modification time (ties broken by name).

    pattern : glob relative to the folder, or None for any file with an image suffix.
    only_new : when True a grab refuses a file that is not newer than the last one delivered
        (a poller then knows there is nothing new). Hidden files (leading ".") are ignored, as many
        copy tools write to a hidden temporary name and rename when done.
    ``last_path`` holds the file the last successful grab delivered.
    """

    kind = "folder"

    def __init__(self, path: str | Path, pattern: str | None = None, only_new: bool = False) -> None:
        self.path = Path(path)
        self.pattern = pattern
        self.only_new = only_new
        self.last_path: Path | None = None
        self._last_key: tuple[int, str] | None = None

    def describe(self) -> str:
        return f"folder {self.path}"

    def _candidates(self) -> list[Path]:
        if self.pattern:
            files = self.path.glob(self.pattern)
        else:
            files = (p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        return [p for p in files if not p.name.startswith(".") and p.is_file()]

    def grab(self) -> np.ndarray:
        if not self.path.is_dir():
            raise SourceError(f"{self.describe()} does not exist or is not a folder")
        try:
            files = self._candidates()
            keyed = [((p.stat().st_mtime_ns, p.name), p) for p in files]
        except OSError as exc:
            raise SourceError(f"{self.describe()} cannot be read ({exc.strerror or exc})") from None
        what = f"matching {self.pattern!r}" if self.pattern else "with an image suffix"
        if not keyed:
            raise SourceError(f"{self.describe()} has no images yet (no file {what})")
        key, newest = max(keyed)
        if self.only_new and self._last_key is not None and key <= self._last_key:
            when = datetime.fromtimestamp(self._last_key[0] / 1e9, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")
            raise SourceError(
                f"{self.describe()} has no new image since the last grab ({self._last_key[1]}, {when})"
            )
        try:
            data = newest.read_bytes()
        except OSError as exc:
            raise SourceError(f"{self.describe()}: newest file {newest.name} cannot be read ({exc.strerror or exc})") from None
        image = decode_bytes(data)
        if image is None:
            raise SourceError(
                f"{self.describe()}: newest file {newest.name} is not a readable image ({len(data)} bytes; "
                "still being written, or not an image)"
            )
        self._last_key, self.last_path = key, newest
        return image
