"""The archive's tables as SQLAlchemy Core ``Table`` objects (the migrations in
``benchctl/archive/migrations`` create the same; a test checks the two agree).

- ``units``: one row per serial, with its part number (the last one a run gave);
- ``runs``: one row per run, keyed by ``run_id`` (the recording folder's name), with who, what,
  when, where, the outcome and the abort reason, the paths and SHA-256 of the recording and its
  report, the config's hash, the software version and the whole record (JSON text);
- ``measurements``: each measurement of a run with its unit, limits, 95 % interval, outcome
  and rule, in the record's order (``seq``).

Times are stored as naive UTC (``DateTime`` without a zone) on both backends.
"""

from __future__ import annotations

from sqlalchemy import (
    BigInteger,
    Column,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Table,
    Text,
    UniqueConstraint,
)

metadata = MetaData()

units = Table(
    "units",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("serial", String(200), nullable=False, unique=True),
    Column("part_number", String(200), nullable=True),
)

runs = Table(
    "runs",
    metadata,
    Column("run_id", String(255), primary_key=True),
    Column("unit_id", Integer, ForeignKey("units.id"), nullable=False),
    Column("serial", String(200), nullable=False),
    Column("part_number", String(200), nullable=True),
    Column("station", String(200), nullable=False),
    Column("operator", String(200), nullable=False),
    Column("start_utc", DateTime(), nullable=True),
    Column("end_utc", DateTime(), nullable=True),
    Column("outcome", String(20), nullable=False),
    Column("exit_code", Integer, nullable=True),
    Column("abort_kind", String(20), nullable=True),
    Column("abort_reason", Text, nullable=True),
    Column("decision_rule", String(20), nullable=True),
    Column("profile_name", String(200), nullable=True),
    Column("profile_kind", String(100), nullable=True),
    Column("profile_seed", BigInteger, nullable=True),
    Column("profile_sha256", String(64), nullable=True),
    Column("config_sha256", String(64), nullable=True),
    Column("software_version", String(100), nullable=True),
    Column("recording_path", Text, nullable=True),
    Column("recording_sha256", String(64), nullable=True),
    Column("report_path", Text, nullable=True),
    Column("report_sha256", String(64), nullable=True),
    Column("source", String(20), nullable=False),  # record.json | recording | killed
    Column("record_json", Text, nullable=False),
    Column("archived_utc", DateTime(), nullable=False),
)
Index("ix_runs_serial_start", runs.c.serial, runs.c.start_utc)
Index("ix_runs_station_start", runs.c.station, runs.c.start_utc)

measurements = Table(
    "measurements",
    metadata,
    Column("id", Integer, primary_key=True, autoincrement=True),
    Column("run_id", String(255), ForeignKey("runs.run_id", ondelete="CASCADE"), nullable=False),
    Column("seq", Integer, nullable=False),
    Column("name", String(200), nullable=False),
    Column("axis", String(50), nullable=True),
    Column("value", Float, nullable=True),
    Column("unit", String(50), nullable=True),
    Column("low", Float, nullable=True),
    Column("high", Float, nullable=True),
    Column("ci95_low", Float, nullable=True),
    Column("ci95_high", Float, nullable=True),
    Column("outcome", String(20), nullable=True),
    Column("rule", String(20), nullable=True),
    UniqueConstraint("run_id", "seq", name="uq_measurements_run_seq"),
)
Index("ix_measurements_name_axis", measurements.c.name, measurements.c.axis)

VERSION_TABLE = "benchctl_archive_version"  # Alembic's version table (a shared database)
HEAD = "0001"  # the newest migration's revision

__all__ = ["HEAD", "VERSION_TABLE", "measurements", "metadata", "runs", "units"]
