"""Workers on other machines share the file store through an S3-compatible bucket: a service that only
enqueues and a ``setupcam worker`` process with its own, empty data folder; the worker reads the
setup's image from the bucket, localises it and writes its pictures there. Nothing goes to a local
folder (docs/jobs.md, "The file store")."""

from __future__ import annotations

import hashlib
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.live_server import live_server
from tests.support.s3 import s3_server
from tests.support.sample_setup import SAMPLES, sample_machine, start_setup, wait_for
from tests.support.service_process import clean_env

pytestmark = [pytest.mark.integration, pytest.mark.slow]
REPO = Path(__file__).resolve().parents[2]


def test_a_worker_localises_an_image_it_reads_from_the_bucket(tmp_path):
    with s3_server() as s3:
        bucket = s3.new_bucket()
        with live_server(tmp_path / "service", embedded_worker=False,
                         **s3.settings(bucket, "plant-a")) as srv, srv.client() as c:
            machine_id, bracket = sample_machine(c)
            accepted = start_setup(c, machine_id, bracket)
            image_sha = hashlib.sha256((SAMPLES / "bracket_on_table.jpg").read_bytes()).hexdigest()
            assert f"plant-a/{image_sha[:2]}/{image_sha}" in s3.keys(bucket), "the upload went to the bucket"
            # another machine: the same database, the same bucket, its own (empty) data folder
            env = clean_env(DATABASE_URL=srv.settings.database_url, SETUPCAM_DATA_DIR=str(tmp_path / "worker"),
                            SETUPCAM_LOG_JSON="false", PYTHONPATH=str(REPO), **s3.env(bucket, "plant-a"))
            with open(tmp_path / "worker.log", "w") as log:
                worker = subprocess.Popen([sys.executable, "-m", "app.cli", "worker"], cwd=REPO, env=env,
                                          stdout=log, stderr=subprocess.STDOUT)
            try:
                job = wait_for(c, accepted["job_url"], lambda j: j["status"] in ("done", "failed"), 240,
                               "localisation by the worker")
            finally:
                worker.send_signal(signal.SIGTERM)
                try:
                    worker.wait(20)
                except subprocess.TimeoutExpired:
                    worker.kill()
            said = (tmp_path / "worker.log").read_text()
            assert job["status"] == "done" and f":{worker.pid}/" in job["worker"], (job, said[-3000:])
            assert f"files in s3://{bucket}/plant-a at {s3.endpoint_url}" in said
            setup = c.get(accepted["url"]).json()
            assert setup["status"] == "located" and setup["result"]["offset"], setup["reason"]
            # what the worker drew is in the bucket, and the service serves it from there
            keys = s3.keys(bucket)
            drawn = [s["image_sha256"] for s in setup["stages"] if s.get("image_sha256")]
            assert drawn and all(f"plant-a/{sha[:2]}/{sha}" in keys for sha in drawn), (drawn, keys)
            r = c.get(f"{accepted['url']}/image")
            assert r.status_code == 200 and hashlib.sha256(r.content).hexdigest() == image_sha
            stage_picture = next(s["image_url"] for s in setup["stages"] if s["image_url"])
            assert c.get(stage_picture).headers["content-type"] == "image/png"
        assert not (tmp_path / "service" / "files").exists() and not (tmp_path / "worker" / "files").exists()
