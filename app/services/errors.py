"""Failures of a use case, each with the HTTP status the API answers and a plain sentence."""

from __future__ import annotations


class ServiceError(Exception):
    """``detail``: one plain sentence; ``code``: a machine-readable reason code (snake_case), answered
    next to the detail as ``{"detail": ..., "code": ...}``. Pages pick their advice from the code, never
    from the sentence; a failure without a specific code answers its class's ``default_code``."""

    status_code = 400
    default_code = "bad_request"

    def __init__(self, detail: str, code: str | None = None):
        super().__init__(detail)
        self.detail = detail
        self.code = code or self.default_code


class NotFound(ServiceError):
    status_code = 404
    default_code = "not_found"


class Invalid(ServiceError):
    status_code = 422
    default_code = "invalid"


class TooLarge(ServiceError):
    status_code = 413
    default_code = "too_large"


class Conflict(ServiceError):
    status_code = 409
    default_code = "conflict"


class Unavailable(ServiceError):
    """An outside system (camera, controller) did not answer."""

    status_code = 502
    default_code = "unavailable"
