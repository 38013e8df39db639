"""Uploads and JSON form fields read the same way by every route: an upload over the size limit is a
413 (read one byte past the limit, never all of it), a form field that is not JSON a 422, both with
the reason."""

from __future__ import annotations

import json
from typing import Any

from fastapi import UploadFile

from app.services.errors import Invalid, TooLarge


async def read_upload(upload: UploadFile, settings, what: str) -> bytes:
    """The bytes of one upload; ``what`` names it in the refusal ("image", "image 'a.png'")."""
    max_bytes = int(settings.max_upload_mb * 1e6)
    data = await upload.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise TooLarge(f"{what} is over {settings.max_upload_mb:.0f} MB")
    return data


async def read_uploads(uploads: list[UploadFile], settings) -> list[tuple[str, bytes]]:
    """(file name, bytes) of several uploaded images, in order."""
    out = []
    for f in uploads:
        out.append((f.filename or f"image{len(out)}", await read_upload(f, settings, f"image {f.filename!r}")))
    return out


def json_form(value: str | None, name: str) -> Any:
    """A JSON form field: None when missing or empty, else the parsed value."""
    if not value:
        return None
    try:
        return json.loads(value)
    except json.JSONDecodeError as exc:
        raise Invalid(f"{name}: not valid JSON ({exc.msg})") from None
