"""The job kinds: each long piece of work, its function and what happens to its subject when the job
fails without it or goes back to the queue. Services and workers take this table from here; it is a
constant (no state)."""

from __future__ import annotations

from app.services.cameras import run_calibration_job
from app.services.jobs import JobKind
from app.services.rotary import run_rotary_job
from app.services.setups import fail_setup, requeue_setup, run_setup_job
from app.services.sheet import run_alignment_job

KINDS: dict[str, JobKind] = {
    "localize": JobKind(run_setup_job, on_fail=fail_setup, on_requeue=requeue_setup),
    "calibrate": JobKind(run_calibration_job),
    "rotary": JobKind(run_rotary_job),
    "sheet_align": JobKind(run_alignment_job),
}
