"""one running sheet monitor per camera: sheet_monitor.camera_id (the alignment's camera) and a unique
index on it over the running monitors; of several already running on one camera the newest keeps running

Revision ID: 0012
Revises: 0011
"""
import sqlalchemy as sa

from alembic import op

revision = '0012'
down_revision = '0011'
branch_labels = None
depends_on = None

RUNNING = sa.text("state = 'running'")


def upgrade() -> None:
    with op.batch_alter_table('sheet_monitor', schema=None) as batch_op:
        # a plain ADD COLUMN (no foreign key: on SQLite that would rebuild the table under its events)
        batch_op.add_column(sa.Column('camera_id', sa.Integer(), nullable=True))
    op.execute("UPDATE sheet_monitor SET camera_id = (SELECT a.camera_id FROM sheet_alignment a "
               "WHERE a.id = sheet_monitor.alignment_id)")
    op.execute("UPDATE sheet_monitor SET state = 'finished', "
               "reason = 'ended by the upgrade to one monitor per camera: a newer monitor watches camera ' "
               "|| camera_id WHERE state = 'running' AND id < (SELECT max(m.id) FROM sheet_monitor m "
               "WHERE m.state = 'running' AND m.camera_id = sheet_monitor.camera_id)")
    op.create_index('uq_sheet_monitor_running_camera', 'sheet_monitor', ['camera_id'], unique=True,
                    sqlite_where=RUNNING, postgresql_where=RUNNING)


def downgrade() -> None:
    op.drop_index('uq_sheet_monitor_running_camera', table_name='sheet_monitor')
    with op.batch_alter_table('sheet_monitor', schema=None) as batch_op:
        batch_op.drop_column('camera_id')
