"""The append-only audit log: who did what, when (and from where, in ``detail``)."""

from __future__ import annotations

from sqlmodel import Session, select

from app.store.models import AuditEntry


def audit(session: Session, actor: str, action: str, *, setup_id: int | None = None,
          machine_id: int | None = None, **detail) -> None:
    """Add one entry in the caller's transaction (it is kept exactly when the change is)."""
    session.add(AuditEntry(actor=(actor or "?")[:200], action=action, setup_id=setup_id, machine_id=machine_id,
                           detail=detail))
    session.flush()


def audit_apart(engine, actor: str, action: str, *, setup_id: int | None = None, machine_id: int | None = None,
                **detail) -> None:
    """An entry in a transaction of its own: for refusals, whose request's transaction is rolled back."""
    from app.store.db import session_scope

    try:
        with session_scope(engine) as session:
            audit(session, actor, action, setup_id=setup_id, machine_id=machine_id, **detail)
    except Exception:  # noqa: BLE001 - the refusal stands even when the log cannot be written
        import logging

        logging.getLogger(__name__).exception("audit of a refusal failed", extra={"action": action})


def audit_refusal(engine, actor: str, what: str, address: str, reason: str) -> None:
    """A role refusal (403) on record."""
    audit_apart(engine, actor, "access.refused", request=what[:300], address=address, reason=reason[:300])


def export_refusals(session: Session, setup_id: int) -> list[AuditEntry]:
    """Exports of a setup refused by a gate before any export row was written (not confirmed,
    implausible, bad slot, ...), oldest first: the ``export.refused`` entries with their reason."""
    return list(session.exec(select(AuditEntry).where(AuditEntry.setup_id == setup_id,
                                                      AuditEntry.action == "export.refused")
                             .order_by(AuditEntry.id)).all())
