"""A real setupcam service on 127.0.0.1 for tests: uvicorn in a thread, its own data folder and database.

Databases: ``sqlite`` (a file in the data folder) or ``postgres`` (a fresh database created on the
PostgreSQL at 127.0.0.1:5432 and dropped afterwards).
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import uvicorn

from app.config import Settings
from app.main import create_app

PG_ADMIN_DSN = os.environ.get("SETUPCAM_TEST_PG", "host=127.0.0.1 port=5432 dbname=test user=postgres")


def free_port() -> int:
    return free_ports(1)[0]


def free_ports(n: int) -> list[int]:
    """``n`` distinct free ports, e.g. a service's and its viewer's: the sockets are held until all are chosen,
    as two calls of ``free_port`` may return the same port, and the service then cannot bind its own."""
    with contextlib.ExitStack() as stack:
        socks = [stack.enter_context(socket.socket()) for _ in range(n)]
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]


def listening_socket() -> socket.socket:
    """A socket listening on a free port of 127.0.0.1, for uvicorn to serve on: nothing else can take the
    port between choosing it and serving on it. ``free_port`` closes its socket, so another worker, or this
    service's own viewer (it binds during start-up, before uvicorn would), could; and a socket that is
    bound but not yet listening does not stop another binding with SO_REUSEADDR on Linux."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(128)
    return sock


class ServerStartError(RuntimeError):
    """The test server stopped before it served; the message holds what it logged and raised."""


class _Records(logging.Handler):
    """Keeps what uvicorn and the service log while a server starts, for the error message."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.setFormatter(logging.Formatter("%(name)s %(levelname)s: %(message)s"))
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(self.format(record))


def postgres_unavailable_reason() -> str | None:
    """None when PostgreSQL answers, else the reason (for a visible skip message)."""
    try:
        import psycopg

        with psycopg.connect(PG_ADMIN_DSN, connect_timeout=3):
            return None
    except Exception as exc:  # noqa: BLE001
        return f"PostgreSQL not reachable at 127.0.0.1:5432 ({exc.__class__.__name__}: {exc}); postgres tests skipped"


@contextlib.contextmanager
def postgres_database() -> Iterator[str]:
    """Create a throw-away database and yield its SQLAlchemy URL."""
    import psycopg

    name = f"setupcam_test_{uuid.uuid4().hex[:10]}"
    with psycopg.connect(PG_ADMIN_DSN, autocommit=True) as conn:
        conn.execute(f'CREATE DATABASE "{name}"')
    try:
        yield f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}"
    finally:
        with psycopg.connect(PG_ADMIN_DSN, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@contextlib.contextmanager
def throwaway_database(backend: str, folder: Path) -> Iterator[str]:
    """The SQLAlchemy URL of an empty database: a SQLite file in ``folder``, or a fresh PostgreSQL database
    (the calling test is skipped, with the reason, when PostgreSQL does not answer)."""
    if backend == "postgres":
        reason = postgres_unavailable_reason()
        if reason:
            pytest.skip(reason)
        with postgres_database() as url:
            yield url
    else:
        yield f"sqlite:///{folder / 'migrations.db'}"


class LiveServer:
    def __init__(self, settings: Settings):
        self.settings = settings
        self.sock = listening_socket()
        self.port = self.sock.getsockname()[1]
        self.url = f"http://127.0.0.1:{self.port}"
        self.app = create_app(settings)
        config = uvicorn.Config(self.app, host="127.0.0.1", port=self.port, log_level="warning", lifespan="on")
        self.server = uvicorn.Server(config)
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        try:
            self.server.run(sockets=[self.sock])
        except BaseException as exc:  # noqa: BLE001 - SystemExit too: uvicorn exits when it cannot serve
            self.error = exc

    def start(self, timeout_s: float = 120.0) -> "LiveServer":
        records = _Records()
        loggers = [logging.getLogger(name) for name in ("uvicorn.error", "setupcam", "app")]
        for logger in loggers:
            logger.addHandler(records)
        try:
            self.thread.start()
            deadline = time.monotonic() + timeout_s
            while not self.server.started:
                if not self.thread.is_alive():
                    self.sock.close()
                    raise ServerStartError(f"test server on port {self.port} (viser {self.settings.viser_port}) "
                                           f"stopped during start-up: {self.error!r}; the end of its log:\n"
                                           + "\n".join(records.lines or ["(nothing)"])[-3000:])
                if time.monotonic() > deadline:
                    raise ServerStartError(f"test server did not start within {timeout_s} s")
                time.sleep(0.05)
        finally:
            for logger in loggers:
                logger.removeHandler(records)
        return self

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=15)

    def make_principals(self) -> None:
        """Test accounts: users test-admin / test-operator (password = name + '-pw') and two API keys."""
        from app.services.access import create_api_key, create_user
        from app.store.db import session_scope

        self.tokens: dict[str, str] = {}
        with session_scope(self.app.state.engine) as session:
            for role in ("admin", "operator"):
                create_user(session, f"test-{role}", role, f"test-{role}-pw")
            self.tokens["mes"] = create_api_key(session, "test mes", "mes")[1]
            self.tokens["admin-key"] = create_api_key(session, "test admin key", "admin")[1]
        for role in ("admin", "operator"):
            r = httpx.post(f"{self.url}/api/v1/auth/login", json={"name": f"test-{role}", "password": f"test-{role}-pw"})
            r.raise_for_status()
            self.tokens[role] = r.json()["token"]

    def client(self, as_: str | None = "admin", **kw) -> httpx.Client:
        """An HTTP client signed in as 'admin', 'operator' (users), 'mes', 'admin-key' (API keys) or None."""
        headers = kw.pop("headers", {})
        if as_ is not None:
            headers["Authorization"] = f"Bearer {self.tokens[as_]}"
        return httpx.Client(base_url=self.url, timeout=120, headers=headers, **kw)


@contextlib.contextmanager
def live_server(data_dir: Path, backend: str = "sqlite", **settings_kw) -> Iterator[LiveServer]:
    with contextlib.ExitStack() as stack:
        env = {"SETUPCAM_DATA_DIR": str(data_dir)}
        if backend == "postgres":
            env["DATABASE_URL"] = stack.enter_context(postgres_database())
        settings_kw.setdefault("viser_port", free_port())  # never the default 8081 of a running service
        settings = Settings(**env, **settings_kw)
        server = LiveServer(settings).start()
        stack.callback(server.stop)
        server.make_principals()
        yield server
