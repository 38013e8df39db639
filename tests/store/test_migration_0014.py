"""Migration 0014 (where a setup's long stage stands): a nullable JSON column on the setup (old setups
have none), and the downgrade drops it again (SQLite and PostgreSQL). Its values are written and read by
a running setup in tests/e2e/test_setup_page.py::test_recognition_shows_how_far_it_is_while_it_runs."""

from __future__ import annotations

import pytest
import sqlalchemy as sa

from alembic import command
from app.store.db import alembic_config, make_engine, migrate
from tests.support.live_server import throwaway_database


@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_migration_0014_adds_a_setups_progress_and_drops_it_again(tmp_path, backend):
    with throwaway_database(backend, tmp_path) as url:
        cfg = alembic_config(url)
        command.upgrade(cfg, "0013")
        engine = make_engine(url)
        assert "progress" not in {c["name"] for c in sa.inspect(engine).get_columns("setup")}
        migrate(engine)
        column = {c["name"]: c for c in sa.inspect(engine).get_columns("setup")}["progress"]
        assert column["nullable"] and isinstance(column["type"], sa.JSON), column
        engine.dispose()
        command.downgrade(cfg, "0013")
        engine = make_engine(url)
        assert "progress" not in {c["name"] for c in sa.inspect(engine).get_columns("setup")}
        engine.dispose()
