"""The append-only audit log: who did what, when (and from where, in ``detail``)."""

from __future__ import annotations

import logging
from datetime import datetime

from sqlmodel import Session, col, select

from app.store.db import session_scope
from app.store.models import AuditEntry

log = logging.getLogger(__name__)


def audit(session: Session, actor: str, action: str, *, setup_id: int | None = None,
          machine_id: int | None = None, **detail) -> None:
    """Add one entry in the caller's transaction (it is kept exactly when the change is)."""
    session.add(AuditEntry(actor=(actor or "?")[:200], action=action, setup_id=setup_id, machine_id=machine_id,
                           detail=detail))
    session.flush()


def audit_apart(engine, actor: str, action: str, *, setup_id: int | None = None, machine_id: int | None = None,
                **detail) -> None:
    """An entry in a transaction of its own: for refusals, whose request's transaction is rolled back."""
    try:
        with session_scope(engine) as session:
            audit(session, actor, action, setup_id=setup_id, machine_id=machine_id, **detail)
    except Exception:  # noqa: BLE001 - the refusal stands even when the log cannot be written
        log.exception("audit of a refusal failed", extra={"action": action})


def audit_refusal(engine, actor: str, what: str, address: str, reason: str) -> None:
    """A role refusal (403) on record."""
    audit_apart(engine, actor, "access.refused", request=what[:300], address=address, reason=reason[:300])


def list_entries(session: Session, *, setup_id: int | None = None, action: str | None = None,
                 since: datetime | None = None, limit: int = 100) -> list[AuditEntry]:
    """Entries newest first: of one setup, whose action starts with ``action``, at or after ``since``."""
    q = select(AuditEntry)
    if setup_id is not None:
        q = q.where(AuditEntry.setup_id == setup_id)
    if action:
        q = q.where(col(AuditEntry.action).startswith(action))
    if since is not None:
        q = q.where(AuditEntry.at >= since)
    return list(session.exec(q.order_by(col(AuditEntry.id).desc()).limit(limit)).all())


def export_refusals(session: Session, setup_id: int) -> list[AuditEntry]:
    """Exports of a setup refused by a gate before any export row was written (not confirmed,
    implausible, bad slot, ...), oldest first: the ``export.refused`` entries with their reason."""
    return list(reversed(list_entries(session, setup_id=setup_id, action="export.refused", limit=10_000)))
