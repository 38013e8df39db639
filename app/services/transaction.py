"""A unit of work for callers outside a web request (the 3D viewer, jobs): a session committed when the
block ends without an exception, rolled back otherwise. Callers above the services (the viewer) use
this rather than reaching into the store."""

from __future__ import annotations

from app.store.db import session_scope as transaction

__all__ = ["transaction"]
