"""Image sources: where a camera's images come from.

Each source has one method, ``grab() -> ndarray (H, W, 3) BGR uint8``, and raises ``SourceError``
with a sentence naming the source and the reason. Kinds: ``upload`` (no grabbing: images are
uploaded), ``http`` (snapshot URL), ``folder`` (newest file in a watched folder), ``opencv`` (device
index or stream/file URL via cv2.VideoCapture).

Example (what ``POST /api/v1/cameras/{id}/snapshot`` does)::

    from app.sources import SourceError, make_source

    source = make_source({"kind": "http", "url": "http://192.0.2.10/snapshot.jpg"})  # ValueError -> 422
    try:
        image = source.grab()
    except SourceError as exc:      # e.g. "HTTP snapshot http://192.0.2.10/snapshot.jpg: connection refused; ..."
        raise HTTPException(502, str(exc))
"""

from app.sources.base import ImageSource, SourceError
from app.sources.config import (
    FolderSourceConfig,
    HttpSourceConfig,
    OpenCVSourceConfig,
    SourceConfig,
    UploadSourceConfig,
    parse_source_config,
)
from app.sources.factory import make_source
from app.sources.folder import FolderSource
from app.sources.http_snapshot import HttpSnapshotSource
from app.sources.opencv_capture import OpenCVSource
from app.sources.upload import UploadSource

__all__ = [
    "FolderSource",
    "FolderSourceConfig",
    "HttpSnapshotSource",
    "HttpSourceConfig",
    "ImageSource",
    "OpenCVSource",
    "OpenCVSourceConfig",
    "SourceConfig",
    "SourceError",
    "UploadSource",
    "UploadSourceConfig",
    "make_source",
    "parse_source_config",
]
