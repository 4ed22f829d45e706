"""The line view's tests: a new database on the session's PostgreSQL server per test (the
shared ``pg`` fixture: the distribution's initdb/pg_ctl; a machine without them fails)."""

from __future__ import annotations

import uuid
from collections.abc import Iterator

import pytest
from archive_helpers import PgServer

from benchctl.archive.store import Archive


@pytest.fixture
def line_url(pg: PgServer) -> str:
    """An empty archive database on the session's PostgreSQL."""
    return pg.create_database(f"line_{uuid.uuid4().hex[:12]}")


@pytest.fixture
def line_archive(line_url: str) -> Iterator[Archive]:
    with Archive(line_url) as a:
        yield a
