"""Several objectives and outcome constraints: a study's outcomes, a trial's values and
feasibility.

Revision ID: 0008
Revises: 0007
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("studies") as batch:
        batch.add_column(sa.Column("outcomes", sa.JSON(none_as_null=True), nullable=True))
    with op.batch_alter_table("trials") as batch:
        batch.add_column(sa.Column("values", sa.JSON(none_as_null=True), nullable=True))
        batch.add_column(sa.Column("feasible", sa.Boolean(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("trials") as batch:
        batch.drop_column("feasible")
        batch.drop_column("values")
    with op.batch_alter_table("studies") as batch:
        batch.drop_column("outcomes")
