"""Folder source: newest image in a folder, optionally only files newer than the last grab."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from app.sources import SourceError, make_source


def _write(path: Path, value: int, mtime_s: float) -> np.ndarray:
    image = np.full((20, 30, 3), value, np.uint8)
    assert cv2.imwrite(str(path), image)
    os.utime(path, (mtime_s, mtime_s))
    return image


def test_newest_image_wins(tmp_path):
    _write(tmp_path / "a.png", 10, 1_700_000_000)
    _write(tmp_path / "c.png", 30, 1_700_000_100)
    _write(tmp_path / "b.png", 20, 1_700_000_050)
    (tmp_path / "notes.txt").write_text("newest, but not an image")
    _write(tmp_path / ".partial.png", 99, 1_700_000_200)  # hidden: a copy in progress
    source = make_source({"kind": "folder", "path": str(tmp_path)})
    image = source.grab()
    assert image.shape == (20, 30, 3) and int(image[0, 0, 0]) == 30
    assert source.last_path == tmp_path / "c.png"


def test_pattern_restricts_files(tmp_path):
    _write(tmp_path / "cam1_0001.png", 10, 1_700_000_000)
    _write(tmp_path / "cam2_0001.png", 20, 1_700_000_100)
    image = make_source({"kind": "folder", "path": str(tmp_path), "pattern": "cam1_*.png"}).grab()
    assert int(image[0, 0, 0]) == 10


def test_only_new(tmp_path):
    _write(tmp_path / "a.png", 10, 1_700_000_000)
    source = make_source({"kind": "folder", "path": str(tmp_path), "only_new": True})
    assert int(source.grab()[0, 0, 0]) == 10
    with pytest.raises(SourceError) as info:
        source.grab()
    assert str(info.value) == (
        f"folder {tmp_path} has no new image since the last grab (a.png, 2023-11-14 22:13:20 UTC)"
    )
    _write(tmp_path / "b.png", 20, 1_700_000_001)
    assert int(source.grab()[0, 0, 0]) == 20
    # without only_new the same file can be grabbed again
    again = make_source({"kind": "folder", "path": str(tmp_path)})
    assert int(again.grab()[0, 0, 0]) == 20 and int(again.grab()[0, 0, 0]) == 20


def test_empty_and_missing_folder(tmp_path):
    with pytest.raises(SourceError) as info:
        make_source({"kind": "folder", "path": str(tmp_path), "pattern": "*.jpg"}).grab()
    assert str(info.value) == f"folder {tmp_path} has no images yet (no file matching '*.jpg')"
    with pytest.raises(SourceError) as info:
        make_source({"kind": "folder", "path": str(tmp_path)}).grab()
    assert str(info.value) == f"folder {tmp_path} has no images yet (no file with an image suffix)"
    missing = tmp_path / "gone"
    with pytest.raises(SourceError) as info:
        make_source({"kind": "folder", "path": str(missing)}).grab()
    assert str(info.value) == f"folder {missing} does not exist or is not a folder"


def test_half_written_newest_file(tmp_path):
    _write(tmp_path / "a.png", 10, 1_700_000_000)
    half = tmp_path / "b.jpg"
    half.write_bytes(b"\xff\xd8\xff\xe0 truncated")
    source = make_source({"kind": "folder", "path": str(tmp_path), "only_new": True})
    with pytest.raises(SourceError) as info:
        source.grab()
    assert str(info.value) == (
        f"folder {tmp_path}: newest file b.jpg is not a readable image (14 bytes; still being written, or not an image)"
    )
    assert source.last_path is None  # a failed grab does not count as delivered
