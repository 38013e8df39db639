"""Migration 0010 (rotary tables): old machines and setups keep working, with no rotary axis and no angle."""

from __future__ import annotations

import numpy as np
import pytest
import sqlalchemy as sa
from sqlmodel import Session

from alembic import command
from app.services.machines import get_machine, table_pose_at
from app.store.db import alembic_config, make_engine, migrate
from tests.support.factories import old_machine_row
from tests.support.live_server import throwaway_database


@pytest.mark.parametrize("backend", ["sqlite", "postgres"])
def test_migration_0010_keeps_old_machines_fixed(tmp_path, backend):
    with throwaway_database(backend, tmp_path) as url:
        cfg = alembic_config(url)
        command.upgrade(cfg, "0009")
        engine = make_engine(url)
        old_machine_row(engine, "[[1,0,0,-450],[0,1,0,-250],[0,0,1,-320],[0,0,0,1]]")
        migrate(engine)
        assert "rotary_axis" in {c["name"] for c in sa.inspect(engine).get_columns("machine")}
        assert {"table_angle_deg", "table_angle_from"} <= {c["name"] for c in sa.inspect(engine).get_columns("setup")}
        with Session(engine) as s:
            m = get_machine(s, 1)
            assert m.rotary_axis is None
            # the fixed pose at any angle: the table does not turn
            assert np.allclose(table_pose_at(m, 37.0), m.T_machine_table) and table_pose_at(m)[0, 3] == -450
        engine.dispose()
        command.downgrade(cfg, "0009")
        engine = make_engine(url)
        assert "rotary_axis" not in {c["name"] for c in sa.inspect(engine).get_columns("machine")}
        assert "table_angle_deg" not in {c["name"] for c in sa.inspect(engine).get_columns("setup")}
        engine.dispose()
