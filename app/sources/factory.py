"""``make_source(config) -> ImageSource`` from a stored/API source config (see app/sources/config.py)."""

from __future__ import annotations

from typing import Any

from app.sources.base import ImageSource
from app.sources.config import (
    FolderSourceConfig,
    HttpSourceConfig,
    OpenCVSourceConfig,
    UploadSourceConfig,
    parse_source_config,
)
from app.sources.folder import FolderSource
from app.sources.http_snapshot import HttpSnapshotSource
from app.sources.opencv_capture import OpenCVSource
from app.sources.upload import UploadSource


def make_source(config: dict[str, Any] | Any) -> ImageSource:
    """Build the source a config describes. No I/O happens here (nothing is opened or fetched).

    Raises ValueError with one sentence when the config is invalid (the API answers 422).
    """
    cfg = parse_source_config(config)
    if isinstance(cfg, UploadSourceConfig):
        return UploadSource()
    if isinstance(cfg, HttpSourceConfig):
        return HttpSnapshotSource(cfg.url, timeout_s=cfg.timeout_s, username=cfg.username, password=cfg.password,
                                  auth=cfg.auth, verify_tls=cfg.verify_tls, max_mb=cfg.max_mb)
    if isinstance(cfg, FolderSourceConfig):
        return FolderSource(cfg.path, pattern=cfg.pattern, only_new=cfg.only_new)
    if isinstance(cfg, OpenCVSourceConfig):
        return OpenCVSource(device=cfg.device, url=cfg.url, warmup_frames=cfg.warmup_frames, timeout_s=cfg.timeout_s)
    raise AssertionError(f"unhandled source config {cfg!r}")  # parse_source_config admits only the kinds above
