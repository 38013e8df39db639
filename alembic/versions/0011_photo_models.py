"""photo models: a library model's source (cad | photo) and a revision's photo template (issue 16)

Revision ID: 0011
Revises: 0010
"""
import sqlalchemy as sa

from alembic import op

revision = '0011'
down_revision = '0010'
branch_labels = None
depends_on = None


# plain ALTER TABLE (SQLite >= 3.35 and PostgreSQL both add and drop columns in place): a batch
# rebuild of library_model would have to drop a table that model_revision and machine refer to


def upgrade() -> None:
    # every existing model came from a CAD file
    op.add_column('library_model', sa.Column('source', sa.String(length=20), nullable=False, server_default='cad'))
    op.add_column('model_revision', sa.Column('photo', sa.JSON(), nullable=True))


def downgrade() -> None:
    op.drop_column('model_revision', 'photo')
    op.drop_column('library_model', 'source')
