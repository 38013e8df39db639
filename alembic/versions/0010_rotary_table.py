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
    with op.batch_alter_table('setup', schema=None) as batch_op:
        batch_op.drop_column('table_angle_from')
        batch_op.drop_column('table_angle_deg')
    with op.batch_alter_table('machine', schema=None) as batch_op:
        batch_op.drop_column('rotary_axis')
