"""Content-addressed file storage: bytes are stored once under ``files/ab/abcdef...`` by sha256."""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlmodel import Session

from app.store.models import StoredFile, utcnow


class FileStore:
    """Files on disk (or shared storage) named by their sha256; rows in ``storedfile``."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def path(self, sha256: str) -> Path:
        return self.root / sha256[:2] / sha256

    def put(self, session: Session, data: bytes, media_type: str) -> str:
        """Store ``data`` (idempotent) and return its sha256."""
        sha = hashlib.sha256(data).hexdigest()
        target = self.path(sha)
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=target.parent)
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            os.replace(tmp, target)  # atomic: a reader never sees half a file
        if session.get(StoredFile, sha) is None:
            # INSERT .. ON CONFLICT DO NOTHING: two workers storing the same bytes at the same moment (the
            # same stage picture of two setups of one photo) both succeed, neither fails on the key
            values = {"sha256": sha, "size_bytes": len(data), "media_type": media_type, "created_at": utcnow()}
            insert = pg_insert if session.get_bind().dialect.name == "postgresql" else sqlite_insert
            session.execute(insert(StoredFile).values(**values).on_conflict_do_nothing(index_elements=["sha256"]))
        return sha

    def read(self, sha256: str) -> bytes:
        return self.path(sha256).read_bytes()

    def media_type(self, session: Session, sha256: str) -> str:
        """The media type the file was stored with ("application/octet-stream" when unknown)."""
        row = session.get(StoredFile, sha256)
        return row.media_type if row is not None and row.media_type else "application/octet-stream"
