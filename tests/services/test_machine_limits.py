"""Per-machine limits on a real database: migration 0008 (SQLite and PostgreSQL when it answers) keeps
every existing machine on the global settings, and which limit is in force, with its source in words."""

from __future__ import annotations

import pytest
import sqlalchemy as sa
from sqlmodel import Session

from alembic import command
from app.config import Settings
from app.services.errors import Invalid
from app.services.machines import get_machine, machine_limit, validate_limit
from app.store.db import alembic_config, make_engine, migrate
from app.store.models import Machine
from tests.support.factories import old_machine_row
from tests.support.live_server import throwaway_database

LIMITS = ("max_tilt_deg", "max_offset_change_mm", "max_offset_change_deg")


@pytest.mark.parametrize("backend", ["sqlite", "postgres"])
def test_migration_0008_adds_the_limits_as_null_and_keeps_the_machines(tmp_path, backend):
    """A database at 0007 with a machine: upgrading adds the three columns, NULL for it (so the global
    settings stay in force); a limit can then be stored; downgrading drops them, the machine stays."""
    with throwaway_database(backend, tmp_path) as url:
        cfg = alembic_config(url)
        command.upgrade(cfg, "0007")
        engine = make_engine(url)
        old_machine_row(engine)
        migrate(engine)
        assert set(LIMITS) <= {c["name"] for c in sa.inspect(engine).get_columns("machine")}
        settings = Settings(SETUPCAM_DATA_DIR=str(tmp_path), SETUPCAM_MAX_TILT_DEG=0.3)
        with Session(engine) as s:
            m = get_machine(s, 1)
            assert [getattr(m, k) for k in LIMITS] == [None, None, None] and m.travel_mm == {"x": [0, 1]}
            assert machine_limit(m, settings, "max_tilt_deg").value == 0.3
            m.max_offset_change_mm = 0.75
            s.add(m)
            s.commit()
        with Session(engine) as s:
            assert get_machine(s, 1).max_offset_change_mm == 0.75
        engine.dispose()
        command.downgrade(cfg, "0007")
        engine = make_engine(url)
        assert not set(LIMITS) & {c["name"] for c in sa.inspect(engine).get_columns("machine")}
        with engine.connect() as conn:
            assert conn.execute(sa.text("SELECT name FROM machine")).scalars().all() == ["Mill 1"]
        engine.dispose()


def test_the_machine_limit_wins_and_each_source_is_named(tmp_path):
    settings = Settings(SETUPCAM_DATA_DIR=str(tmp_path), SETUPCAM_MAX_OFFSET_CHANGE_MM=4.0)
    m = Machine(name="Mill 2", table_model_id=1, table_revision=1, T_machine_table=[], travel_mm={},
                max_tilt_deg=0.0, max_offset_change_deg=0.5)
    tilt, mm, deg = (machine_limit(m, settings, k) for k in LIMITS)
    assert (tilt.value, tilt.source) == (0.0, "machine 'Mill 2'")   # 0 is a limit, not "unset"
    assert (mm.value, mm.source) == (4.0, "the global setting SETUPCAM_MAX_OFFSET_CHANGE_MM")
    assert (deg.value, deg.source) == (0.5, "machine 'Mill 2'")


@pytest.mark.parametrize("name, value", [("max_tilt_deg", float("nan")), ("max_tilt_deg", 10.5),
                                         ("max_offset_change_mm", 0.0), ("max_offset_change_deg", float("inf")),
                                         ("max_offset_change_deg", "two")])
def test_limits_given_past_the_api_are_checked_too(name, value):
    with pytest.raises(Invalid, match=f"{name}: must be a number"):
        validate_limit(name, value)
    assert validate_limit(name, None) is None
