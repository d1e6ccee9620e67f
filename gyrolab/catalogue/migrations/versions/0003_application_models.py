"""The models of a compensated recording that applied one per unit of a multi-unit run
(``gyrolab apply`` without ``--unit``).

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-27
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "application_models",
        sa.Column("application_id", sa.Integer(), nullable=False),
        sa.Column("model_hash", sa.String(length=80), nullable=False),
        sa.ForeignKeyConstraint(["application_id"], ["applications.id"]),
        sa.PrimaryKeyConstraint("application_id", "model_hash"),
    )
    with op.batch_alter_table("application_models", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_application_models_model_hash"), ["model_hash"], unique=False
        )


def downgrade() -> None:
    with op.batch_alter_table("application_models", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_application_models_model_hash"))
    op.drop_table("application_models")
