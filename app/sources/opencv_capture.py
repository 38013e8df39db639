"""The "opencv" source: one frame from cv2.VideoCapture (device index, RTSP/HTTP stream or video file)."""

from __future__ import annotations

import cv2
import numpy as np

from app.sources.base import ImageSource, SourceError, to_bgr_uint8


class OpenCVSource(ImageSource):
    """Opens the device or stream, drops ``warmup_frames`` frames, returns the next one, releases.

    Opening per grab keeps no device locked between snapshots and returns a current frame (a capture
    left open would hand out a stale buffered frame).
    """

    kind = "opencv"

    def __init__(self, device: int | None = None, url: str | None = None, warmup_frames: int = 0,
                 timeout_s: float = 10.0) -> None:
        if (device is None) == (url is None):
            raise ValueError('give exactly one of "device" or "url"')
        self.device = device
        self.url = url
        self.warmup_frames = warmup_frames
        self.timeout_s = timeout_s

    def describe(self) -> str:
        return f"OpenCV device {self.device}" if self.device is not None else f"OpenCV stream {self.url}"

    def grab(self) -> np.ndarray:
        ms = int(self.timeout_s * 1000)
        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, ms]
        target = self.device if self.device is not None else self.url
        cap = cv2.VideoCapture(target, cv2.CAP_ANY, params)
        try:
            if not cap.isOpened():
                hint = ("no such device, or it is busy or not permitted (check /dev/video* and the video group)"
                        if self.device is not None else
                        "check the URL or path, the network and that the stream format is supported")
                raise SourceError(f"{self.describe()}: could not be opened; {hint}")
            frame = None
            for _ in range(self.warmup_frames + 1):
                ok, frame = cap.read()
                if not ok or frame is None:
                    raise SourceError(
                        f"{self.describe()}: opened but delivered no frame within {self.timeout_s:g} s "
                        "(end of file, or the stream stalled)"
                    )
            return to_bgr_uint8(frame)
        finally:
            cap.release()
