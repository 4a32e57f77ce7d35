"""Pruning: a study's pruner and pruned count, and trials' intermediate reports.

Revision ID: 0005
Revises: 0004
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

import adservice.models

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("studies") as batch:
        batch.add_column(
            sa.Column("pruner", sa.JSON(), nullable=False, server_default='{"name": "none"}')
        )
        batch.add_column(sa.Column("n_pruned", sa.Integer(), nullable=False, server_default="0"))
    with op.batch_alter_table("studies") as batch:
        batch.alter_column("pruner", server_default=None)
        batch.alter_column("n_pruned", server_default=None)
    op.create_table(
        "trial_reports",
        sa.Column("trial_id", sa.Integer(), nullable=False),
        sa.Column("step", sa.Integer(), autoincrement=False, nullable=False),
        sa.Column("study_id", sa.Integer(), nullable=False),
        sa.Column("value", sa.Double(), nullable=False),
        sa.Column("created_at", adservice.models.UTCDateTime(), nullable=False),
        sa.ForeignKeyConstraint(["study_id"], ["studies.id"], ondelete="CASCADE"),
        sa.ForeignKeyConstraint(["trial_id"], ["trials.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("trial_id", "step"),
    )
    op.create_index("ix_trial_reports_study_step", "trial_reports", ["study_id", "step"])


def downgrade() -> None:
    op.drop_index("ix_trial_reports_study_step", table_name="trial_reports")
    op.drop_table("trial_reports")
    with op.batch_alter_table("studies") as batch:
        batch.drop_column("n_pruned")
        batch.drop_column("pruner")
