"""The runs a model's causal part was also fitted on (``compensate --also``).

Revision ID: 0002
Revises: 0001
Create Date: 2026-11-27
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "model_also_runs",
        sa.Column("model_id", sa.Integer(), nullable=False),
        sa.Column("position", sa.Integer(), nullable=False),
        sa.Column("file_hash", sa.String(length=80), nullable=True),
        sa.Column("data_hash", sa.String(length=80), nullable=True),
        sa.Column("path", sa.Text(), nullable=True),
        sa.ForeignKeyConstraint(["model_id"], ["models.id"]),
        sa.PrimaryKeyConstraint("model_id", "position"),
    )
    with op.batch_alter_table("model_also_runs", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_model_also_runs_file_hash"), ["file_hash"], unique=False
        )


def downgrade() -> None:
    with op.batch_alter_table("model_also_runs", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_model_also_runs_file_hash"))
    op.drop_table("model_also_runs")
