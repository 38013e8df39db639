"""Migration 0012 (one running sheet monitor per camera) on a database that already has two monitors
running on one camera: the newest keeps running, the older ends with the reason; from then on the
database itself refuses a second running monitor on a camera (SQLite and PostgreSQL when it answers)."""

from __future__ import annotations

import pytest
import sqlalchemy as sa

from alembic import command
from app.store.db import alembic_config, make_engine, migrate
from tests.support.live_server import throwaway_database

NOW = "CURRENT_TIMESTAMP"


def _old_database(conn) -> None:
    """At 0009: a camera, a machine, two confirmed alignments on the camera, a running monitor on each."""
    def run(sql: str) -> None:
        conn.execute(sa.text(sql))

    run(f"INSERT INTO storedfile (sha256, size_bytes, media_type, created_at) VALUES ('{'a' * 64}', 1, 'image/jpeg', {NOW})")
    run(f"INSERT INTO camera (id, name, intrinsics, source, created_at) VALUES (7, 'bed cam', NULL, "
        f"'{{\"kind\": \"upload\"}}', {NOW})")
    run(f"INSERT INTO library_model (id, kind, name, description, current_revision, created_at) "
        f"VALUES (1, 'table', 'bed', '', 1, {NOW})")
    run(f"INSERT INTO machine (id, name, table_model_id, table_revision, \"T_machine_table\", travel_mm, camera_ids, "
        f"created_at) VALUES (1, 'laser', 1, 1, '[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]', '{{}}', '[7]', {NOW})")
    for aid in (1, 2):
        run(f"INSERT INTO sheet_alignment (id, machine_id, camera_id, intrinsics, \"T_cam_bed\", thickness_mm, margin_mm, "
            f"image_sha256, origin, status, reason, confirmed_by, confirmed_at, created_at) VALUES ({aid}, 1, 7, '{{}}', "
            f"'[]', 3.0, 0.0, '{'a' * 64}', 'upload', 'located', '', 'op', {NOW}, {NOW})")
        run(f"INSERT INTO sheet_monitor (id, alignment_id, l1_mm, l2_mm, slot, roi_px, state, reason, frames, "
            f"created_at, updated_at) VALUES ({10 + aid}, {aid}, 1.0, 4.0, 'G54', 100, 'running', '', 0, {NOW}, {NOW})")


@pytest.mark.parametrize("backend", ["sqlite", pytest.param("postgres", marks=pytest.mark.postgres)])
def test_migration_0012_keeps_the_newest_monitor_of_a_camera_running(tmp_path, backend):
    with throwaway_database(backend, tmp_path) as url:
        cfg = alembic_config(url)
        command.upgrade(cfg, "0009")
        engine = make_engine(url)
        with engine.begin() as conn:
            _old_database(conn)
        migrate(engine)
        with engine.connect() as conn:
            rows = conn.execute(sa.text("SELECT id, camera_id, state, reason FROM sheet_monitor ORDER BY id")).all()
        assert [(r.id, r.camera_id, r.state) for r in rows] == [(11, 7, "finished"), (12, 7, "running")]
        assert rows[0].reason == "ended by the upgrade to one monitor per camera: a newer monitor watches camera 7"
        with pytest.raises(sa.exc.IntegrityError), engine.begin() as conn:
            conn.execute(sa.text(f"INSERT INTO sheet_monitor (alignment_id, camera_id, l1_mm, l2_mm, slot, roi_px, "
                                 f"state, reason, frames, created_at, updated_at) VALUES (1, 7, 1.0, 4.0, 'G54', 100, "
                                 f"'running', '', 0, {NOW}, {NOW})"))
        with engine.begin() as conn:  # a finished one more on the camera is fine
            conn.execute(sa.text(f"INSERT INTO sheet_monitor (alignment_id, camera_id, l1_mm, l2_mm, slot, roi_px, "
                                 f"state, reason, frames, created_at, updated_at) VALUES (1, 7, 1.0, 4.0, 'G54', 100, "
                                 f"'finished', '', 0, {NOW}, {NOW})"))
        engine.dispose()
        command.downgrade(cfg, "0009")
        engine = make_engine(url)
        assert "camera_id" not in {c["name"] for c in sa.inspect(engine).get_columns("sheet_monitor")}
        engine.dispose()
