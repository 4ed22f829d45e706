"""The stations' heartbeats in the archive's database: what each station is doing now.

Runs reach the archive only when they end, so a run in progress is known from its station
alone: the station server publishes its state (``publish_station_state``, or
``StationBoard.publish``) on every change of state and every ``HEARTBEAT_EVERY_S`` seconds
between, into one table beside the archive's, ``benchctl_station_heartbeats``, one row per
station:

=============== ======================================================================
station         the station's name (as its runs record it), the key
state           ``idle`` or ``running``
phase           the run's phase while running (``prechecks``, ``ramp-in`` …), free text
serial          the unit under test, part_number, operator, run_id: while running
started_utc     when the run started (the station's clock)
updated_utc     when this row was last written (the **database's** clock)
last_outcome    the verdict of the station's last run (PASS, FAIL, INCONCLUSIVE, ABORTED),
                with last_serial, last_run_id and last_end_utc; kept by a heartbeat that
                does not name them
note            a line the station wants shown under its state ("waiting for the
                operator", "E-stop pressed"), free text
=============== ======================================================================

A station whose row is older than the staleness bound (``STALE_AFTER_S``, three missed
heartbeats) is **offline**, whatever its row says: its server stopped, crashed or lost the
network. The age is measured on the database's clock (written by it, read against it), so the
stations' own clocks need not agree.

The table is created by the first station that publishes, under a lock
(PostgreSQL: an advisory lock; SQLite: the database's own write lock), so that two stations
starting together do not trip over each other. It is not part of the archive's migrated
schema: it holds no results, only what is happening now, and can be dropped at any time.

Every failure to reach or write the database is an ``ArchiveError`` (its ``kind`` as the
archive says it: ``benchctl.archive.failures.classify``): a station server calls
``publish`` from its own thread and logs the error; a heartbeat lost never touches a run.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import StrEnum
from typing import Any

from sqlalchemy import (
    Column,
    DateTime,
    MetaData,
    String,
    Table,
    Text,
    func,
    inspect,
    select,
    text,
)
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.engine import Connection
from sqlalchemy.exc import SQLAlchemyError

from benchctl.archive.failures import classify
from benchctl.archive.rows import utc_naive
from benchctl.archive.store import Archive
from benchctl.clock import REAL, LockLike
from benchctl.errors import ArchiveError, InputError
from benchctl.redact import redact_text

HEARTBEAT_EVERY_S = 5.0  # how often a station server should publish between changes
STALE_AFTER_S = 15.0  # no heartbeat for this long: the station is offline
TABLE = "benchctl_station_heartbeats"
_CREATE_KEY = 0x6C696E65  # PostgreSQL advisory lock while the table is made ("line")

metadata = MetaData()
heartbeats = Table(
    TABLE,
    metadata,
    Column("station", String(200), primary_key=True),
    Column("state", String(20), nullable=False),
    Column("phase", String(50), nullable=True),
    Column("serial", String(200), nullable=True),
    Column("part_number", String(200), nullable=True),
    Column("operator", String(200), nullable=True),
    Column("run_id", String(255), nullable=True),
    Column("started_utc", DateTime(), nullable=True),
    Column("updated_utc", DateTime(), nullable=False),
    Column("last_outcome", String(20), nullable=True),
    Column("last_serial", String(200), nullable=True),
    Column("last_run_id", String(255), nullable=True),
    Column("last_end_utc", DateTime(), nullable=True),
    Column("note", Text, nullable=True),
)


class StationState(StrEnum):
    """What a station server publishes."""

    IDLE = "idle"
    RUNNING = "running"


class Presence(StrEnum):
    """What the line view shows: the published state, or why there is none."""

    IDLE = "idle"
    RUNNING = "running"
    OFFLINE = "offline"  # a heartbeat older than the staleness bound
    UNKNOWN = "unknown"  # runs in the archive, but never a heartbeat


@dataclass(frozen=True)
class Heartbeat:
    """One station's row."""

    station: str
    state: str
    updated_utc: datetime  # naive UTC, the database's clock
    phase: str | None = None
    serial: str | None = None
    part_number: str | None = None
    operator: str | None = None
    run_id: str | None = None
    started_utc: datetime | None = None  # naive UTC
    last_outcome: str | None = None
    last_serial: str | None = None
    last_run_id: str | None = None
    last_end_utc: datetime | None = None
    note: str | None = None


def presence(hb: Heartbeat | None, now_utc: datetime,
             stale_after_s: float = STALE_AFTER_S) -> Presence:
    """A station's presence at ``now_utc`` (naive UTC, the database's clock): its published
    state while its heartbeat is fresh (age ≤ ``stale_after_s``), else offline; unknown
    without one."""
    if hb is None:
        return Presence.UNKNOWN
    if (now_utc - hb.updated_utc).total_seconds() > stale_after_s:
        return Presence.OFFLINE
    return Presence.RUNNING if hb.state == StationState.RUNNING else Presence.IDLE


def database_error(archive: Archive, what: str, e: BaseException) -> ArchiveError:
    """The ``ArchiveError`` for a failure of ``archive`` while doing ``what``: its kind as the
    archive says it (``classify``) and the driver's first line, passwords hidden."""
    kind = classify(e)
    orig = getattr(e, "orig", None)
    first = str(orig if orig is not None else e).strip().splitlines()
    cause = redact_text(first[0]) if first else type(e).__name__
    return ArchiveError(f"archive {archive.name}: cannot {what}: {kind} ({cause})", kind)


@contextmanager
def transaction(archive: Archive, what: str) -> Iterator[Connection]:
    """A transaction on ``archive``'s database; a failure is ``database_error``'s."""
    try:
        with archive.engine.begin() as conn:
            yield conn
    except SQLAlchemyError as e:
        raise database_error(archive, what, e) from e


def _cut(v: object, limit: int) -> str | None:
    return None if v is None else str(v)[:limit]


def _now_expr(backend: str) -> Any:
    """The database's current time as naive UTC."""
    if backend == "postgresql":
        return text("timezone('utc', clock_timestamp())")
    return func.strftime("%Y-%m-%d %H:%M:%f", "now")


class StationBoard:
    """The heartbeats table of one open archive: ``publish`` a station's state, ``read``
    them all with the database's time. The table is made on first use. Thread-safe (the
    archive's engine pools its connections)."""

    def __init__(self, archive: Archive) -> None:
        self.archive = archive
        self._ready = False
        self._lock: LockLike = REAL.lock()

    def _begin(self, what: str) -> Any:
        return transaction(self.archive, what)

    def ensure_table(self) -> None:
        """Create the heartbeats table when it is not there (once per board)."""
        with self._lock:
            if self._ready:
                return
            with self._begin(f"create the table {TABLE}") as conn:
                if self.archive.backend == "postgresql":
                    conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": _CREATE_KEY})
                metadata.create_all(conn, checkfirst=True)
            self._ready = True

    def publish(self, station: str, state: StationState | str, *, phase: str | None = None,
                serial: str | None = None, part_number: str | None = None,
                operator: str | None = None, run_id: str | None = None,
                started_utc: datetime | str | None = None, last_outcome: str | None = None,
                last_serial: str | None = None, last_run_id: str | None = None,
                last_end_utc: datetime | str | None = None, note: str | None = None) -> None:
        """Write ``station``'s row (insert or replace), ``updated_utc`` the database's now.
        The run's fields (phase, serial, part number, operator, run id, start) are as given:
        None clears them (an idle station); the last run's fields (``last_*``) are kept
        when not given. ``InputError`` for an unknown state or an empty station name."""
        try:
            st = StationState(state)
        except ValueError:
            raise InputError(f"state = {state!r}: expected one of "
                             f"{', '.join(s.value for s in StationState)}") from None
        if not station or not station.strip():
            raise InputError(f"station = {station!r}: expected the station's name")
        self.ensure_table()
        row: dict[str, Any] = {
            "station": _cut(station, 200), "state": st.value, "phase": _cut(phase, 50),
            "serial": _cut(serial, 200), "part_number": _cut(part_number, 200),
            "operator": _cut(operator, 200), "run_id": _cut(run_id, 255),
            "started_utc": utc_naive(started_utc),
            "updated_utc": _now_expr(self.archive.backend),
            "last_outcome": _cut(None if last_outcome is None else str(last_outcome).upper(),
                                 20),
            "last_serial": _cut(last_serial, 200), "last_run_id": _cut(last_run_id, 255),
            "last_end_utc": utc_naive(last_end_utc), "note": _cut(note, 2000),
        }
        ins = _insert(self.archive.backend)(heartbeats).values(**row)
        kept = ("last_outcome", "last_serial", "last_run_id", "last_end_utc")
        ins = ins.on_conflict_do_update(
            index_elements=[heartbeats.c.station],
            set_={k: (func.coalesce(ins.excluded[k], heartbeats.c[k]) if k in kept
                      else ins.excluded[k]) for k in row if k != "station"},
        )
        try:
            with self._begin(f"publish the state of station {station!r}") as conn:
                conn.execute(ins)
        except ArchiveError:
            self._ready = False  # the table may have been dropped: looked for again next time
            raise

    def read(self) -> tuple[datetime, list[Heartbeat]]:
        """The database's time now (naive UTC) and every station's row, by name (none
        before a station first published: reading creates nothing, so a reader needs no
        right to write)."""
        with self._begin("read the stations' heartbeats") as conn:
            now = _as_datetime(conn.execute(select(_now_expr(self.archive.backend)))
                               .scalar_one())
            if not self._ready and not inspect(conn).has_table(TABLE):
                return now, []
            rows = conn.execute(select(heartbeats).order_by(heartbeats.c.station)).all()
        return now, [Heartbeat(**dict(r._mapping)) for r in rows]

    def forget(self, station: str) -> None:
        """Remove a station's row (a station taken off the line)."""
        self.ensure_table()
        with self._begin(f"forget station {station!r}") as conn:
            conn.execute(heartbeats.delete().where(heartbeats.c.station == station))


def _insert(backend: str) -> Any:
    """The dialect's INSERT (both have ``on_conflict_do_update``)."""
    if backend == "postgresql":
        return pg_insert
    return sqlite_insert


def _as_datetime(v: object) -> datetime:
    if isinstance(v, datetime):
        return v.astimezone(UTC).replace(tzinfo=None) if v.tzinfo is not None else v
    d = utc_naive(str(v))
    if d is None:
        raise ArchiveError(f"the database's time {v!r}: not a time")
    return d


def publish_station_state(archive: Archive | str, station: str, state: StationState | str,
                          **fields: Any) -> None:
    """Publish ``station``'s state (``StationBoard.publish``'s arguments) into the archive
    ``archive`` (an open ``Archive``, or its URL: opened and closed again, for a one-off; a
    server publishing every few seconds keeps one ``StationBoard``)."""
    if isinstance(archive, Archive):
        StationBoard(archive).publish(station, state, **fields)
        return
    with Archive(archive) as a:
        StationBoard(a).publish(station, state, **fields)


__all__ = ["HEARTBEAT_EVERY_S", "STALE_AFTER_S", "TABLE", "Heartbeat", "Presence",
           "StationBoard", "StationState", "database_error", "heartbeats", "presence",
           "publish_station_state", "transaction"]
