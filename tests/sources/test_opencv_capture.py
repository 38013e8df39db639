"""OpenCV source: one frame from a real video file written with cv2.VideoWriter, and a bad device."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from app.sources import SourceError, make_source

LEVELS = (20, 80, 140, 200)  # one grey level per frame, so the frame delivered can be identified


@pytest.fixture(scope="module")
def video(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("video") / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    assert writer.isOpened(), "OpenCV cannot write MJPG/AVI here"
    for level in LEVELS:
        frame = np.full((48, 64, 3), level, np.uint8)
        cv2.putText(frame, str(level), (5, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1)
        writer.write(frame)
    writer.release()
    assert path.stat().st_size > 0
    return path


def test_first_frame_of_a_file(video):
    image = make_source({"kind": "opencv", "url": str(video)}).grab()
    assert image.shape == (48, 64, 3) and image.dtype == np.uint8
    assert abs(float(np.median(image)) - LEVELS[0]) < 5


def test_warmup_frames_are_dropped(video):
    image = make_source({"kind": "opencv", "url": str(video), "warmup_frames": 2}).grab()
    assert abs(float(np.median(image)) - LEVELS[2]) < 5


def test_end_of_file(video):
    with pytest.raises(SourceError) as info:
        make_source({"kind": "opencv", "url": str(video), "warmup_frames": 10, "timeout_s": 2}).grab()
    assert str(info.value) == (
        f"OpenCV stream {video}: opened but delivered no frame within 2 s (end of file, or the stream stalled)"
    )


def test_bad_device_and_missing_file(tmp_path):
    with pytest.raises(SourceError) as info:
        make_source({"kind": "opencv", "device": 97}).grab()
    assert str(info.value).startswith("OpenCV device 97: could not be opened; no such device")
    missing = tmp_path / "none.avi"
    with pytest.raises(SourceError) as info:
        make_source({"kind": "opencv", "url": str(missing), "timeout_s": 2}).grab()
    assert str(info.value).startswith(f"OpenCV stream {missing}: could not be opened; check the URL or path")
