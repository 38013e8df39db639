"""Following a job the service accepted (202), as a client does: poll its URL, then read what it made."""

from __future__ import annotations

import time

import httpx

FINAL = ("done", "failed")


def wait_job(client: httpx.Client, accepted: dict, timeout_s: float = 180.0) -> dict:
    """The job (as GET /api/v1/jobs/{id}) once it is done or failed."""
    deadline = time.monotonic() + timeout_s
    while True:
        job = client.get(accepted["job_url"]).json()
        if job["status"] in FINAL:
            return job
        assert time.monotonic() < deadline, f"job still {job['status']} after {timeout_s} s: {job}"
        time.sleep(0.1)


def settled(client: httpx.Client, r: httpx.Response, timeout_s: float = 180.0) -> httpx.Response:
    """``r`` itself when the request was refused (4xx); else, after its job ended, the GET of what the
    job made (the calibration, rotary run or alignment; 200)."""
    if r.status_code != 202:
        return r
    job = wait_job(client, r.json(), timeout_s)
    assert job.get("result") and job["result"].get("url"), f"the job made nothing: {job}"
    return client.get(job["result"]["url"])
