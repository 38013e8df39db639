"""What a failure looks like on the wire: ``{"detail": "<one sentence>", "code": "<reason code>"}``.

Every 4xx/5xx JSON answer carries a machine-readable ``code`` (snake_case) beside the sentence, so a
page or a client picks its advice from the code and never matches the English text. Service failures
name their own code (app/services/errors.py); refusals of the HTTP layer (sign-in, role, size, unknown
path) use the codes below.
"""

from __future__ import annotations

from fastapi import HTTPException

# the code of an answer whose raiser named none, by HTTP status
STATUS_CODES = {400: "bad_request", 401: "sign_in_required", 403: "forbidden", 404: "not_found",
                405: "method_not_allowed", 409: "conflict", 413: "too_large", 415: "unsupported_media_type",
                422: "invalid", 429: "too_many_attempts", 500: "internal_error", 502: "unavailable",
                503: "not_running"}


def code_for_status(status: int) -> str:
    """The generic reason code of an HTTP status (``error`` for one without a name here)."""
    return STATUS_CODES.get(status, "error")


def problem(status: int, detail: str, code: str | None = None) -> dict:
    """The JSON body of a failure."""
    return {"detail": detail, "code": code or code_for_status(status)}


class Refused(HTTPException):
    """An HTTPException with its own reason code (e.g. ``admin_required``)."""

    def __init__(self, status_code: int, detail: str, code: str, headers: dict | None = None):
        super().__init__(status_code, detail, headers=headers)
        self.code = code
