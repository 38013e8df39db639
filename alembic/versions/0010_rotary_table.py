"""rotary tables in the kinematic chain: a machine's rotary axis; a setup's table angle at the picture

Revision ID: 0010
Revises: 0009
"""
import sqlalchemy as sa

from alembic import op

revision = '0010'
down_revision = '0009'
branch_labels = None
depends_on = None


def upgrade() -> None:
    # nullable with no default: every existing machine keeps its fixed table, every setup has no angle
    with op.batch_alter_table('machine', schema=None) as batch_op:
        batch_op.add_column(sa.Column('rotary_axis', sa.JSON(), nullable=True))
    with op.batch_alter_table('setup', schema=None) as batch_op:
        batch_op.add_column(sa.Column('table_angle_deg', sa.Float(), nullable=True))
        batch_op.add_column(sa.Column('table_angle_from', sa.String(length=20), nullable=True))


def downgrade() -> None:
    # plain ALTER TABLE ... DROP COLUMN (SQLite >= 3.35): a batch copy would drop and re-create the
    # machine table, which the foreign keys of existing setups and monitors forbid
    op.drop_column('setup', 'table_angle_from')
    op.drop_column('setup', 'table_angle_deg')
    op.drop_column('machine', 'rotary_axis')
