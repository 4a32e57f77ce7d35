"""Issue 37 (a fall back is never silent): how many of a study's candidates were Sobol
points forced by a budget or a failed model, and why its latest ask fell back.

Revision ID: 0010
Revises: 0009
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0010"
down_revision = "0009"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("studies") as batch:
        batch.add_column(
            sa.Column("proposal_fallbacks", sa.Integer(), nullable=False, server_default="0")
        )
        batch.add_column(sa.Column("proposal_fallback_reason", sa.Text(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("studies") as batch:
        batch.drop_column("proposal_fallback_reason")
        batch.drop_column("proposal_fallbacks")
