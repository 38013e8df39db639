"""A real S3-compatible server for tests: moto's server mode (``moto[server]``) on 127.0.0.1, speaking
the S3 HTTP API as MinIO or AWS would; boto3 (the service, a worker process) talks to it over HTTP."""

from __future__ import annotations

import contextlib
import logging
import uuid
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from tests.support.live_server import free_port

KEY_ID, SECRET, REGION = "setupcam-test", "setupcam-test-secret", "us-east-1"


@dataclass
class S3Server:
    endpoint_url: str

    def client(self):
        import boto3

        return boto3.client("s3", endpoint_url=self.endpoint_url, aws_access_key_id=KEY_ID,
                            aws_secret_access_key=SECRET, region_name=REGION)

    def new_bucket(self) -> str:
        """A fresh, empty bucket's name."""
        name = f"setupcam-{uuid.uuid4().hex[:12]}"
        self.client().create_bucket(Bucket=name)
        return name

    def keys(self, bucket: str) -> list[str]:
        """Every object's key in ``bucket``."""
        pages = self.client().get_paginator("list_objects_v2").paginate(Bucket=bucket)
        return sorted(o["Key"] for page in pages for o in page.get("Contents", []))

    def settings(self, bucket: str, prefix: str) -> dict:
        """The service's settings (keyword arguments of Settings) for ``s3://bucket/prefix`` on this server."""
        return {"file_store": f"s3://{bucket}/{prefix}", "s3_endpoint_url": self.endpoint_url, "s3_region": REGION,
                "s3_access_key_id": KEY_ID, "s3_secret_access_key": SECRET}

    def env(self, bucket: str, prefix: str) -> dict[str, str]:
        """The same as environment variables, for a ``setupcam`` process."""
        return {"SETUPCAM_FILE_STORE": f"s3://{bucket}/{prefix}", "SETUPCAM_S3_ENDPOINT_URL": self.endpoint_url,
                "SETUPCAM_S3_REGION": REGION, "SETUPCAM_S3_ACCESS_KEY_ID": KEY_ID,
                "SETUPCAM_S3_SECRET_ACCESS_KEY": SECRET}


@contextlib.contextmanager
def s3_server() -> Iterator[S3Server]:
    """moto's S3 server in a thread of this process (skips the test when moto is not installed)."""
    server_mod = pytest.importorskip("moto.server", reason="moto[server] is not installed (pip install -e '.[test]')")
    logging.getLogger("werkzeug").setLevel(logging.ERROR)  # not one line per request
    port = free_port()
    server = server_mod.ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    try:
        yield S3Server(f"http://127.0.0.1:{port}")
    finally:
        server.stop()
