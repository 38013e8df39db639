"""Source configs: valid ones build the right source without I/O, invalid ones say why (API: 422)."""

from __future__ import annotations

import pytest

from app.sources import (
    FolderSource,
    HttpSnapshotSource,
    OpenCVSource,
    SourceError,
    UploadSource,
    make_source,
    parse_source_config,
)


@pytest.mark.parametrize(
    "config, cls, described",
    [
        ({"kind": "upload"}, UploadSource, "upload only"),
        ({"kind": "http", "url": "http://192.0.2.10/snapshot.jpg"}, HttpSnapshotSource,
         "HTTP snapshot http://192.0.2.10/snapshot.jpg"),
        ({"kind": "http", "url": "http://admin:secret@192.0.2.10/snap.jpg", "username": "u", "password": "p",
          "auth": "digest"}, HttpSnapshotSource, "HTTP snapshot http://192.0.2.10/snap.jpg"),
        ({"kind": "folder", "path": "/srv/cam1", "pattern": "*.jpg"}, FolderSource, "folder /srv/cam1"),
        ({"kind": "opencv", "device": 0}, OpenCVSource, "OpenCV device 0"),
        ({"kind": "opencv", "url": "rtsp://192.0.2.11/stream1"}, OpenCVSource, "OpenCV stream rtsp://192.0.2.11/stream1"),
    ],
)
def test_valid_configs_build_sources(config, cls, described):
    source = make_source(config)
    assert isinstance(source, cls)
    assert source.describe() == described
    assert "secret" not in repr(source)


@pytest.mark.parametrize(
    "config, message",
    [
        ({}, "source needs a kind; use one of upload, http, folder, opencv"),
        ({"kind": "ftp"}, "source kind 'ftp' is unknown; use one of upload, http, folder, opencv"),
        ("http://cam", "source config must be a JSON object such as {\"kind\": \"upload\"}, got str"),
        ({"kind": "http"}, "http source field url: Field required"),
        ({"kind": "http", "url": "ftp://192.0.2.10/x.jpg"},
         "http source field url: url 'ftp://192.0.2.10/x.jpg' must start with http:// or https:// and name a host"),
        ({"kind": "http", "url": "http://cam/x.jpg", "timeout_s": 0},
         "http source field timeout_s: Input should be greater than 0"),
        ({"kind": "folder", "path": "/srv/cam1", "patern": "*.jpg"},
         "folder source field patern: unknown field for a folder source (allowed: kind, path, pattern, only_new)"),
        ({"kind": "folder", "path": "/srv/cam1", "pattern": "../*.jpg"},
         "folder source field pattern: pattern '../*.jpg' must stay inside the folder (no leading / and no ..)"),
        ({"kind": "folder"}, "folder source field path: Field required"),
        ({"kind": "opencv"},
         'opencv source: give exactly one of "device" (an index such as 0) or "url" (a stream or file)'),
        ({"kind": "opencv", "device": 0, "url": "rtsp://x"},
         'opencv source: give exactly one of "device" (an index such as 0) or "url" (a stream or file)'),
        ({"kind": "opencv", "device": -1}, "opencv source field device: Input should be greater than or equal to 0"),
    ],
)
def test_invalid_configs_say_why(config, message):
    with pytest.raises(ValueError) as info:
        make_source(config)
    assert str(info.value) == message


def test_parse_keeps_the_users_url_and_defaults():
    cfg = parse_source_config({"kind": "http", "url": "http://cam"})
    assert cfg.url == "http://cam" and cfg.timeout_s == 5.0 and cfg.model_dump()["kind"] == "http"
    assert parse_source_config(cfg) is cfg


def test_upload_source_cannot_grab():
    with pytest.raises(SourceError) as info:
        make_source({"kind": "upload"}).grab()
    assert str(info.value).startswith("this camera only accepts uploaded images (source kind 'upload')")
    with pytest.raises(SourceError, match="^camera mill3 only accepts uploaded images"):
        UploadSource("mill3").grab()
