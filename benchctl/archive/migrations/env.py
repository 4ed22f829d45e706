"""Alembic's environment for the archive: run programmatically by ``benchctl.archive.store``
(no alembic.ini): the connection comes in ``config.attributes["connection"]``.

On PostgreSQL the migration holds a transaction-level advisory lock, so two benches opening
a new shared archive at once do not both create the tables; on SQLite the transaction begins
IMMEDIATE (the engine's own rule) for the same effect.
"""

from __future__ import annotations

from alembic import context
from sqlalchemy import text

from benchctl.archive.schema import VERSION_TABLE, metadata

ADVISORY_KEY = 0x62656E6368  # "bench"


def run_migrations_online() -> None:
    connection = context.config.attributes.get("connection")
    if connection is None:
        raise RuntimeError("benchctl.archive migrations: run through benchctl.archive.store")
    context.configure(
        connection=connection,
        target_metadata=metadata,
        version_table=VERSION_TABLE,
        transaction_per_migration=False,
    )
    with context.begin_transaction():
        if connection.dialect.name == "postgresql":
            connection.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": ADVISORY_KEY})
        context.run_migrations()


if context.is_offline_mode():
    raise RuntimeError("benchctl.archive migrations run online only")
run_migrations_online()
