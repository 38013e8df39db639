"""Content-addressed file storage: bytes are stored once under ``ab/abcdef...`` by their sha256.

Two stores behind one interface (:class:`FileStore`: ``put``, ``read``, ``exists``, ``media_type``):

* :class:`FolderStore`: a folder (``$SETUPCAM_DATA_DIR/files``, or a shared NFS/SMB mount);
* :class:`S3Store`: a bucket on an S3-compatible server (AWS S3, MinIO, Ceph RGW), ``s3://bucket/prefix``.

:func:`open_file_store` picks one from the settings (``SETUPCAM_FILE_STORE``). The ``storedfile`` rows
(size, media type) are in the database either way; a file is written before its row, so a row always
names bytes that exist.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from abc import ABC, abstractmethod
from pathlib import Path
from typing import TYPE_CHECKING
from urllib.parse import urlsplit

from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlmodel import Session

from app.store.models import StoredFile, utcnow

if TYPE_CHECKING:
    from app.config import Settings


class FileStoreError(RuntimeError):
    """The file store cannot be used (unknown bucket, refused credentials, missing boto3): the sentence why."""


def file_key(sha256: str) -> str:
    """Where a file lives inside a store: ``ab/abcdef...`` (the first two hex digits fan the files out)."""
    return f"{sha256[:2]}/{sha256}"


class FileStore(ABC):
    """Files named by their sha256, with a row in ``storedfile``. Subclasses say where the bytes live."""

    def put(self, session: Session, data: bytes, media_type: str) -> str:
        """Store ``data`` (idempotent: the same bytes are written once) and return its sha256."""
        sha = hashlib.sha256(data).hexdigest()
        if not self.exists(sha):
            self._write(sha, data, media_type)
        if session.get(StoredFile, sha) is None:
            # INSERT .. ON CONFLICT DO NOTHING: two workers storing the same bytes at the same moment (the
            # same stage picture of two setups of one photo) both succeed, neither fails on the key
            values = {"sha256": sha, "size_bytes": len(data), "media_type": media_type, "created_at": utcnow()}
            insert = pg_insert if session.get_bind().dialect.name == "postgresql" else sqlite_insert
            session.execute(insert(StoredFile).values(**values).on_conflict_do_nothing(index_elements=["sha256"]))
        return sha

    @abstractmethod
    def read(self, sha256: str) -> bytes:
        """The bytes stored under ``sha256``; FileNotFoundError naming where they were looked for."""

    @abstractmethod
    def exists(self, sha256: str) -> bool:
        """Whether the bytes of ``sha256`` are in the store."""

    @abstractmethod
    def _write(self, sha256: str, data: bytes, media_type: str) -> None:
        """Write ``data`` under ``sha256`` so that a reader never sees half of it."""

    @abstractmethod
    def describe(self) -> str:
        """Where the files are, for logs and error messages (never a credential)."""

    def media_type(self, session: Session, sha256: str) -> str:
        """The media type the file was stored with ("application/octet-stream" when unknown)."""
        row = session.get(StoredFile, sha256)
        return row.media_type if row is not None and row.media_type else "application/octet-stream"


class FolderStore(FileStore):
    """Files in a folder: ``<root>/ab/abcdef...``, each written to a temporary file and renamed."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, sha256: str) -> Path:
        return self.root / file_key(sha256)

    def exists(self, sha256: str) -> bool:
        return self.path(sha256).exists()

    def _write(self, sha256: str, data: bytes, media_type: str) -> None:
        target = self.path(sha256)
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=target.parent)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, target)  # atomic: a reader never sees half a file

    def read(self, sha256: str) -> bytes:
        return self.path(sha256).read_bytes()

    def describe(self) -> str:
        return str(self.root)


class S3Store(FileStore):
    """Files in a bucket of an S3-compatible server: object ``<prefix>/ab/abcdef...``.

    An object appears whole or not at all (S3 semantics), so no temporary name is needed. boto3's client
    is thread-safe: one store serves all the worker threads of a process."""

    def __init__(self, bucket: str, prefix: str = "", *, endpoint_url: str | None = None, region: str | None = None,
                 access_key_id: str | None = None, secret_access_key: str | None = None, client=None):
        self.bucket = bucket
        self.prefix = prefix.strip("/")
        self.endpoint_url = endpoint_url or None
        if client is None:
            try:
                import boto3
                from botocore.config import Config
            except ImportError:
                raise FileStoreError(f"{self.describe()}: the S3 file store needs boto3 "
                                     "(pip install 'setupcam[s3]')") from None
            session = boto3.session.Session(aws_access_key_id=access_key_id or None,
                                            aws_secret_access_key=secret_access_key or None,
                                            region_name=region or None)
            # path-style addressing (server/bucket/key): what MinIO and Ceph expect behind a plain host name
            config = Config(retries={"max_attempts": 5, "mode": "standard"}, connect_timeout=10, read_timeout=60,
                            s3={"addressing_style": "path" if self.endpoint_url else "auto"})
            client = session.client("s3", endpoint_url=self.endpoint_url, config=config)
        self.client = client

    def key(self, sha256: str) -> str:
        return f"{self.prefix}/{file_key(sha256)}" if self.prefix else file_key(sha256)

    def check(self) -> None:
        """FileStoreError with the reason when the bucket cannot be reached (unknown, refused, no server)."""
        from botocore.exceptions import BotoCoreError, ClientError

        try:
            self.client.head_bucket(Bucket=self.bucket)
        except ClientError as exc:
            code = exc.response.get("Error", {}).get("Code", "")
            why = {"404": "no such bucket", "NoSuchBucket": "no such bucket",
                   "403": "access denied (check the credentials)"}.get(code, f"{code}: {exc}")
            raise FileStoreError(f"{self.describe()}: {why}") from None
        except BotoCoreError as exc:
            raise FileStoreError(f"{self.describe()}: {exc}") from None

    def exists(self, sha256: str) -> bool:
        from botocore.exceptions import ClientError

        try:
            self.client.head_object(Bucket=self.bucket, Key=self.key(sha256))
            return True
        except ClientError as exc:
            if exc.response.get("Error", {}).get("Code") in ("404", "NoSuchKey", "NotFound"):
                return False
            raise

    def _write(self, sha256: str, data: bytes, media_type: str) -> None:
        self.client.put_object(Bucket=self.bucket, Key=self.key(sha256), Body=data, ContentType=media_type)

    def read(self, sha256: str) -> bytes:
        from botocore.exceptions import ClientError

        try:
            return self.client.get_object(Bucket=self.bucket, Key=self.key(sha256))["Body"].read()
        except ClientError as exc:
            if exc.response.get("Error", {}).get("Code") in ("404", "NoSuchKey", "NotFound"):
                raise FileNotFoundError(f"{self.describe()}/{file_key(sha256)} does not exist") from None
            raise

    def describe(self) -> str:
        where = f"s3://{self.bucket}/{self.prefix}" if self.prefix else f"s3://{self.bucket}"
        return f"{where} at {self.endpoint_url}" if self.endpoint_url else where


def open_file_store(settings: Settings, *, check: bool = True) -> FileStore:
    """The file store the settings name: ``SETUPCAM_FILE_STORE`` empty (``$SETUPCAM_DATA_DIR/files``) or a
    folder -> :class:`FolderStore`; ``s3://bucket/prefix`` -> :class:`S3Store` with the
    ``SETUPCAM_S3_*`` settings (credentials left empty: boto3's own chain, ``AWS_ACCESS_KEY_ID`` ...).
    ``check``: reach the bucket now, so that a wrong name or credential stops the start with the reason."""
    where = settings.file_store.strip()
    if not where.startswith("s3://"):
        return FolderStore(settings.files_dir)
    url = urlsplit(where)
    if not url.netloc:
        raise FileStoreError(f"SETUPCAM_FILE_STORE={where!r}: name a bucket (s3://bucket/prefix)")
    secret = settings.s3_secret_access_key.get_secret_value() if settings.s3_secret_access_key else None
    store = S3Store(url.netloc, url.path, endpoint_url=settings.s3_endpoint_url, region=settings.s3_region,
                    access_key_id=settings.s3_access_key_id, secret_access_key=secret)
    if check:
        store.check()
    return store
