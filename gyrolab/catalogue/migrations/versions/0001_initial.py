"""Initial schema: units, runs, segments, models, exports, applications, flashes,
verifications, reports (the tables of gyrolab/catalogue/schema.py at revision 0001).

Revision ID: 0001
Revises:
Create Date: 2026-11-26
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "applications",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("model_hash", sa.String(length=80), nullable=True),
        sa.Column("run_file", sa.String(length=80), nullable=True),
        sa.Column("file_hash", sa.String(length=80), nullable=False),
        sa.Column("path", sa.Text(), nullable=False),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("file_hash"),
    )
    with op.batch_alter_table("applications", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_applications_model_hash"), ["model_hash"], unique=False
        )
        batch_op.create_index(batch_op.f("ix_applications_run_file"), ["run_file"], unique=False)

    op.create_table(
        "exports",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("model_hash", sa.String(length=80), nullable=True),
        sa.Column("format", sa.String(length=16), nullable=False),
        sa.Column("target", sa.JSON(), nullable=False),
        sa.Column("file_hash", sa.String(length=80), nullable=False),
        sa.Column("path", sa.Text(), nullable=False),
        sa.Column("files", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("file_hash"),
    )
    with op.batch_alter_table("exports", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_exports_model_hash"), ["model_hash"], unique=False)

    op.create_table(
        "runs",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("run_key", sa.String(length=100), nullable=False),
        sa.Column("source", sa.String(length=32), nullable=False),
        sa.Column("station", sa.String(length=200), nullable=False),
        sa.Column("operator", sa.String(length=200), nullable=False),
        sa.Column("profile_name", sa.String(length=200), nullable=False),
        sa.Column("profile", sa.JSON(), nullable=False),
        sa.Column("simulated", sa.Boolean(), nullable=False),
        sa.Column("outcome", sa.String(length=32), nullable=False),
        sa.Column("started_at", sa.DateTime(), nullable=True),
        sa.Column("registered_at", sa.DateTime(), nullable=False),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("run_key"),
    )
    op.create_table(
        "units",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("serial", sa.String(length=64), nullable=False),
        sa.Column("part_number", sa.String(length=200), nullable=True),
        sa.Column("first_seen", sa.DateTime(), nullable=False),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("serial"),
    )
    op.create_table(
        "flashes",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("record_hash", sa.String(length=80), nullable=False),
        sa.Column("record_path", sa.Text(), nullable=False),
        sa.Column("unit_id", sa.Integer(), nullable=True),
        sa.Column("params_hash", sa.String(length=80), nullable=False),
        sa.Column("model_hash", sa.String(length=80), nullable=True),
        sa.Column("device", sa.Text(), nullable=False),
        sa.Column("result", sa.String(length=32), nullable=False),
        sa.Column("detail", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.Column("host", sa.String(length=200), nullable=False),
        sa.ForeignKeyConstraint(
            ["unit_id"],
            ["units.id"],
        ),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("record_hash"),
    )
    with op.batch_alter_table("flashes", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_flashes_model_hash"), ["model_hash"], unique=False)
        batch_op.create_index(batch_op.f("ix_flashes_params_hash"), ["params_hash"], unique=False)
        batch_op.create_index(batch_op.f("ix_flashes_unit_id"), ["unit_id"], unique=False)

    op.create_table(
        "models",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("model_hash", sa.String(length=80), nullable=False),
        sa.Column("path", sa.Text(), nullable=False),
        sa.Column("unit_id", sa.Integer(), nullable=True),
        sa.Column("calibration_file", sa.String(length=80), nullable=True),
        sa.Column("validation_file", sa.String(length=80), nullable=True),
        sa.Column("calibration_hash", sa.String(length=80), nullable=True),
        sa.Column("validation_hash", sa.String(length=80), nullable=True),
        sa.Column("calibration_path", sa.Text(), nullable=True),
        sa.Column("validation_path", sa.Text(), nullable=True),
        sa.Column("held_out", sa.Boolean(), nullable=False),
        sa.Column("family", sa.String(length=64), nullable=True),
        sa.Column("axes", sa.Integer(), nullable=False),
        sa.Column("metrics", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(), nullable=True),
        sa.Column("registered_at", sa.DateTime(), nullable=False),
        sa.ForeignKeyConstraint(
            ["unit_id"],
            ["units.id"],
        ),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("model_hash"),
    )
    with op.batch_alter_table("models", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_models_calibration_file"), ["calibration_file"], unique=False
        )
        batch_op.create_index(batch_op.f("ix_models_unit_id"), ["unit_id"], unique=False)
        batch_op.create_index(
            batch_op.f("ix_models_validation_file"), ["validation_file"], unique=False
        )

    op.create_table(
        "reports",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("report_hash", sa.String(length=80), nullable=False),
        sa.Column("unit_id", sa.Integer(), nullable=True),
        sa.Column("run_file", sa.String(length=80), nullable=True),
        sa.Column("model_hash", sa.String(length=80), nullable=True),
        sa.Column("path", sa.Text(), nullable=False),
        sa.Column("outcome", sa.String(length=32), nullable=True),
        sa.Column("verdict", sa.String(length=16), nullable=True),
        sa.Column("spec", sa.Text(), nullable=True),
        sa.Column("held_out", sa.Boolean(), nullable=False),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.ForeignKeyConstraint(
            ["unit_id"],
            ["units.id"],
        ),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("report_hash"),
    )
    with op.batch_alter_table("reports", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_reports_model_hash"), ["model_hash"], unique=False)
        batch_op.create_index(batch_op.f("ix_reports_run_file"), ["run_file"], unique=False)
        batch_op.create_index(batch_op.f("ix_reports_unit_id"), ["unit_id"], unique=False)

    op.create_table(
        "run_units",
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("unit_id", sa.Integer(), nullable=False),
        sa.ForeignKeyConstraint(
            ["run_id"],
            ["runs.id"],
        ),
        sa.ForeignKeyConstraint(
            ["unit_id"],
            ["units.id"],
        ),
        sa.PrimaryKeyConstraint("run_id", "unit_id"),
    )
    with op.batch_alter_table("run_units", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_run_units_unit_id"), ["unit_id"], unique=False)

    op.create_table(
        "segments",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("run_id", sa.Integer(), nullable=False),
        sa.Column("number", sa.Integer(), nullable=False),
        sa.Column("file_hash", sa.String(length=80), nullable=False),
        sa.Column("path", sa.Text(), nullable=False),
        sa.Column("size_bytes", sa.BigInteger(), nullable=False),
        sa.Column("outcome", sa.String(length=32), nullable=False),
        sa.Column("outcome_line", sa.Text(), nullable=False),
        sa.Column("started_at", sa.DateTime(), nullable=True),
        sa.Column("host", sa.String(length=200), nullable=False),
        sa.Column("registered_at", sa.DateTime(), nullable=False),
        sa.ForeignKeyConstraint(
            ["run_id"],
            ["runs.id"],
        ),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("file_hash"),
    )
    with op.batch_alter_table("segments", schema=None) as batch_op:
        batch_op.create_index(batch_op.f("ix_segments_run_id"), ["run_id"], unique=False)

    op.create_table(
        "verifications",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("record_hash", sa.String(length=80), nullable=False),
        sa.Column("record_path", sa.Text(), nullable=False),
        sa.Column("unit_id", sa.Integer(), nullable=True),
        sa.Column("flash_record", sa.String(length=80), nullable=True),
        sa.Column("run_file", sa.String(length=80), nullable=True),
        sa.Column("verdict", sa.String(length=16), nullable=False),
        sa.Column("detail", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(), nullable=False),
        sa.Column("host", sa.String(length=200), nullable=False),
        sa.ForeignKeyConstraint(
            ["unit_id"],
            ["units.id"],
        ),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("record_hash"),
    )
    with op.batch_alter_table("verifications", schema=None) as batch_op:
        batch_op.create_index(
            batch_op.f("ix_verifications_flash_record"), ["flash_record"], unique=False
        )
        batch_op.create_index(batch_op.f("ix_verifications_run_file"), ["run_file"], unique=False)
        batch_op.create_index(batch_op.f("ix_verifications_unit_id"), ["unit_id"], unique=False)



def downgrade() -> None:
    with op.batch_alter_table("verifications", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_verifications_unit_id"))
        batch_op.drop_index(batch_op.f("ix_verifications_run_file"))
        batch_op.drop_index(batch_op.f("ix_verifications_flash_record"))

    op.drop_table("verifications")
    with op.batch_alter_table("segments", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_segments_run_id"))

    op.drop_table("segments")
    with op.batch_alter_table("run_units", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_run_units_unit_id"))

    op.drop_table("run_units")
    with op.batch_alter_table("reports", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_reports_unit_id"))
        batch_op.drop_index(batch_op.f("ix_reports_run_file"))
        batch_op.drop_index(batch_op.f("ix_reports_model_hash"))

    op.drop_table("reports")
    with op.batch_alter_table("models", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_models_validation_file"))
        batch_op.drop_index(batch_op.f("ix_models_unit_id"))
        batch_op.drop_index(batch_op.f("ix_models_calibration_file"))

    op.drop_table("models")
    with op.batch_alter_table("flashes", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_flashes_unit_id"))
        batch_op.drop_index(batch_op.f("ix_flashes_params_hash"))
        batch_op.drop_index(batch_op.f("ix_flashes_model_hash"))

    op.drop_table("flashes")
    op.drop_table("units")
    op.drop_table("runs")
    with op.batch_alter_table("exports", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_exports_model_hash"))

    op.drop_table("exports")
    with op.batch_alter_table("applications", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_applications_run_file"))
        batch_op.drop_index(batch_op.f("ix_applications_model_hash"))

    op.drop_table("applications")
