"""Migration 0013 (a fixture's guide on its model revision): old revisions stand free (null), a guide
is stored and read back as JSON, and the downgrade drops the column again (SQLite and PostgreSQL)."""

from __future__ import annotations

import pytest
import sqlalchemy as sa
from sqlmodel import Session

from alembic import command
from app.services.library import get_revision
from app.store.db import alembic_config, make_engine, migrate
from app.store.models import ModelRevision
from tests.support.live_server import throwaway_database

NOW = "CURRENT_TIMESTAMP"
GUIDE = {"carrier": "vise body", "T_carrier_obj": [[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 70.0], [0, 0, 0, 1.0]],
         "axis": [1.0, 0.0, 0.0], "travel_mm": [-95.0, 100.0]}


def _old_revision(conn) -> None:
    """At 0012: a clamp with one revision (no guide column yet; its id from the sequence, so that
    PostgreSQL numbers the next one on)."""
    sha = "a" * 64
    conn.execute(sa.text(f"INSERT INTO storedfile (sha256, size_bytes, media_type, created_at) "
                         f"VALUES ('{sha}', 1, 'model/gltf-binary', {NOW})"))
    conn.execute(sa.text(f"INSERT INTO library_model (id, kind, name, description, current_revision, created_at) "
                         f"VALUES (1, 'clamp', 'moving jaw', '', 1, {NOW})"))
    conn.execute(sa.text(f"INSERT INTO model_revision (model_id, revision, source_filename, source_sha256, "
                         f"glb_sha256, thumbnail_sha256, units, summary, resting_poses, note, created_at) VALUES "
                         f"(1, 1, 'jaw.stl', '{sha}', '{sha}', '{sha}', 'mm', '{{}}', '[]', '', {NOW})"))


@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_migration_0013_adds_the_guide_and_drops_it_again(tmp_path, backend):
    with throwaway_database(backend, tmp_path) as url:
        cfg = alembic_config(url)
        command.upgrade(cfg, "0012")
        engine = make_engine(url)
        with engine.begin() as conn:
            _old_revision(conn)
        migrate(engine)
        assert "guide" in {c["name"] for c in sa.inspect(engine).get_columns("model_revision")}
        with Session(engine) as s:
            old = get_revision(s, 1)
            assert old.guide is None and old.source_filename == "jaw.stl"      # old revisions stand free
            s.add(ModelRevision(**{**old.model_dump(exclude={"id"}), "revision": 2, "guide": GUIDE}))
            s.commit()
        with Session(engine) as s:
            assert get_revision(s, 1, 2).guide == GUIDE
        engine.dispose()
        command.downgrade(cfg, "0012")
        engine = make_engine(url)
        assert "guide" not in {c["name"] for c in sa.inspect(engine).get_columns("model_revision")}
        with engine.connect() as conn:                      # the rows stay, without their guides
            assert conn.execute(sa.text("SELECT count(*) FROM model_revision")).scalar() == 2
        engine.dispose()
