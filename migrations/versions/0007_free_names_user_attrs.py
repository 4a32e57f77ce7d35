"""Study data (issue 16): free-text study names of up to 200 characters, user attributes
of studies and trials, and ids SQLite never gives again once studies can be deleted.

Revision ID: 0007
Revises: 0006
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None

EMPTY = sa.text("'{}'")


def _recreate() -> str:
    """SQLite adds AUTOINCREMENT only by copying a table; PostgreSQL's sequences never
    reuse ids, so there the columns are altered in place."""
    return "always" if op.get_bind().dialect.name == "sqlite" else "auto"


def upgrade() -> None:
    autoincrement = {"sqlite_autoincrement": True}
    with op.batch_alter_table("studies", recreate=_recreate(), table_kwargs=autoincrement) as batch:
        batch.alter_column("name", existing_type=sa.String(128), type_=sa.String(200))
        batch.add_column(sa.Column("user_attrs", sa.JSON(), nullable=False, server_default=EMPTY))
    with op.batch_alter_table("trials", recreate=_recreate(), table_kwargs=autoincrement) as batch:
        batch.add_column(sa.Column("user_attrs", sa.JSON(), nullable=False, server_default=EMPTY))


def downgrade() -> None:
    # A longer name does not fit the old column: keep its first 128 characters.
    op.execute("UPDATE studies SET name = substr(name, 1, 128) WHERE length(name) > 128")
    with op.batch_alter_table("trials", recreate=_recreate()) as batch:
        batch.drop_column("user_attrs")
    with op.batch_alter_table("studies", recreate=_recreate()) as batch:
        batch.drop_column("user_attrs")
        batch.alter_column("name", existing_type=sa.String(200), type_=sa.String(128))
