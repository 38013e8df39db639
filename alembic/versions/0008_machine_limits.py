"""per-machine limits: max tilt and the offset change that needs no acknowledgement (NULL: the global setting)

Revision ID: 0008
Revises: 0007
"""
from alembic import op
import sqlalchemy as sa


revision = '0008'
down_revision = '0007'
branch_labels = None
depends_on = None

COLUMNS = ('max_tilt_deg', 'max_offset_change_mm', 'max_offset_change_deg')


def upgrade() -> None:
    # nullable with no default: every existing machine keeps using the global settings
    with op.batch_alter_table('machine', schema=None) as batch_op:
        for name in COLUMNS:
            batch_op.add_column(sa.Column(name, sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table('machine', schema=None) as batch_op:
        for name in reversed(COLUMNS):
            batch_op.drop_column(name)
