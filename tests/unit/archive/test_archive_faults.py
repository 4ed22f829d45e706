"""The archive never blocks a run and never jams its queue, on a real PostgreSQL
(``archive_helpers.PgServer``) and on SQLite:

- a record the database refuses (a NUL character PostgreSQL cannot store; an integer out of
  SQLite's range) between two good ones in the queue: the good ones are stored, the bad one
  set aside in ``<queue>/refused/`` with its reason, listed by ``benchctl archive status``,
  and ``sync`` says "refused"; ``archive rebuild`` goes past such a recording too;
- another session holding ``LOCK TABLE runs IN ACCESS EXCLUSIVE MODE`` (PostgreSQL), or a
  write transaction on the file (SQLite): the run's final write gives up within its lock
  timeout, the record is queued, the log says "locked" and the run returns seconds after its
  verdict (bounded generously: 30 s; without a timeout it waited for ever);
- a read-only SQLite file: "read-only", the record queued;
- a database that stops answering in the middle of a statement (no server-side timeout can
  bound that): the run's end queues the record after its bound and returns.
"""

from __future__ import annotations

import json
import logging
import os
import pickle
import pwd
import socket
import sqlite3
import tempfile
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from archive_helpers import SINE, PgServer, make_record, make_recording
from sqlalchemy.exc import OperationalError

from benchctl.archive.failures import classify
from benchctl.archive.service import (
    ArchiveSettings,
    archive_run,
    enqueue,
    queued,
    refused,
    settings_for,
    sync,
)
from benchctl.archive.store import Archive
from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.config import ArchiveConfig

# the fixtures pg (a PostgreSQL server for the module) and url (an empty SQLite or PostgreSQL
# archive) are in conftest.py


def _bad(url: str, run_id: str, **kw: Any) -> dict[str, Any]:
    """A record this database cannot store: a NUL in the operator's name on PostgreSQL
    (text cannot hold one), an exit code beyond 64 bits on SQLite."""
    rec = make_record(run_id, **kw)
    if url.startswith("sqlite"):
        rec["exit_code"] = 2**70
    else:
        rec["operator"] = "an\x00na"
    return rec


def _entry(record: dict[str, Any]) -> dict[str, Any]:
    return {"record": record, "recording_sha256": None, "source": "record.json"}


# --- a refused record is set aside; the rest goes on --------------------------------------------

def test_a_refused_record_is_set_aside_and_the_queue_goes_on(
        url: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "runs"
    q = settings_for(None, out).queue_dir
    t = time.time() - 100
    for i, rec in enumerate((make_record("good-1"), _bad(url, "bad-2"), make_record("good-3"))):
        p = enqueue(q, _entry(rec))
        os.utime(p, (t + i, t + i))  # queued in this order: the bad one in the middle
    assert main(["archive", "sync", "--url", url, "--out", str(out)]) == 2
    printed = capsys.readouterr().out
    assert "sent 2 run(s)" in printed and "0 left" in printed
    assert "refused" in printed and "bad-2.json" in printed and "unreachable" not in printed
    with Archive(url) as a:
        assert a.run_ids() == {"good-1", "good-3"}
    assert queued(q) == []
    (aside,) = refused(q)
    assert aside["file"] == "bad-2.json" and "refused" in aside["reason"]
    assert ("NUL" in aside["reason"]) if url.startswith("postgresql") else (
        "too large" in aside["reason"] or "overflow" in aside["reason"].lower())
    assert json.loads((q / "refused" / "bad-2.json").read_text())["record"]["run_id"] == "bad-2"
    # listed by archive status (which opens no database), with its reason
    assert main(["archive", "status", "--url", url, "--out", str(out)]) == 0
    status = capsys.readouterr().out
    assert "0 record(s) waiting" in status and "refused  bad-2.json" in status
    assert main(["archive", "status", "--url", url, "--out", str(out), "--json"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert js["queued"] == [] and [r["file"] for r in js["refused"]] == ["bad-2.json"]
    # sync again: nothing left to jam on
    assert main(["archive", "sync", "--url", url, "--out", str(out)]) == 0
    assert "empty, nothing to send" in capsys.readouterr().out


def test_rebuild_goes_past_a_refused_recording(url: str, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    for name, rec in (("A-1", make_record("A-1")), ("A-2", _bad(url, "A-2")),
                      ("A-3", make_record("A-3"))):
        make_recording(runs, name, record=rec)
    assert main(["archive", "rebuild", str(runs), "--url", url]) == 2
    printed = capsys.readouterr().out
    assert "stored 2 run(s)" in printed and "refused A-2" in printed
    with Archive(url) as a:
        assert a.run_ids() == {"A-1", "A-3"}


def test_a_runs_own_refused_record_is_set_aside_at_once(
        url: str, tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    rec = make_recording(tmp_path / "runs", "R-1", record=_bad(url, "R-1"))
    q = tmp_path / "q"
    with caplog.at_level(logging.WARNING):
        assert archive_run(ArchiveSettings(url, q), rec) == "refused"
    assert "refused" in caplog.text and queued(q) == []
    assert [r["file"] for r in refused(q)] == ["R-1.json"]


# --- a lock held by another session: the run gives up in seconds ---------------------------------

def _run_in_thread(fn: Callable[[], Any], bound_s: float) -> tuple[bool, Any]:
    """``fn()`` in a thread, waited for at most ``bound_s``: (finished, its result)."""
    box: dict[str, Any] = {}

    def go() -> None:
        try:
            box["result"] = fn()
        except BaseException as e:  # reported, not lost in the thread
            box["result"] = e

    t = threading.Thread(target=go, daemon=True)
    t.start()
    t.join(bound_s)
    return not t.is_alive(), box.get("result")


@pytest.mark.slow
def test_a_locked_runs_table_costs_the_run_seconds_not_for_ever(
        pg: PgServer, tmp_path: Path, caplog: pytest.LogCaptureFixture,
        capsys: pytest.CaptureFixture[str], vclock: VirtualClock) -> None:
    """A whole run (in-process fakes of the stand and the instrument, on simulated time; the
    database and its lock on the host's time) archiving into a PostgreSQL database while
    another session holds ``runs`` in ACCESS EXCLUSIVE mode. The run is in this thread: were
    it to wait for the lock for ever, the test's timeout would end it."""
    import psycopg
    from run_fakes import FakeSensor, FakeStand, bench_config

    from benchctl.run.prepare import RunOptions
    from benchctl.run.session import run_test

    url = pg.create_database(f"l_{uuid.uuid4().hex[:12]}")
    with Archive(url):
        pass  # the schema made
    cfg = bench_config(tmp_path)
    # the run's lock timeout 0.5 s (default 2 s): another session holds the lock for sure
    cfg = cfg.model_copy(update={"archive": ArchiveConfig(url=url, write_timeout_s=0.5)})
    profile = tmp_path / "sine.yaml"
    profile.write_text(SINE)
    stand = FakeStand(("roll",), clock=vclock)
    holder = psycopg.connect(url.replace("+psycopg", ""), connect_timeout=30)
    try:
        holder.execute("LOCK TABLE runs IN ACCESS EXCLUSIVE MODE")  # a transaction, kept open
        with caplog.at_level(logging.WARNING):
            res = run_test(cfg, profile, RunOptions("SN-L", "tester"),
                           device_factory=lambda c, p: (stand, FakeSensor(stand)), clock=vclock)
            returned = time.time()
        assert res.state == "done" and res.recording is not None, res.reason
        verdict_at = (res.recording / "end.json").stat().st_mtime
        assert returned - verdict_at < 30.0, returned - verdict_at
        assert [p.name for p in queued(tmp_path / "archive-queue")] == [
            f"{res.recording.name}.json"]
        assert "locked" in caplog.text and "is unreachable" not in caplog.text
        # archive sync meanwhile: stops at the lock, says so, keeps the queue
        t0 = time.monotonic()
        assert main(["archive", "sync", "--url", url, "--out", str(tmp_path)]) == 2
        assert time.monotonic() - t0 < 30.0
        printed = capsys.readouterr().out
        assert "stopped" in printed and "locked" in printed, printed
        assert len(queued(tmp_path / "archive-queue")) == 1
    finally:
        holder.rollback()
        holder.close()
    assert main(["archive", "sync", "--url", url, "--out", str(tmp_path)]) == 0
    with Archive(url) as a:
        assert res.recording.name in a.run_ids()


def test_a_busy_sqlite_file_is_said_locked(tmp_path: Path,
                                           caplog: pytest.LogCaptureFixture) -> None:
    db = tmp_path / "archive.sqlite"
    url = f"sqlite:///{db}"
    with Archive(url):
        pass
    rec = make_recording(tmp_path / "runs", "R-1", record=make_record("R-1"))
    other = sqlite3.connect(db, isolation_level=None)
    try:
        other.execute("BEGIN IMMEDIATE")  # another writer, holding the file
        t0 = time.monotonic()
        with caplog.at_level(logging.WARNING):
            assert archive_run(ArchiveSettings(url, tmp_path / "q", write_timeout_s=1.0),
                               rec) == "queued"
        assert time.monotonic() - t0 < 30.0
    finally:
        other.execute("ROLLBACK")
        other.close()
    assert "locked" in caplog.text and "is unreachable" not in caplog.text
    assert len(queued(tmp_path / "q")) == 1


def test_the_timeouts_reach_the_postgresql_session(pg: PgServer) -> None:
    url = pg.create_database(f"t_{uuid.uuid4().hex[:12]}")
    with Archive(url, busy_timeout_s=0.5, statement_timeout_s=1.0) as a, \
            a.engine.connect() as conn:
        from sqlalchemy import text

        assert conn.execute(text("SHOW lock_timeout")).scalar() == "500ms"
        assert conn.execute(text("SHOW statement_timeout")).scalar() == "1s"
        with pytest.raises(OperationalError) as e:
            conn.execute(text("SELECT pg_sleep(10)"))
        assert classify(e.value) == "timed out"


# --- a read-only SQLite file ---------------------------------------------------------------------

def _unprivileged(fn: Callable[[], Any]) -> Any:
    """``fn()``'s result, run as a user who cannot write what root could: in a forked child
    that drops to ``nobody`` when the tests run as root, in this process otherwise."""
    if os.geteuid() != 0:
        return fn()
    pw = pwd.getpwnam("nobody")
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: never returns into pytest
        code = 0
        try:
            os.close(r)
            os.setgroups([])
            os.setgid(pw.pw_gid)
            os.setuid(pw.pw_uid)
            data = pickle.dumps(fn())
        except BaseException as e:
            data = pickle.dumps(RuntimeError(f"{type(e).__name__}: {e}"))
            code = 1
        with os.fdopen(w, "wb") as f:
            f.write(data)
        os._exit(code)
    os.close(w)
    with os.fdopen(r, "rb") as f:
        data = f.read()
    os.waitpid(pid, 0)
    out = pickle.loads(data)
    if isinstance(out, BaseException):
        raise out
    return out


def test_a_read_only_sqlite_file_is_said_read_only() -> None:
    top = Path(tempfile.mkdtemp(prefix="benchctl-ro-"))  # reachable by nobody (not 0700)
    try:
        top.chmod(0o755)
        db_dir = top / "db"
        db_dir.mkdir()
        url = f"sqlite:///{db_dir / 'archive.sqlite'}"
        with Archive(url) as a:
            a.store(make_record("old"))
        rec = make_recording(top / "runs", "R-1", record=make_record("R-1"))
        for p in (top / "runs", rec, *rec.iterdir()):
            p.chmod(0o755 if p.is_dir() else 0o644)
        q = top / "q"
        q.mkdir()
        q.chmod(0o777)
        for p in db_dir.iterdir():
            p.chmod(0o444)
        db_dir.chmod(0o555)

        def store() -> tuple[str, str]:
            log = logging.getLogger("benchctl.archive")
            lines: list[str] = []

            class Keep(logging.Handler):
                def emit(self, record: logging.LogRecord) -> None:
                    lines.append(record.getMessage())

            h = Keep(logging.WARNING)
            log.addHandler(h)
            try:
                return archive_run(ArchiveSettings(url, q), rec), "\n".join(lines)
            finally:
                log.removeHandler(h)

        what, said = _unprivileged(store)
        assert what == "queued", said
        assert "read-only" in said and "unreachable" not in said, said
        assert [p.name for p in queued(q)] == ["R-1.json"]
    finally:
        db_dir.chmod(0o755)
        import shutil

        shutil.rmtree(top, ignore_errors=True)


def test_unreachable_is_still_said_unreachable(tmp_path: Path,
                                               caplog: pytest.LogCaptureFixture) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    rec = make_recording(tmp_path / "runs", "R-1", record=make_record("R-1"))
    with caplog.at_level(logging.WARNING):
        assert archive_run(ArchiveSettings(
            f"postgresql+psycopg://bench@127.0.0.1:{port}/x", tmp_path / "q"), rec) == "queued"
    assert "is unreachable" in caplog.text
    with pytest.raises(Exception, match="unreachable"):
        sync(ArchiveSettings(f"postgresql+psycopg://bench@127.0.0.1:{port}/x", tmp_path / "q"))


def test_a_database_that_stops_answering_mid_statement_costs_the_run_its_bound(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        caplog: pytest.LogCaptureFixture) -> None:
    """What no server-side timeout can bound — a server stopped, or the network gone, in
    the middle of a statement — stands here as a store that never returns: the run's end
    queues the record after ``end_bound_s`` and returns."""
    from benchctl.archive.service import RunArchive, end_bound_s

    release = threading.Event()

    def hung(self: Archive, *a: Any, **kw: Any) -> str:
        release.wait(120.0)
        raise RuntimeError("released")

    monkeypatch.setattr(Archive, "store", hung)
    s = ArchiveSettings(f"sqlite:///{tmp_path / 'a.sqlite'}", tmp_path / "q",
                        connect_timeout_s=1.0, write_timeout_s=0.5)
    rec = make_recording(tmp_path / "runs", "R-1", record=make_record("R-1"))
    ra = RunArchive(s, tmp_path / "runs")
    ra.begin()
    try:
        with caplog.at_level(logging.WARNING):
            t0 = time.monotonic()
            finished, what = _run_in_thread(lambda: ra.end(rec), 60.0)
            took = time.monotonic() - t0
        assert finished and what == "queued", what
        assert end_bound_s(s) - 0.5 < took < end_bound_s(s) + 20.0, took
        assert "did not answer within" in caplog.text
        assert [p.name for p in queued(tmp_path / "q")] == ["R-1.json"]
    finally:
        release.set()
