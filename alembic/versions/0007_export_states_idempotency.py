"""export states (pending, writing, written, failed, unknown) and an idempotency key per export

Revision ID: 0007
Revises: 0006
"""
from alembic import op
import sqlalchemy as sa


revision = '0007'
down_revision = '0006'
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table('export', schema=None) as batch_op:
        batch_op.add_column(sa.Column('idempotency_key', sa.String(length=100), nullable=True))
        batch_op.create_unique_constraint('uq_export_idempotency_key', ['idempotency_key'])
    # the old names of the two ends: verified is written, mismatch is failed (the read-back differed)
    op.execute("UPDATE export SET status = 'written' WHERE status = 'verified'")
    op.execute("UPDATE export SET status = 'failed' WHERE status = 'mismatch'")


def downgrade() -> None:
    op.execute("UPDATE export SET status = 'verified' WHERE status = 'written'")
    with op.batch_alter_table('export', schema=None) as batch_op:
        batch_op.drop_constraint('uq_export_idempotency_key', type_='unique')
        batch_op.drop_column('idempotency_key')
