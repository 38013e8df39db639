"""The file store's rows when two workers store the same bytes at the same moment (the same stage
picture of two setups of one photo): both succeed, one row, on SQLite and PostgreSQL."""

from __future__ import annotations

import contextlib
import threading

import pytest
from sqlmodel import Session, select

from app.store.db import make_engine, migrate
from app.store.files import FolderStore
from app.store.models import StoredFile
from tests.support.live_server import postgres_database, postgres_unavailable_reason


@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_two_sessions_store_the_same_bytes_at_once(tmp_path, backend):
    with contextlib.ExitStack() as stack:
        if backend == "postgres":
            why = postgres_unavailable_reason()
            if why:
                pytest.skip(why)
            url = stack.enter_context(postgres_database())
        else:
            url = f"sqlite:///{tmp_path / 'db.sqlite'}"
        engine = make_engine(url)
        stack.callback(engine.dispose)
        migrate(engine)
        files = FolderStore(tmp_path / "files")
        first, second = Session(engine), Session(engine)
        errors: list[BaseException] = []
        sha = files.put(first, b"the same stage picture", "image/png")  # inserted, not yet committed

        def other() -> None:
            try:  # waits for the first transaction's row (PostgreSQL) or the database lock (SQLite)
                files.put(second, b"the same stage picture", "image/png")
                second.commit()
            except BaseException as exc:  # noqa: BLE001 - reported below
                errors.append(exc)

        t = threading.Thread(target=other)
        t.start()
        t.join(0.5)
        first.commit()
        t.join(30)
        assert not t.is_alive() and not errors, errors
        with Session(engine) as session:
            assert [r.sha256 for r in session.exec(select(StoredFile)).all()] == [sha]
        first.close()
        second.close()
