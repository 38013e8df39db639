"""/api/v1/health: liveness, database and job worker for load balancers and the MES: 200 when all is
well, 503 naming the failing part otherwise."""

from __future__ import annotations

from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from sqlalchemy import text

import app

router = APIRouter(tags=["health"])


class Health(BaseModel):
    status: str = Field(description="ok | degraded")
    version: str
    database: str = Field(description="ok | error: <kind>")
    database_backend: str
    worker: str = Field(description="ok | stopped (setup jobs are not being run)")
    failing: list[str] = Field(default_factory=list, description="the parts that are not ok")


@router.get("/health", response_model=Health, summary="Service, database and worker status",
            responses={503: {"model": Health, "description": "degraded: `failing` names the parts"}})
def health(request: Request):
    engine = request.app.state.engine
    try:
        with engine.connect() as conn:
            conn.execute(text("SELECT 1"))
        db = "ok"
    except Exception as exc:  # noqa: BLE001 - health reports, never raises
        db = f"error: {exc.__class__.__name__}"
    jobs = getattr(request.app.state, "jobs", None)
    worker = "ok" if jobs is not None and jobs.alive() else "stopped"
    failing = [name for name, state in (("database", db), ("worker", worker)) if state != "ok"]
    body = Health(status="degraded" if failing else "ok", version=app.__version__, database=db,
                  database_backend=engine.dialect.name, worker=worker, failing=failing)
    if failing:
        return JSONResponse(body.model_dump(), status_code=503)
    return body
