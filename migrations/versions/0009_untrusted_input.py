"""Issue 36 (trust nothing a user sends): a trial's expanded URDF, stored once; who
uploaded an artifact, under which lease (trials.leases); a study whose proposals fail.

Revision ID: 0009
Revises: 0008
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0009"
down_revision = "0008"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "trial_urdfs",
        sa.Column(
            "trial_id",
            sa.Integer(),
            sa.ForeignKey("trials.id", ondelete="CASCADE"),
            primary_key=True,
        ),
        sa.Column("urdf", sa.Text(), nullable=True),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("created_at", sa.DateTime(), nullable=False),
    )
    with op.batch_alter_table("artifacts") as batch:
        batch.add_column(sa.Column("uploader", sa.String(16), nullable=True))
        batch.add_column(sa.Column("attempt", sa.Integer(), nullable=True))
    with op.batch_alter_table("trials") as batch:
        batch.add_column(sa.Column("leases", sa.Integer(), nullable=False, server_default="0"))
    with op.batch_alter_table("studies") as batch:
        batch.add_column(sa.Column("proposal_error", sa.Text(), nullable=True))
        batch.add_column(
            sa.Column("proposal_failures", sa.Integer(), nullable=False, server_default="0")
        )
        batch.add_column(sa.Column("proposal_retry_at", sa.DateTime(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("studies") as batch:
        batch.drop_column("proposal_retry_at")
        batch.drop_column("proposal_failures")
        batch.drop_column("proposal_error")
    with op.batch_alter_table("trials") as batch:
        batch.drop_column("leases")
    with op.batch_alter_table("artifacts") as batch:
        batch.drop_column("attempt")
        batch.drop_column("uploader")
    op.drop_table("trial_urdfs")
