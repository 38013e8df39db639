"""/api/v1/jobs: long work (localisation, sheet alignment, calibration, rotary run) as queued jobs.

A route that starts long work only checks the request, stores its files, enqueues a job and answers
202 with :class:`JobAccepted` (the job's URL and its events URL); the job's ``result.url`` names what
it made once it is done.
"""

from __future__ import annotations

import asyncio
import json
from datetime import datetime
from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import StreamingResponse
from pydantic import BaseModel, Field
from sqlmodel import Session

from app.api.deps import SessionDep, get_principal
from app.services import jobs as svc
from app.services.transaction import transaction

router = APIRouter(prefix="/jobs", tags=["jobs"], dependencies=[Depends(get_principal)])

# where each kind of thing a job makes is read (services build no URLs)
RESOURCE_URLS = {
    "setup": lambda r: f"/api/v1/setups/{r['id']}",
    "calibration": lambda r: f"/api/v1/cameras/{r['camera_id']}/calibrations/{r['id']}",
    "rotary_run": lambda r: f"/api/v1/rotary/runs/{r['id']}",
    "sheet_alignment": lambda r: f"/api/v1/sheet/alignments/{r['id']}",
}


class JobAccepted(BaseModel):
    job_id: int
    kind: str
    status: str = Field(description="queued | running | done | failed")
    job_url: str = Field(description="GET: the job's status, reason and result")
    events_url: str = Field(description="GET: the job's status as server-sent events until it ends")


class JobPublic(BaseModel):
    id: int
    kind: str = Field(description="localize | sheet_align | calibrate | rotary")
    status: str = Field(description="queued | running | done | failed")
    reason: str = Field(description="Why it failed (timeout, crash, a worker that died too often), or why it "
                                    "went back to the queue")
    result: dict | None = Field(description="What it made: {resource, id, url}")
    attempts: int = Field(description="Starts so far (a start per worker that took it)")
    max_attempts: int
    timeout_s: float
    worker: str | None = Field(description="host:pid/thread of the last run")
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    url: str
    events_url: str


def job_urls(job_id: int) -> tuple[str, str]:
    return f"/api/v1/jobs/{job_id}", f"/api/v1/jobs/{job_id}/events"


def result_public(result: dict | None) -> dict | None:
    if not result:
        return result
    link = RESOURCE_URLS.get(result.get("resource", ""))
    return {**result, "url": link(result)} if link else result


def job_public(job) -> JobPublic:
    url, events_url = job_urls(job.id)
    return JobPublic(**job.model_dump(exclude={"result", "args"}), result=result_public(job.result), url=url,
                     events_url=events_url)


def enqueue(request: Request, session: Session, kind: str, args: dict, created_by: str | None) -> JobAccepted:
    """Create the job, commit (so that a worker elsewhere sees it), hand it to the queue."""
    job = svc.create_job(session, kind, args, request.app.state.settings, created_by=created_by)
    session.commit()
    request.app.state.jobs.push(job.id)
    url, events_url = job_urls(job.id)
    return JobAccepted(job_id=job.id, kind=kind, status=job.status, job_url=url, events_url=events_url)


@router.get("", response_model=list[JobPublic], summary="Recent jobs, newest first")
def list_jobs(session: SessionDep, status: str | None = None,
              limit: Annotated[int, Query(ge=1, le=500)] = 50) -> list[JobPublic]:
    return [job_public(j) for j in svc.list_jobs(session, status=status, limit=limit)]


@router.get("/{job_id}", response_model=JobPublic, summary="A job's status, reason and result")
def get_job(session: SessionDep, job_id: int) -> JobPublic:
    return job_public(svc.get_job(session, job_id))


@router.get("/{job_id}/events", summary="The job's status as server-sent events until it ends",
            response_class=StreamingResponse, responses={200: {"content": {"text/event-stream": {}}}})
async def job_events(request: Request, job_id: int) -> StreamingResponse:
    """``event: status`` with the job (as GET) at each change of status or attempt; the stream ends
    with the job."""
    engine = request.app.state.engine
    with transaction(engine) as session:
        svc.get_job(session, job_id)  # 404 before the stream starts

    def snapshot() -> dict:
        with transaction(engine) as session:
            return job_public(svc.get_job(session, job_id)).model_dump(mode="json")

    async def stream():
        last = None
        for _ in range(10 * 60 * 10):  # at most 10 minutes, then the client reconnects
            if await request.is_disconnected():
                return
            job = await asyncio.to_thread(snapshot)
            if (job["status"], job["attempts"]) != last:
                last = (job["status"], job["attempts"])
                yield f"event: status\ndata: {json.dumps(job)}\n\n"
            if job["status"] in svc.FINAL:
                return
            await asyncio.sleep(0.1)

    return StreamingResponse(stream(), media_type="text/event-stream",
                             headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"})
