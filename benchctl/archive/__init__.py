"""The results archive: every run in a database — SQLite by default, one PostgreSQL server for
a line of benches — through SQLAlchemy 2 Core, its schema managed by Alembic migrations shipped
here (``migrations/``) and applied on open.

- ``benchctl.archive.schema``: the tables (units, runs, measurements);
- ``benchctl.archive.store``: ``Archive(url)``: open, migrate, store (idempotent by run_id),
  query (history, one run, a unit's σ series, a station's yield per day);
- ``benchctl.archive.ingest``: a recording's record (record.json, or built from its files) and
  its SHA-256; killed runs (no end.json);
- ``benchctl.archive.service``: settings from the config, a run's store-or-queue, sync,
  rebuild;
- ``benchctl.archive.history``: the history as text, CSV, JSON and an HTML page.

Imports of SQLAlchemy happen in these modules only; ``benchctl.archive`` itself is light.
"""
