"""Study owners, leases bound to tokens, dashboard sessions.

Revision ID: 0004
Revises: 0003
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

import adservice.models

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("studies") as batch:
        batch.add_column(sa.Column("owner_token_id", sa.Integer(), nullable=True))
        batch.add_column(sa.Column("created_by", sa.String(length=128), nullable=True))
    with op.batch_alter_table("trials") as batch:
        batch.add_column(sa.Column("lease_token_id", sa.Integer(), nullable=True))
    op.create_table(
        "sessions",
        sa.Column("id_sha256", sa.String(length=64), nullable=False),
        sa.Column("token_id", sa.Integer(), nullable=False),
        sa.Column("csrf_token", sa.String(length=64), nullable=False),
        sa.Column("created_at", adservice.models.UTCDateTime(), nullable=False),
        sa.Column("expires_at", adservice.models.UTCDateTime(), nullable=False),
        sa.ForeignKeyConstraint(["token_id"], ["tokens.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id_sha256"),
    )


def downgrade() -> None:
    op.drop_table("sessions")
    with op.batch_alter_table("trials") as batch:
        batch.drop_column("lease_token_id")
    with op.batch_alter_table("studies") as batch:
        batch.drop_column("created_by")
        batch.drop_column("owner_token_id")
