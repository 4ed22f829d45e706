"""The archive's first schema: units, runs, measurements.

Revision ID: 0001
Revises:
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
        "units",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("serial", sa.String(200), nullable=False, unique=True),
        sa.Column("part_number", sa.String(200), nullable=True),
    )
    op.create_table(
        "runs",
        sa.Column("run_id", sa.String(255), primary_key=True),
        sa.Column("unit_id", sa.Integer, sa.ForeignKey("units.id"), nullable=False),
        sa.Column("serial", sa.String(200), nullable=False),
        sa.Column("part_number", sa.String(200), nullable=True),
        sa.Column("station", sa.String(200), nullable=False),
        sa.Column("operator", sa.String(200), nullable=False),
        sa.Column("start_utc", sa.DateTime(), nullable=True),
        sa.Column("end_utc", sa.DateTime(), nullable=True),
        sa.Column("outcome", sa.String(20), nullable=False),
        sa.Column("exit_code", sa.Integer, nullable=True),
        sa.Column("abort_kind", sa.String(20), nullable=True),
        sa.Column("abort_reason", sa.Text, nullable=True),
        sa.Column("decision_rule", sa.String(20), nullable=True),
        sa.Column("profile_name", sa.String(200), nullable=True),
        sa.Column("profile_kind", sa.String(100), nullable=True),
        sa.Column("profile_seed", sa.BigInteger, nullable=True),
        sa.Column("profile_sha256", sa.String(64), nullable=True),
        sa.Column("config_sha256", sa.String(64), nullable=True),
        sa.Column("software_version", sa.String(100), nullable=True),
        sa.Column("recording_path", sa.Text, nullable=True),
        sa.Column("recording_sha256", sa.String(64), nullable=True),
        sa.Column("report_path", sa.Text, nullable=True),
        sa.Column("report_sha256", sa.String(64), nullable=True),
        sa.Column("source", sa.String(20), nullable=False),
        sa.Column("record_json", sa.Text, nullable=False),
        sa.Column("archived_utc", sa.DateTime(), nullable=False),
    )
    op.create_index("ix_runs_serial_start", "runs", ["serial", "start_utc"])
    op.create_index("ix_runs_station_start", "runs", ["station", "start_utc"])
    op.create_table(
        "measurements",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column(
            "run_id", sa.String(255), sa.ForeignKey("runs.run_id", ondelete="CASCADE"),
            nullable=False,
        ),
        sa.Column("seq", sa.Integer, nullable=False),
        sa.Column("name", sa.String(200), nullable=False),
        sa.Column("axis", sa.String(50), nullable=True),
        sa.Column("value", sa.Float, nullable=True),
        sa.Column("unit", sa.String(50), nullable=True),
        sa.Column("low", sa.Float, nullable=True),
        sa.Column("high", sa.Float, nullable=True),
        sa.Column("ci95_low", sa.Float, nullable=True),
        sa.Column("ci95_high", sa.Float, nullable=True),
        sa.Column("outcome", sa.String(20), nullable=True),
        sa.Column("rule", sa.String(20), nullable=True),
        sa.UniqueConstraint("run_id", "seq", name="uq_measurements_run_seq"),
    )
    op.create_index("ix_measurements_name_axis", "measurements", ["name", "axis"])


def downgrade() -> None:
    op.drop_table("measurements")
    op.drop_table("runs")
    op.drop_table("units")
