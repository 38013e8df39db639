"""setup progress: where a long stage (recognition over the library) stands while it runs

Revision ID: 0014
Revises: 0013
"""
import sqlalchemy as sa

from alembic import op

revision = '0014'
down_revision = '0013'
branch_labels = None
depends_on = None


# plain ALTER TABLE, as 0013 (SQLite >= 3.35 and PostgreSQL add and drop columns in place)


def upgrade() -> None:
    # no setup is running across an upgrade that matters here: null is "no stage in progress"
    op.add_column('setup', sa.Column('progress', sa.JSON(), nullable=True))


def downgrade() -> None:
    op.drop_column('setup', 'progress')
