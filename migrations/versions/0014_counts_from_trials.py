"""Issue 40 (one server on PostgreSQL keeps 32 workers fed): a study's complete, failed
and pruned counts are those of its trials' states, read from the trials table, no
longer counters on the study row that every tell updated (and locked).

Revision ID: 0014
Revises: 0013
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0014"
down_revision = "0013"
branch_labels = None
depends_on = None

COUNTERS = {"n_complete": "complete", "n_failed": "failed", "n_pruned": "pruned"}
KEEP_IDS = {"sqlite_autoincrement": True}
"""SQLite drops a column by copying the table: the copy keeps AUTOINCREMENT only when
told, else a deleted newest study's id is given again."""


def upgrade() -> None:
    with op.batch_alter_table("studies", table_kwargs=KEEP_IDS) as batch:
        for column in COUNTERS:
            batch.drop_column(column)


def downgrade() -> None:
    with op.batch_alter_table("studies", table_kwargs=KEEP_IDS) as batch:
        for column in COUNTERS:
            batch.add_column(
                sa.Column(column, sa.Integer(), nullable=False, server_default=sa.text("0"))
            )
    for column, state in COUNTERS.items():
        op.execute(
            sa.text(
                f"UPDATE studies SET {column} = (SELECT count(*) FROM trials"
                " WHERE trials.study_id = studies.id AND trials.state = :state)"
            ).bindparams(state=state)
        )
