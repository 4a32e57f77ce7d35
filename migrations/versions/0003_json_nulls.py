"""Store absent tasks and representations as SQL NULL, not JSON 'null'.

Revision ID: 0003
Revises: 0002
"""

from __future__ import annotations

from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    as_text = "CAST({} AS TEXT)" if op.get_bind().dialect.name == "postgresql" else "{}"
    for column in ("task", "representation"):
        op.execute(f"UPDATE studies SET {column} = NULL WHERE {as_text.format(column)} = 'null'")


def downgrade() -> None:
    pass  # SQL NULL reads back as None either way
