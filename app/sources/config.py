"""Image-source configuration as stored on a camera and accepted by the API.

    {"kind": "upload"}
    {"kind": "http", "url": "http://192.0.2.10/snapshot.jpg", "timeout_s": 5}
    {"kind": "folder", "path": "/srv/cam1", "pattern": "*.jpg", "only_new": true}
    {"kind": "opencv", "device": 0}   or   {"kind": "opencv", "url": "rtsp://192.0.2.11/stream1"}

``parse_source_config(dict)`` validates and returns the matching model; bad input raises ValueError
with one sentence (the API turns it into 422).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Union

import httpx
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

KINDS = ("upload", "http", "folder", "opencv")


class _Config(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class UploadSourceConfig(_Config):
    """No source: images only arrive as uploads."""

    kind: Literal["upload"] = "upload"


class HttpSourceConfig(_Config):
    """A URL that answers GET with one JPEG/PNG (an IP camera's snapshot URL)."""

    kind: Literal["http"] = "http"
    url: str = Field(examples=["http://192.0.2.10/snapshot.jpg"], description="http:// or https:// snapshot URL")
    timeout_s: float = Field(5.0, gt=0, le=120, description="connect/read timeout in seconds")
    username: str | None = Field(None, description="for cameras behind HTTP authentication")
    password: str | None = None
    auth: Literal["basic", "digest"] = Field("basic", description="HTTP authentication scheme")
    verify_tls: bool = Field(True, description="check the server certificate for https URLs")
    max_mb: float = Field(50.0, gt=0, le=1000, description="refuse answers larger than this (a stream, not a snapshot)")

    @field_validator("url")
    @classmethod
    def _http_url(cls, url: str) -> str:
        try:
            parsed = httpx.URL(url)
        except Exception as exc:  # httpx.InvalidURL and friends
            raise ValueError(f"url {url!r} is not a valid URL ({exc})") from None
        if parsed.scheme not in ("http", "https") or not parsed.host:
            raise ValueError(f"url {url!r} must start with http:// or https:// and name a host")
        return url


class FolderSourceConfig(_Config):
    """A folder another program writes images into; a grab takes the newest file."""

    kind: Literal["folder"] = "folder"
    path: str = Field(min_length=1, examples=["/srv/cameras/mill3"], description="folder on this server")
    pattern: str | None = Field(
        None, examples=["*.jpg"],
        description="glob inside the folder; default: any .jpg/.jpeg/.png/.bmp/.tif/.tiff/.webp file",
    )
    only_new: bool = Field(False, description="refuse to deliver the same file twice (only files newer than the last grab)")

    @field_validator("pattern")
    @classmethod
    def _relative_pattern(cls, pattern: str | None) -> str | None:
        if pattern is None:
            return None
        if not pattern.strip():
            raise ValueError("pattern is empty; leave it out to accept any image file")
        if pattern.startswith(("/", "\\")) or ".." in pattern.replace("\\", "/").split("/"):
            raise ValueError(f"pattern {pattern!r} must stay inside the folder (no leading / and no ..)")
        return pattern


class OpenCVSourceConfig(_Config):
    """A camera device index or a stream/file URL opened with cv2.VideoCapture for one frame."""

    kind: Literal["opencv"] = "opencv"
    device: int | None = Field(None, ge=0, le=255, description="device index, e.g. 0 for /dev/video0")
    url: str | None = Field(None, min_length=1, examples=["rtsp://192.0.2.11/stream1"],
                            description="stream URL (rtsp://, http:// MJPEG) or video file path")
    warmup_frames: int = Field(0, ge=0, le=100, description="frames to drop before the one returned (auto exposure)")
    timeout_s: float = Field(10.0, gt=0, le=120, description="open/read timeout in seconds")

    @model_validator(mode="after")
    def _one_target(self) -> OpenCVSourceConfig:
        if (self.device is None) == (self.url is None):
            raise ValueError('give exactly one of "device" (an index such as 0) or "url" (a stream or file)')
        return self


SourceConfig = Annotated[
    Union[UploadSourceConfig, HttpSourceConfig, FolderSourceConfig, OpenCVSourceConfig],
    Field(discriminator="kind"),
]
_BY_KIND = {"upload": UploadSourceConfig, "http": HttpSourceConfig, "folder": FolderSourceConfig,
            "opencv": OpenCVSourceConfig}


def parse_source_config(config: Any) -> UploadSourceConfig | HttpSourceConfig | FolderSourceConfig | OpenCVSourceConfig:
    """Validate a source config (dict or model); ValueError with one readable sentence on bad input."""
    if isinstance(config, tuple(_BY_KIND.values())):
        return config
    if not isinstance(config, dict):
        raise ValueError(f"source config must be a JSON object such as {{\"kind\": \"upload\"}}, got {type(config).__name__}")
    kind = config.get("kind")
    if kind not in _BY_KIND:
        what = "needs a kind" if kind is None else f"kind {kind!r} is unknown"
        raise ValueError(f"source {what}; use one of {', '.join(KINDS)}")
    try:
        return _BY_KIND[kind].model_validate(config)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        msg = first["msg"].removeprefix("Value error, ")
        if first["type"] == "extra_forbidden":
            allowed = ", ".join(_BY_KIND[kind].model_fields)
            msg = f"unknown field for a {kind} source (allowed: {allowed})"
        raise ValueError(f"{kind} source{' field ' + where if where else ''}: {msg}") from None
