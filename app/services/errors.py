"""Failures of a use case, each with the HTTP status the API answers and a plain sentence."""

from __future__ import annotations


class ServiceError(Exception):
    """``detail``: one plain sentence; ``code``: an optional machine-readable reason code (snake_case),
    answered next to the detail as ``{"detail": ..., "code": ...}`` (e.g. the probing program's gates)."""

    status_code = 400

    def __init__(self, detail: str, code: str | None = None):
        super().__init__(detail)
        self.detail = detail
        self.code = code


class NotFound(ServiceError):
    status_code = 404


class Invalid(ServiceError):
    status_code = 422


class TooLarge(ServiceError):
    status_code = 413


class Conflict(ServiceError):
    status_code = 409


class Unavailable(ServiceError):
    """An outside system (camera, controller) did not answer."""

    status_code = 502
