"""The results archive: one database (SQLite by default, PostgreSQL for a line of benches)
opened with ``Archive(url)``, its schema brought to the newest migration on open (Alembic,
programmatically: no alembic.ini at the user's site), runs stored idempotently by ``run_id``.

SQLite runs in WAL mode with a busy timeout, every write transaction beginning IMMEDIATE (so
two writers wait for each other instead of failing, for at most the busy timeout); PostgreSQL
goes through psycopg 3 (``postgresql+psycopg://``; a plain ``postgresql://`` means the same)
with a short connect timeout, and every session it opens has a ``lock_timeout`` (the busy
timeout) and a ``statement_timeout``: no statement waits on the database for ever. Every
failure to reach or write the database is an ``ArchiveError`` naming the archive (its
password hidden: ``benchctl.redact``), what it was doing and the cause, its ``kind`` saying
which it was (``classify``): ``refused`` (this record), ``locked``, ``timed out``,
``read-only``, ``denied``, ``unreachable`` or ``failed``.
"""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import math
import os
import threading
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from datetime import datetime
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, delete, event, func, inspect, select, text
from sqlalchemy.dialects.postgresql import insert as pg_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.engine import URL, Connection, make_url
from sqlalchemy.exc import ArgumentError, SQLAlchemyError
from sqlalchemy.pool import NullPool

from benchctl.archive.failures import RECORD_ERRORS, cause_line, classify
from benchctl.archive.rows import (
    iso,
    measurement_dict,
    measurement_rows,
    run_row,
    run_summary,
)
from benchctl.archive.schema import HEAD, VERSION_TABLE, measurements, runs, units
from benchctl.errors import ArchiveError
from benchctl.outcomes import RUN_OUTCOMES, Outcome
from benchctl.redact import redact_secret, redact_text

log = logging.getLogger(__name__)

MIGRATIONS = Path(__file__).resolve().parent / "migrations"
OUTCOMES = RUN_OUTCOMES  # the runs' outcomes the archive counts
DEFAULT_CONNECT_TIMEOUT_S = 2.0
DEFAULT_BUSY_TIMEOUT_S = 30.0  # how long a statement waits for a lock (SQLite: a busy file)
MIGRATE_KEY = 0x62656E6368  # PostgreSQL advisory lock of the migrations ("bench")
_TX_ERRORS: tuple[type[Exception], ...] = (SQLAlchemyError, *RECORD_ERRORS)


def parse_url(url: str, field: str = "archive.url") -> URL:
    """An archive URL checked and normalised: ``sqlite:///PATH`` or
    ``postgresql[+psycopg]://…`` (psycopg 3 either way). ``ArchiveError`` names ``field``."""
    try:
        u = make_url(url)
    except (ArgumentError, ValueError) as e:
        raise ArchiveError(f"{field} = {redact_text(url)!r}: not a database URL "
                           f"({redact_text(str(e))})") from None
    backend, _, driver = u.drivername.partition("+")
    if backend == "sqlite":
        if driver not in ("", "pysqlite"):
            raise ArchiveError(f"{field} = {shown(u)!r}: expected sqlite:///PATH "
                               f"(driver {driver}?)")
        if not u.database or u.database == ":memory:":
            raise ArchiveError(f"{field} = {shown(u)!r}: expected sqlite:///PATH (a file)")
        return u.set(drivername="sqlite")
    if backend in ("postgresql", "postgres"):
        if driver not in ("", "psycopg"):
            raise ArchiveError(
                f"{field} = {shown(u)}: expected postgresql+psycopg://… (psycopg 3), "
                f"not driver {driver}"
            )
        return u.set(drivername="postgresql+psycopg")
    raise ArchiveError(
        f"{field} = {shown(u)}: expected sqlite:///PATH or postgresql+psycopg://USER@HOST/DB"
    )


def shown(url: URL | str) -> str:
    """A URL for messages and logs: its password hidden, in whatever form it is given
    (``user:pw@``, ``?password=``; a URL that does not parse too: ``benchctl.redact``)."""
    if isinstance(url, URL):
        return redact_text(url.render_as_string(hide_password=True))
    return redact_text(str(url))


















_MIGRATE_LOCK = threading.Lock()


def _revision(conn: Connection) -> str | None:
    if not inspect(conn).has_table(VERSION_TABLE):
        return None
    row = conn.execute(text(f"SELECT version_num FROM {VERSION_TABLE}")).first()
    return None if row is None else str(row[0])


class Archive:
    """An open archive. ``Archive(url)`` connects and migrates (``ArchiveError`` when it
    cannot); use as a context manager or call ``close()``.

    ``busy_timeout_s``: how long a statement waits for a lock another session holds (SQLite:
    its busy timeout; PostgreSQL: ``lock_timeout``, and the migrations' advisory lock);
    ``statement_timeout_s`` (default twice that): PostgreSQL's ``statement_timeout``, how long
    any one statement may take. Both are set on every connection, reads included."""

    def __init__(self, url: str, *, connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S,
                 busy_timeout_s: float = DEFAULT_BUSY_TIMEOUT_S,
                 statement_timeout_s: float | None = None, migrate: bool = True) -> None:
        self.url = parse_url(url)
        self.name = shown(self.url)
        self.backend = "sqlite" if self.url.drivername == "sqlite" else "postgresql"
        self.busy_timeout_s = busy_timeout_s
        self.statement_timeout_s = (2.0 * busy_timeout_s if statement_timeout_s is None
                                    else statement_timeout_s)
        self.engine = self._engine(connect_timeout_s, busy_timeout_s)
        try:
            if migrate:
                self.migrate()
            else:
                with self.engine.connect():
                    pass
        except BaseException:
            self.engine.dispose()
            raise

    def _engine(self, connect_timeout_s: float, busy_timeout_s: float) -> Engine:
        if self.backend == "sqlite":
            db = Path(str(self.url.database)).expanduser()
            try:
                db.parent.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise ArchiveError(
                    f"archive {self.name}: cannot create the folder {db.parent}: {e.strerror}"
                ) from None
            engine = create_engine(
                self.url.set(database=str(db)),
                connect_args={"timeout": busy_timeout_s, "check_same_thread": False},
                poolclass=NullPool,
            )
            busy_ms = int(busy_timeout_s * 1000)

            @event.listens_for(engine, "connect")
            def _on_connect(dbapi_conn: Any, _record: Any) -> None:
                dbapi_conn.isolation_level = None  # we BEGIN ourselves (IMMEDIATE)
                cur = dbapi_conn.cursor()
                cur.execute(f"PRAGMA busy_timeout = {busy_ms}")
                cur.execute("PRAGMA journal_mode = WAL")
                cur.execute("PRAGMA synchronous = NORMAL")
                cur.execute("PRAGMA foreign_keys = ON")
                cur.close()

            @event.listens_for(engine, "begin")
            def _on_begin(conn: Connection) -> None:
                conn.exec_driver_sql("BEGIN IMMEDIATE")

            return engine
        timeout = max(1, math.ceil(connect_timeout_s))
        # every session: no lock waited for longer than busy_timeout_s, no statement longer
        # than statement_timeout_s (the server cancels it: lock_not_available, query_canceled)
        options = (f"-c lock_timeout={max(1, round(busy_timeout_s * 1000))} "
                   f"-c statement_timeout={max(1, round(self.statement_timeout_s * 1000))}")
        given = self.url.query.get("options")
        if isinstance(given, str) and given.strip():
            options = f"{given} {options}"  # the URL's own options kept, ours last (they win)
        return create_engine(
            self.url,
            connect_args={"connect_timeout": timeout, "application_name": "benchctl",
                          "options": options},
            pool_pre_ping=True,
            pool_size=2,
            max_overflow=2,
        )

    def _error(self, what: str, e: BaseException) -> ArchiveError:
        """The ``ArchiveError`` for a failure while doing ``what``: its kind (``classify``)
        and the driver's first line, passwords hidden."""
        kind = classify(e)
        cause = redact_secret(cause_line(e), self.url.password)
        if kind == "locked":
            cause += f"; waited {self.busy_timeout_s:g} s"
        elif kind == "timed out":
            cause += f"; statement timeout {self.statement_timeout_s:g} s"
        return ArchiveError(f"archive {self.name}: cannot {what}: {kind} ({cause})", kind)

    @contextmanager
    def _tx(self, what: str) -> Iterator[Connection]:
        try:
            with self.engine.begin() as conn:
                yield conn
        except _TX_ERRORS as e:
            raise self._error(what, e) from e

    def _read(self, what: str) -> Any:
        @contextmanager
        def cm() -> Iterator[Connection]:
            try:
                with self.engine.connect() as conn:
                    yield conn
            except SQLAlchemyError as e:
                raise self._error(what, e) from e
        return cm()

    def migrate(self) -> None:
        """Bring the schema to the newest migration (Alembic ``upgrade head``; Alembic is
        loaded only when the schema is not at ``HEAD`` already). Processes opening the same
        new archive at once take turns: SQLite through a lock file beside the database,
        PostgreSQL through an advisory lock, each checking the version again once it holds
        the lock (a second migrator finds the schema made, never a half-made one)."""
        if not _MIGRATE_LOCK.acquire(timeout=self.statement_timeout_s):
            raise ArchiveError(f"archive {self.name}: cannot bring its schema up to date: "
                               "locked (another thread of this process is migrating)", "locked")
        try:
            with self._sqlite_lock():
                self._migrate()
        finally:
            _MIGRATE_LOCK.release()

    def _migrate(self) -> None:
        try:
            with self.engine.connect() as conn:
                if self.backend == "postgresql":
                    conn.execute(text("SELECT pg_advisory_lock(:k)"), {"k": MIGRATE_KEY})
                try:
                    if _revision(conn) != HEAD:
                        self._upgrade(conn)
                finally:
                    if self.backend == "postgresql":
                        conn.rollback()  # out of any failed transaction, then unlock
                        conn.execute(text("SELECT pg_advisory_unlock(:k)"),
                                     {"k": MIGRATE_KEY})
                        conn.commit()
        except SQLAlchemyError as e:
            raise self._error("open it or bring its schema up to date", e) from e

    @contextmanager
    def _sqlite_lock(self) -> Iterator[None]:
        """SQLite: an exclusive lock on ``<database>.migrate.lock`` while held (no-op else),
        waited for at most the busy timeout (``locked`` then)."""
        if self.backend != "sqlite":
            yield
            return

        path = Path(str(self.engine.url.database) + ".migrate.lock")
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        except OSError as e:
            if e.errno not in (errno.EACCES, errno.EPERM, errno.EROFS) or not path.is_file():
                kind = "read-only" if e.errno in (errno.EACCES, errno.EPERM, errno.EROFS) \
                    else "failed"
                raise ArchiveError(f"archive {self.name}: cannot open {path}: {kind} "
                                   f"({e.strerror})", kind) from None
            # a read-only folder or file: the lock still works on a descriptor opened to read
            # (the database itself will say whether it can be written)
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
        try:
            deadline = time.monotonic() + self.busy_timeout_s
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() >= deadline:
                        raise ArchiveError(
                            f"archive {self.name}: cannot bring its schema up to date: locked "
                            f"(another process holds {path}; waited {self.busy_timeout_s:g} s)",
                            "locked") from None
                    time.sleep(0.05)
            yield
        finally:
            os.close(fd)  # releases the lock

    def _upgrade(self, conn: Connection) -> None:
        # Alembic: about 0.25 s to import, needed only when the schema is behind
        from alembic import command
        from alembic.config import Config

        cfg = Config()
        cfg.set_main_option("script_location", str(MIGRATIONS))
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "head")
        conn.commit()

    def revision(self) -> str | None:
        """The schema's migration revision (None: an empty database)."""
        with self._read("read the schema version") as conn:
            return _revision(conn)

    def close(self) -> None:
        self.engine.dispose()

    def __enter__(self) -> Archive:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- writing --------------------------------------------------------------------------

    def _insert(self) -> Any:
        if self.backend == "sqlite":
            return sqlite_insert
        return pg_insert

    def store(self, record: Mapping[str, Any], *, recording_sha256: str | None = None,
              source: str = "record.json") -> str:
        """Insert or replace one run (its unit, its row, its measurements) in one transaction;
        returns its run_id. Storing the same record twice leaves one run."""
        row = run_row(record, recording_sha256=recording_sha256, source=source)
        ms = measurement_rows(record)
        ins = self._insert()
        with self._tx(f"store run {row['run_id']}") as conn:
            u = ins(units).values(serial=row["serial"], part_number=row["part_number"])
            u = u.on_conflict_do_update(
                index_elements=[units.c.serial],
                set_={"part_number": func.coalesce(u.excluded.part_number, units.c.part_number)},
            ).returning(units.c.id)
            unit_id = conn.execute(u).scalar_one()
            values = {**row, "unit_id": unit_id}
            r = ins(runs).values(**values)
            r = r.on_conflict_do_update(
                index_elements=[runs.c.run_id],
                set_={k: r.excluded[k] for k in values if k != "run_id"},
            )
            conn.execute(r)
            conn.execute(delete(measurements).where(measurements.c.run_id == row["run_id"]))
            if ms:
                conn.execute(measurements.insert(), ms)
        return str(row["run_id"])

    # --- reading --------------------------------------------------------------------------

    def run_ids(self, among: Iterable[str] | None = None) -> set[str]:
        """The run_ids stored (only those in ``among`` when given)."""
        q = select(runs.c.run_id)
        if among is not None:
            ids = list(among)
            if not ids:
                return set()
            q = q.where(runs.c.run_id.in_(ids))
        with self._read("list runs") as conn:
            return {str(r[0]) for r in conn.execute(q)}

    def count(self) -> tuple[int, int]:
        """(runs, measurements) stored."""
        with self._read("count runs") as conn:
            n = conn.execute(select(func.count()).select_from(runs)).scalar_one()
            m = conn.execute(select(func.count()).select_from(measurements)).scalar_one()
        return int(n), int(m)

    def history(self, serial: str | None = None, *, since: datetime | None = None,
                station: str | None = None, limit: int | None = None) -> list[dict[str, Any]]:
        """Runs, oldest first, with each axis' σ (and its limit): filtered by serial, start
        time (naive UTC, ≥) and station."""
        q = select(runs).order_by(runs.c.start_utc, runs.c.run_id)
        if serial is not None:
            q = q.where(runs.c.serial == serial)
        if station is not None:
            q = q.where(runs.c.station == station)
        if since is not None:
            q = q.where(runs.c.start_utc >= since)
        with self._read("list runs") as conn:
            rows = [dict(r._mapping) for r in conn.execute(q)]
            if limit is not None:
                rows = rows[-limit:]
            sigmas = self._sigmas(conn, [r["run_id"] for r in rows])
        return [run_summary(r, sigmas.get(r["run_id"], [])) for r in rows]

    def _sigmas(self, conn: Connection, ids: Sequence[str]) -> dict[str, list[dict[str, Any]]]:
        out: dict[str, list[dict[str, Any]]] = {}
        for i in range(0, len(ids), 500):
            chunk = ids[i:i + 500]
            q = (select(measurements)
                 .where(measurements.c.run_id.in_(chunk), measurements.c.name == "sigma")
                 .order_by(measurements.c.run_id, measurements.c.seq))
            for m in conn.execute(q):
                out.setdefault(m.run_id, []).append(measurement_dict(dict(m._mapping)))
        return out

    def show(self, run_id: str) -> dict[str, Any] | None:
        """One run: its row, its measurements and its whole record; None when not stored."""
        with self._read(f"read run {run_id}") as conn:
            r = conn.execute(select(runs).where(runs.c.run_id == run_id)).first()
            if r is None:
                return None
            row = dict(r._mapping)
            ms = conn.execute(select(measurements).where(measurements.c.run_id == run_id)
                              .order_by(measurements.c.seq))
            mlist = [measurement_dict(dict(m._mapping)) for m in ms]
        out = run_summary(row, [m for m in mlist if m["name"] == "sigma"])
        out["measurements"] = mlist
        try:
            out["record"] = json.loads(row["record_json"])
        except ValueError:
            out["record"] = None
        return out

    def sigma_series(self, serial: str) -> list[dict[str, Any]]:
        """A unit's σ over its runs, oldest first: one entry per run and axis with σ, its 95 %
        interval, the limit and the outcome."""
        q = (select(runs.c.run_id, runs.c.start_utc, runs.c.station, runs.c.outcome,
                    measurements.c.axis, measurements.c.value, measurements.c.ci95_low,
                    measurements.c.ci95_high, measurements.c.high,
                    measurements.c.outcome.label("m_outcome"))
             .join(measurements, measurements.c.run_id == runs.c.run_id)
             .where(runs.c.serial == serial, measurements.c.name == "sigma")
             .order_by(runs.c.start_utc, runs.c.run_id, measurements.c.seq))
        with self._read(f"read σ of {serial}") as conn:
            return [
                {"run_id": r.run_id, "start_utc": iso(r.start_utc), "station": r.station,
                 "run_outcome": r.outcome, "axis": r.axis, "sigma": r.value,
                 "ci95": None if r.ci95_low is None or r.ci95_high is None
                 else [r.ci95_low, r.ci95_high],
                 "limit": r.high, "outcome": r.m_outcome}
                for r in conn.execute(q)
            ]

    def station_yield(self, station: str | None = None, *,
                      since: datetime | None = None) -> list[dict[str, Any]]:
        """Per station and UTC day: runs, how many passed, failed, were inconclusive or
        aborted, and the yield (passed / runs that reached a verdict: PASS, FAIL or
        INCONCLUSIVE; None on a day with none)."""
        q = select(runs.c.station, runs.c.start_utc, runs.c.outcome)
        if station is not None:
            q = q.where(runs.c.station == station)
        if since is not None:
            q = q.where(runs.c.start_utc >= since)
        days: dict[tuple[str, str], dict[str, int]] = {}
        with self._read("read the yield") as conn:
            for r in conn.execute(q):
                day = r.start_utc.date().isoformat() if r.start_utc is not None else "unknown"
                c = days.setdefault((r.station, day), dict.fromkeys(OUTCOMES, 0))
                if r.outcome in c:
                    c[r.outcome] += 1
        out = []
        for (st, day), c in sorted(days.items()):
            judged = c[Outcome.PASS] + c[Outcome.FAIL] + c[Outcome.INCONCLUSIVE]
            out.append({"station": st, "day": day, "runs": sum(c.values()),
                        "pass": c[Outcome.PASS], "fail": c[Outcome.FAIL],
                        "inconclusive": c[Outcome.INCONCLUSIVE], "aborted": c[Outcome.ABORTED],
                        "yield": None if judged == 0 else c[Outcome.PASS] / judged})
        return out













__all__ = ["OUTCOMES", "Archive", "parse_url", "shown"]
