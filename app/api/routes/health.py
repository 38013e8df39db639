"""/api/v1/health: liveness and database reachability for load balancers and the MES."""

from __future__ import annotations

from fastapi import APIRouter, Request
from pydantic import BaseModel
from sqlalchemy import text

import app

router = APIRouter(tags=["health"])


class Health(BaseModel):
    status: str
    version: str
    database: str
    database_backend: str


@router.get("/health", response_model=Health, summary="Service and database status")
def health(request: Request) -> Health:
    engine = request.app.state.engine
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
        db = "ok"
    except Exception as exc:  # noqa: BLE001 - health reports, never raises
        db = f"error: {exc.__class__.__name__}"
    return Health(status="ok" if db == "ok" else "degraded", version=app.__version__, database=db,
                  database_backend=engine.dialect.name)
