"""jobs: one table for all long work; on PostgreSQL also Procrastinate's schema (the queue that delivers them);
a sheet monitor's drift state (it resumes after a restart)

Revision ID: 0009
Revises: 0008
"""
from alembic import op
import sqlalchemy as sa
import sqlmodel


revision = '0009'
down_revision = '0008'
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        'job',
        sa.Column('id', sa.Integer(), primary_key=True),
        sa.Column('kind', sa.String(length=40), nullable=False),
        sa.Column('args', sa.JSON(), nullable=False),
        sa.Column('status', sa.String(length=20), nullable=False),
        sa.Column('reason', sa.String(length=2000), nullable=False),
        sa.Column('result', sa.JSON(), nullable=True),
        sa.Column('attempts', sa.Integer(), nullable=False),
        sa.Column('max_attempts', sa.Integer(), nullable=False),
        sa.Column('timeout_s', sa.Float(), nullable=False),
        sa.Column('worker', sa.String(length=200), nullable=True),
        sa.Column('heartbeat_at', sqlmodel.sql.sqltypes.UTCDateTime(), nullable=True),
        sa.Column('started_at', sqlmodel.sql.sqltypes.UTCDateTime(), nullable=True),
        sa.Column('finished_at', sqlmodel.sql.sqltypes.UTCDateTime(), nullable=True),
        sa.Column('created_by', sa.String(length=200), nullable=True),
        sa.Column('created_at', sqlmodel.sql.sqltypes.UTCDateTime(), nullable=False),
        sa.Column('updated_at', sqlmodel.sql.sqltypes.UTCDateTime(), nullable=False),
    )
    op.create_index('ix_job_kind', 'job', ['kind'])
    op.create_index('ix_job_status', 'job', ['status'])
    with op.batch_alter_table('sheet_monitor', schema=None) as batch_op:
        batch_op.add_column(sa.Column('drift_state', sa.JSON(), nullable=True))
    bind = op.get_bind()
    if bind.dialect.name == 'postgresql':
        from procrastinate.schema import SchemaManager

        exists = bind.exec_driver_sql("SELECT to_regclass('procrastinate_jobs')").scalar()
        if exists is None:
            # the raw cursor without parameters: the schema is many statements, with % in its messages
            bind.connection.dbapi_connection.cursor().execute(SchemaManager.get_schema())


def downgrade() -> None:
    with op.batch_alter_table('sheet_monitor', schema=None) as batch_op:
        batch_op.drop_column('drift_state')
    op.drop_index('ix_job_status', table_name='job')
    op.drop_index('ix_job_kind', table_name='job')
    op.drop_table('job')
