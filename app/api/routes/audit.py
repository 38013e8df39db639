"""/api/v1/audit: the append-only log of security-relevant actions (admin): sign-ins (ok, failed,
throttled), account and key changes, role refusals, confirm, adjust, refine, datum, exports, machine,
camera and library changes; who, when and (in ``detail``) from where. Readable as JSON or as CSV."""

from __future__ import annotations

import csv
import io
import json
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Query, Response
from pydantic import BaseModel
from app.api.deps import AdminPrincipal, SessionDep
from app.services import audit as audit_svc

router = APIRouter(prefix="/audit", tags=["audit"])


class AuditPublic(BaseModel):
    id: int
    at: datetime
    actor: str
    action: str
    setup_id: int | None
    machine_id: int | None
    detail: dict


def _entries(session, setup_id: int | None, action: str | None, since: datetime | None, limit: int):
    return audit_svc.list_entries(session, setup_id=setup_id, action=action, since=since, limit=limit)


@router.get("", response_model=list[AuditPublic], summary="Audit log, newest first (admin)")
def list_audit(session: SessionDep, _admin: AdminPrincipal, setup_id: int | None = None,
               action: Annotated[str | None, Query(max_length=50, description="prefix, e.g. auth. or setup.")] = None,
               since: datetime | None = None,
               limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> list[AuditPublic]:
    return [AuditPublic.model_validate(r, from_attributes=True)
            for r in _entries(session, setup_id, action, since, limit)]


@router.get("/export.csv", response_class=Response, summary="The audit log as CSV, newest first (admin)",
            responses={200: {"content": {"text/csv": {}}}})
def export_audit(session: SessionDep, _admin: AdminPrincipal, setup_id: int | None = None,
                 action: Annotated[str | None, Query(max_length=50)] = None, since: datetime | None = None,
                 limit: Annotated[int, Query(ge=1, le=100_000)] = 10_000) -> Response:
    out = io.StringIO()
    w = csv.writer(out)
    w.writerow(["id", "at", "actor", "action", "setup_id", "machine_id", "detail"])
    for r in _entries(session, setup_id, action, since, limit):
        w.writerow([r.id, r.at.isoformat(), r.actor, r.action, r.setup_id or "", r.machine_id or "",
                    json.dumps(r.detail, sort_keys=True)])
    return Response(out.getvalue(), media_type="text/csv",
                    headers={"Content-Disposition": 'attachment; filename="setupcam-audit.csv"'})
