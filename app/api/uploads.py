"""Uploads and JSON form fields read the same way by every route: an upload over the size limit is a
413 (read one byte past the limit, never all of it), an image whose header says more pixels than
``max_image_pixels`` a 413 before anything decodes it, one without a readable header and a form field
that is not JSON a 422, all with the reason. (The whole request body is bounded earlier, before it is
read, by app/api/limits.py.)"""

from __future__ import annotations

import json
import re
from typing import Any
from urllib.parse import quote

from fastapi import UploadFile

from app.services.errors import Invalid, TooLarge
from app.vision.image_header import ImageHeaderError, check_image_size


async def read_upload(upload: UploadFile, settings, what: str) -> bytes:
    """The bytes of one upload; ``what`` names it in the refusal ("image", "image 'a.png'")."""
    max_bytes = int(settings.max_upload_mb * 1e6)
    data = await upload.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise TooLarge(f"{what} is over {settings.max_upload_mb:.0f} MB")
    return data


def check_image(data: bytes, settings, what: str, unreadable_ok: bool = False) -> bytes:
    """``data`` when its header names a readable image of at most ``settings.max_image_pixels``; else
    413 (too many pixels) or 422 (no readable header; let through with ``unreadable_ok``, for the drift
    monitor, which records an unreadable frame as missing). Nothing is decoded here."""
    try:
        check_image_size(data, settings.max_image_pixels)
    except ImageHeaderError as exc:
        if exc.too_large or not unreadable_ok:
            raise (TooLarge if exc.too_large else Invalid)(f"{what} {exc}") from None
    return data


async def read_image_upload(upload: UploadFile, settings, what: str) -> bytes:
    """The bytes of one uploaded image, size and pixel count checked (see :func:`check_image`)."""
    return check_image(await read_upload(upload, settings, what), settings, what)


async def read_uploads(uploads: list[UploadFile], settings) -> list[tuple[str, bytes]]:
    """(file name, bytes) of several uploaded images, in order, each checked like one image and all
    together against ``settings.max_request_pixels`` (they are decoded side by side)."""
    out, pixels = [], 0
    for f in uploads:
        what = f"image {f.filename!r}"
        data = await read_image_upload(f, settings, what)
        w, h = check_image_size(data, settings.max_image_pixels)
        pixels += w * h
        if pixels > settings.max_request_pixels:
            raise TooLarge(f"the {len(out) + 1} images up to {what} have {pixels:,} px together; one request "
                           f"takes at most {settings.max_request_pixels:,} px")
        out.append((f.filename or f"image{len(out)}", data))
    return out


def json_form(value: str | None, name: str) -> Any:
    """A JSON form field: None when missing or empty, else the parsed value."""
    if not value:
        return None
    try:
        return json.loads(value)
    except json.JSONDecodeError as exc:
        raise Invalid(f"{name}: not valid JSON ({exc.msg})") from None


_UNSAFE_NAME = re.compile(r"[\x00-\x1f\x7f\"\\;]")


def safe_filename(name: str | None, default: str = "upload") -> str:
    """An uploaded file's name without folders, control characters, quotes or semicolons (at most 200
    characters, suffix kept): safe to store, show and send back."""
    name = (name or "").replace("\\", "/").rsplit("/", 1)[-1]
    name = _UNSAFE_NAME.sub("", name).strip().lstrip(".")
    if len(name) > 200:
        stem, dot, suffix = name.rpartition(".")
        name = (stem[: 200 - len(suffix) - 1] + dot + suffix) if dot and len(suffix) <= 10 else name[:200]
    return name or default


def content_disposition(filename: str, disposition: str = "inline") -> str:
    """``Content-Disposition`` for any file name: an ASCII fallback plus the UTF-8 name (RFC 5987/6266), so
    a name such as 'Spannvorrichtung-Ø40.step' or '治具.stl' never breaks the (Latin-1) header."""
    name = safe_filename(filename, "file")
    ascii_name = name.encode("ascii", "replace").decode("ascii").replace("?", "_")
    header = f'{disposition}; filename="{ascii_name}"'
    if ascii_name != name:
        header += f"; filename*=UTF-8''{quote(name, safe='')}"
    return header
