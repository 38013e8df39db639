"""model revision guide: what carries a fixture and how it moves there (a vise's moving jaw on its body)

Revision ID: 0013
Revises: 0012
"""
import sqlalchemy as sa

from alembic import op

revision = '0013'
down_revision = '0012'
branch_labels = None
depends_on = None


# plain ALTER TABLE (SQLite >= 3.35 and PostgreSQL both add and drop columns in place), as 0011: a
# batch rebuild of model_revision would have to drop a table that setups and machines refer to


def upgrade() -> None:
    # every existing model stands free (null)
    op.add_column('model_revision', sa.Column('guide', sa.JSON(), nullable=True))


def downgrade() -> None:
    op.drop_column('model_revision', 'guide')
