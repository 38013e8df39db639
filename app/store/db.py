"""Engine, sessions and migrations. The only place that knows the database URL."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from alembic import command
from alembic.config import Config
from sqlalchemy import event
from sqlalchemy.engine import Engine
from sqlmodel import Session, create_engine

from app.resources import bundled_dir


def make_engine(database_url: str) -> Engine:
    """Create the engine; SQLite gets WAL and foreign keys, and may be used from worker threads."""
    if database_url.startswith("sqlite"):
        path = database_url.split("///", 1)[-1]
        if path and path != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
        engine = create_engine(database_url, connect_args={"check_same_thread": False, "timeout": 30})

        @event.listens_for(engine, "connect")
        def _sqlite_pragmas(dbapi_conn, _record):  # pragma: no cover - trivial
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.close()

        return engine
    if database_url.startswith("postgresql://"):
        database_url = "postgresql+psycopg://" + database_url[len("postgresql://"):]
    return create_engine(database_url, pool_pre_ping=True)


def alembic_config(database_url: str) -> Config:
    cfg = Config()
    cfg.set_main_option("script_location", str(bundled_dir("alembic")))
    cfg.set_main_option("sqlalchemy.url", database_url.replace("%", "%%"))
    return cfg


def migrate(engine: Engine) -> None:
    """Bring the schema to the newest revision (``alembic upgrade head``) on this engine."""
    cfg = alembic_config(str(engine.url.render_as_string(hide_password=False)))
    with engine.begin() as conn:
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "head")


@contextmanager
def session_scope(engine: Engine) -> Iterator[Session]:
    """A session that commits on success and rolls back on error (for services and workers)."""
    with Session(engine, expire_on_commit=False) as session:
        try:
            yield session
            session.commit()
        except Exception:
            session.rollback()
            raise


def protect_data(data_dir: Path, database_url: str, files_dir: Path | None = None) -> None:
    """Only the service's user may read what it keeps: data folder and the file store's folder
    (``files_dir``, default ``data_dir/files``) 0700, the SQLite file with its WAL/SHM companions 0600.
    Applied at every start, so an older install is fixed. (A bucket's access is its key's.)"""
    import os
    import stat

    for folder in (Path(data_dir), Path(files_dir) if files_dir else Path(data_dir) / "files"):
        if folder.is_dir():
            os.chmod(folder, stat.S_IRWXU)
    if database_url.startswith("sqlite"):
        path = database_url.split("///", 1)[-1]
        if path and path != ":memory:":
            for suffix in ("", "-wal", "-shm", "-journal"):
                f = Path(path + suffix)
                if f.exists():
                    os.chmod(f, stat.S_IRUSR | stat.S_IWUSR)
