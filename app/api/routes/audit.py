"""/api/v1/audit: the append-only log of exports and other controller writes (admin)."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Query
from pydantic import BaseModel
from sqlmodel import col, select

from app.api.deps import AdminPrincipal, SessionDep
from app.store.models import AuditEntry

router = APIRouter(prefix="/audit", tags=["audit"])


class AuditPublic(BaseModel):
    id: int
    at: datetime
    actor: str
    action: str
    setup_id: int | None
    machine_id: int | None
    detail: dict


@router.get("", response_model=list[AuditPublic], summary="Audit log, newest first (admin)")
def list_audit(session: SessionDep, _admin: AdminPrincipal, setup_id: int | None = None,
               limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[AuditPublic]:
    q = select(AuditEntry)
    if setup_id is not None:
        q = q.where(AuditEntry.setup_id == setup_id)
    rows = session.exec(q.order_by(col(AuditEntry.id).desc()).limit(limit)).all()
    return [AuditPublic.model_validate(r, from_attributes=True) for r in rows]
