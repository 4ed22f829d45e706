"""The results archive on both backends: SQLite (a file in tmp) and a
real PostgreSQL server started for this module in a temporary folder (``archive_helpers.
PgServer``: the distribution's initdb/pg_ctl; a machine without them FAILS these tests).

Schema from empty by the migrations (and equal to the Core tables), store/upsert with
measurements, history filters, show, the σ series and the yield per day, rebuild from
recordings (record.json, the fallback from meta/end/report, a killed run), an unreachable
archive → queue → sync, two processes writing at once, a session's run archived at its end,
the CLI (history --json/--csv/--html, show).

One file (about 630 lines): one PostgreSQL server is started per module, so the cases that
need it on both backends live together.
"""

from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
import time
import uuid
from html.parser import HTMLParser
from pathlib import Path

import pytest
from archive_helpers import SINE, PgServer, age, make_record, make_recording
from repo_paths import HELPERS
from sqlalchemy import inspect

from benchctl.archive.ingest import KILLED_REASON, record_of, recording_sha256
from benchctl.archive.rows import utc_naive
from benchctl.archive.schema import HEAD, metadata
from benchctl.archive.service import (
    ArchiveSettings,
    RunArchive,
    archive_at_start,
    archive_run,
    enqueue,
    queued,
    rebuild,
    refused,
    settings_for,
    sync,
)
from benchctl.archive.store import Archive, parse_url
from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.errors import ArchiveError, DataError

# the fixtures pg (a PostgreSQL server for the module) and url (an empty SQLite or PostgreSQL
# archive) are in conftest.py


# --- schema and store ------------------------------------------------------------------------

def test_migrations_create_the_schema_from_empty(url: str) -> None:
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    with Archive(url) as a:
        assert a.revision() == HEAD
        with a.engine.connect() as conn:
            names = set(inspect(conn).get_table_names())
            assert {"units", "runs", "measurements", "benchctl_archive_version"} <= names
            ctx = MigrationContext.configure(conn, opts={"compare_type": True})
            diff = [d for d in compare_metadata(ctx, metadata)
                    if not (isinstance(d, tuple) and "benchctl_archive_version" in str(d))]
        assert diff == [], diff  # the migrations build exactly the Core tables
    with Archive(url) as again:  # reopening an up-to-date archive changes nothing
        assert again.revision() == HEAD and again.count() == (0, 0)


def test_store_is_an_upsert_with_measurements(url: str) -> None:
    with Archive(url) as a:
        rec = make_record("R1", axes=("roll", "pitch"))
        a.store(rec)
        a.store(rec)
        assert a.count() == (1, 3)
        run = a.show("R1")
        assert run is not None
        assert run["serial"] == "SN-1" and run["part_number"] == "IN-100"
        assert run["outcome"] == "PASS" and run["decision_rule"] == "guarded"
        assert run["profile"] == {"name": "ci_short", "kind": "roll_spectrum", "seed": 7,
                                  "sha256": "ab" * 32}
        assert run["config_sha256"] == "cd" * 32 and run["software_version"] == "1.2.3"
        assert run["report_json"]["sha256"] == "ef" * 32
        assert run["start_utc"] == "2026-11-20T08:00:00.000+00:00"
        assert [m["name"] for m in run["measurements"]] == ["sigma", "sigma", "delay"]
        m0 = run["measurements"][0]
        assert m0 == {"name": "sigma", "axis": "roll", "value": pytest.approx(0.28),
                      "unit": "deg", "low": None, "high": 0.4,
                      "ci95": [pytest.approx(0.28 * 0.97), pytest.approx(0.28 * 1.03)],
                      "outcome": "PASS", "rule": "guarded"}
        assert run["record"] == rec
        # a new version of the same run replaces it whole: outcome, measurements, unit data
        rec2 = make_record("R1", outcome="FAIL", sigma=0.5, part_number=None)
        a.store(rec2)
        assert a.count() == (1, 2)
        run = a.show("R1")
        assert run is not None and run["outcome"] == "FAIL"
        assert run["sigma"] == {"roll": pytest.approx(0.5)}
        assert run["part_number"] is None
        assert a.show("nope") is None


def test_store_aborted_with_reason_and_seed_range(url: str) -> None:
    with Archive(url) as a:
        rec = make_record("A1", outcome="ABORTED",
                          abort={"kind": "operator", "reason": "interrupted by SIGINT"})
        rec["profile"]["seed"] = 2**63 - 1  # the largest seed the CLI takes
        a.store(rec)
        run = a.show("A1")
        assert run is not None
        assert run["abort"] == {"kind": "operator", "reason": "interrupted by SIGINT"}
        assert run["profile"]["seed"] == 2**63 - 1
        with pytest.raises(DataError, match="run_id"):
            a.store({"outcome": "PASS"})


def test_history_filters_sigma_series_and_yield(url: str) -> None:
    with Archive(url) as a:
        a.store(make_record("r1", serial="A", start="2026-11-20T08:00:00Z", sigma=0.20))
        a.store(make_record("r2", serial="A", start="2026-11-21T08:00:00Z", sigma=0.30,
                            station="bench-2"))
        a.store(make_record("r3", serial="A", start="2026-11-21T09:00:00Z", sigma=0.45,
                            outcome="FAIL"))
        a.store(make_record("r4", serial="B", start="2026-11-21T10:00:00Z",
                            outcome="INCONCLUSIVE"))
        a.store(make_record("r5", serial="B", start="2026-11-22T07:00:00+02:00",
                            outcome="ABORTED", abort={"kind": "equipment", "reason": "x"}))
        assert [r["run_id"] for r in a.history()] == ["r1", "r2", "r3", "r4", "r5"]
        assert [r["run_id"] for r in a.history("A")] == ["r1", "r2", "r3"]
        assert [r["run_id"] for r in a.history(station="bench-2")] == ["r2"]
        since = utc_naive("2026-11-21")
        assert [r["run_id"] for r in a.history(since=since)] == ["r2", "r3", "r4", "r5"]
        assert [r["run_id"] for r in a.history("B", since=utc_naive("2026-11-22"))] == ["r5"]
        assert a.history("A")[2]["sigma"] == {"roll": pytest.approx(0.45)}
        series = a.sigma_series("A")
        assert [(s["run_id"], s["sigma"], s["limit"]) for s in series] == [
            ("r1", pytest.approx(0.20), 0.4), ("r2", pytest.approx(0.30), 0.4),
            ("r3", pytest.approx(0.45), 0.4)]
        y = {(d["station"], d["day"]): d for d in a.station_yield()}
        assert y[("bench-1", "2026-11-21")] == {
            "station": "bench-1", "day": "2026-11-21", "runs": 2, "pass": 0, "fail": 1,
            "inconclusive": 1, "aborted": 0, "yield": 0.0}
        assert y[("bench-1", "2026-11-20")]["yield"] == 1.0
        # 07:00+02:00 is 05:00 UTC on the 22nd; only aborted: no yield that day
        assert y[("bench-1", "2026-11-22")]["aborted"] == 1
        assert y[("bench-1", "2026-11-22")]["yield"] is None
        assert [d["station"] for d in a.station_yield("bench-2")] == ["bench-2"]


def test_urls_are_checked_and_named() -> None:
    assert parse_url("postgresql://u:pw@h/db").drivername == "postgresql+psycopg"
    for bad in ("mysql://u@h/db", "sqlite://", "postgresql+psycopg2://u@h/db", "nonsense"):
        with pytest.raises(ArchiveError, match=r"archive\.url"):
            parse_url(bad)
    with pytest.raises(ArchiveError) as e:
        parse_url("postgresql+asyncpg://u:secret@h/db")
    assert "secret" not in str(e.value)


def test_config_archive_section(tmp_path: Path) -> None:
    from run_fakes import bench_config

    from benchctl.config import parse_config
    from benchctl.errors import ConfigError

    cfg = bench_config(tmp_path)
    s = settings_for(cfg)
    assert s.url == f"sqlite:///{tmp_path.resolve() / 'archive.sqlite'}"
    assert s.queue_dir == tmp_path.resolve() / "archive-queue" and s.enabled
    data = cfg.model_dump(mode="json", exclude={"source"})
    cfg2 = parse_config({**data, "archive": {"url": "sqlite:///db/a.sqlite",
                                             "queue_dir": "q", "enabled": False}},
                        tmp_path / "conf" / "bench.yaml")
    s2 = settings_for(cfg2)
    assert s2.url == f"sqlite:///{(tmp_path / 'conf' / 'db' / 'a.sqlite').resolve()}"
    assert s2.queue_dir == (tmp_path / "conf" / "q").resolve() and not s2.enabled
    with pytest.raises(ConfigError, match=r"field archive\.url = 'mysql://x/y'"):
        parse_config({**data, "archive": {"url": "mysql://x/y"}}, tmp_path / "b.yaml")


# --- recordings: record.json, the fallback, killed runs, rebuild ------------------------------

def test_rebuild_from_recordings(url: str, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    full = make_recording(runs, "20261120T080000Z_SN-1", record=make_record(
        "20261120T080000Z_SN-1", outcome="FAIL", sigma=0.45))
    old = make_recording(runs, "20261120T090000Z_SN-2", serial="SN-2", reason="PASS",
                         report={"verdict": "PASS", "exit_code": 0, "limit_sigma_deg": 0.4,
                                 "axes": {"roll": {"sigma": 0.21, "sigma_ci95": [0.2, 0.22],
                                                   "limit": 0.4, "verdict": "PASS"}}})
    aborted = make_recording(runs, "20261120T100000Z_SN-3", serial="SN-3", close="aborted",
                             reason="interrupted by SIGINT")
    killed = make_recording(runs, "20261120T110000Z_SN-4", serial="SN-4", close=None)
    age(killed, 3600)
    live = make_recording(runs, "20261120T120000Z_SN-5", serial="SN-5", close=None)
    with Archive(url) as a:
        res = rebuild(a, runs)
        assert sorted(res.stored) == sorted(p.name for p in (full, old, aborted, killed))
        assert len(res.skipped) == 1 and live.name in res.skipped[0]
        r = a.show(full.name)
        assert r is not None and r["outcome"] == "FAIL" and r["source"] == "record.json"
        assert r["recording"]["path"] == str(full.resolve())
        assert r["recording"]["sha256"] == recording_sha256(full)
        assert re.fullmatch(r"[0-9a-f]{64}", r["recording"]["sha256"])
        r = a.show(old.name)
        assert r is not None and r["outcome"] == "PASS" and r["source"] == "recording"
        assert r["sigma"] == {"roll": 0.21} and r["part_number"] == "IN-100"
        assert r["measurements"][0]["ci95"] == [0.2, 0.22]
        assert r["report_json"]["sha256"] is not None
        r = a.show(aborted.name)
        assert r is not None and r["outcome"] == "ABORTED"
        assert r["abort"] == {"kind": "operator", "reason": "interrupted by SIGINT"}
        r = a.show(killed.name)
        assert r is not None and r["outcome"] == "ABORTED" and r["source"] == "killed"
        assert r["abort"]["reason"] == KILLED_REASON
        assert a.count()[0] == 4
        # rebuilding again: the same four runs, nothing doubled
        rebuild(a, runs)
        assert a.count()[0] == 4


def test_nan_in_an_old_report_is_stored_as_null(url: str, tmp_path: Path) -> None:
    rec = make_recording(tmp_path, "N", report={"verdict": "PASS", "axes": {"roll": {
        "sigma": 0.2, "sigma_ci95": [float("nan"), 0.3], "limit": 0.4, "verdict": "PASS"}}})
    with Archive(url) as a:
        assert rebuild(a, rec).stored == ["N"]
        run = a.show("N")
    assert run is not None and run["measurements"][0]["ci95"] is None
    assert run["record"]["measurements"][0]["ci95"] == [None, 0.3]


def test_record_of_prefers_record_json_and_falls_back(tmp_path: Path) -> None:
    good = make_recording(tmp_path, "G", record=make_record("G", outcome="FAIL"))
    rec, source = record_of(good)
    assert source == "record.json" and rec["outcome"] == "FAIL"
    (good / "record.json").write_text("{torn")  # unreadable: built from the recording
    rec, source = record_of(good)
    assert source == "recording" and rec["outcome"] == "PASS"  # end.json: done, PASS
    assert rec["run_id"] == "G" and rec["unit"]["serial"] == "SN-1"
    killed = make_recording(tmp_path, "K", close=None)
    (killed / "record.json").write_text(json.dumps(make_record("K")))
    rec, source = record_of(killed)  # no end.json: killed, whatever a record says
    assert source == "killed" and rec["outcome"] == "ABORTED"
    assert rec["abort"]["reason"] == KILLED_REASON


def test_recording_sha256_covers_the_recording(tmp_path: Path) -> None:
    rec = make_recording(tmp_path, "R")
    before = recording_sha256(rec)
    (rec / "report.txt").write_text("a report is not part of the recording")
    assert recording_sha256(rec) == before
    with open(rec / "instrument.csv", "a") as f:
        f.write("1,,,,0.5\n")
    assert recording_sha256(rec) != before


def test_killed_runs_found_at_the_next_start(url: str, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    done = make_recording(runs, "20261120T080000Z_SN-1", record=make_record(
        "20261120T080000Z_SN-1"))
    killed = make_recording(runs, "20261120T090000Z_SN-2", close=None, serial="SN-2")
    age(killed, 600)
    live = make_recording(runs, "20261120T100000Z_SN-3", close=None, serial="SN-3")
    s = ArchiveSettings(url, tmp_path / "queue")
    got = archive_at_start(s, runs)
    assert got["killed"] == [killed.name] and got["queued"] == []
    with Archive(url) as a:
        assert a.run_ids() == {killed.name}  # the finished run is its own run's business
        r = a.show(killed.name)
        assert r is not None and r["outcome"] == "ABORTED"
        assert r["abort"] == {"kind": "software", "reason": KILLED_REASON}
    assert archive_at_start(s, runs)["killed"] == []  # once only
    assert done.exists() and live.exists()


# --- unreachable → queue → sync ----------------------------------------------------------------

def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_unreachable_archive_queues_then_sync(url: str, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    rec = make_recording(runs, "20261120T080000Z_SN-1", record=make_record(
        "20261120T080000Z_SN-1", sigma=0.3))
    queue = tmp_path / "queue"
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    for dead in (f"postgresql+psycopg://bench@127.0.0.1:{_closed_port()}/postgres",
                 f"sqlite:///{blocker / 'sub' / 'archive.sqlite'}"):
        t0 = time.monotonic()
        assert archive_run(ArchiveSettings(dead, queue), rec) == "queued"
        assert time.monotonic() - t0 < 5.0
    files = queued(queue)
    assert [p.name for p in files] == [f"{rec.name}.json"]  # one entry per run
    res = sync(ArchiveSettings(url, queue))
    assert res.sent == [rec.name] and res.left == 0 and queued(queue) == []
    with Archive(url) as a:
        r = a.show(rec.name)
        assert r is not None and r["sigma"] == {"roll": pytest.approx(0.3)}
        assert r["recording"]["sha256"] == recording_sha256(rec)
    # an empty queue syncs to nothing without opening anything
    assert sync(ArchiveSettings("sqlite:////proc/none/x.sqlite", queue)).sent == []


def test_queued_warning_hides_the_password_and_disabled_does_nothing(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    rec = make_recording(tmp_path / "runs", "R", record=make_record("R"))
    dead = f"postgresql+psycopg://bench:s3cret@127.0.0.1:{_closed_port()}/x"
    with caplog.at_level("WARNING"):
        assert archive_run(ArchiveSettings(dead, tmp_path / "q"), rec) == "queued"
    assert "queued" in caplog.text and "s3cret" not in caplog.text
    assert "bench:***@127.0.0.1" in caplog.text
    off = ArchiveSettings(f"sqlite:///{tmp_path / 'off.sqlite'}", tmp_path / "q2", enabled=False)
    assert archive_run(off, rec) == "disabled"
    killed = make_recording(tmp_path / "runs", "K", close=None)
    age(killed, 3600)
    assert archive_at_start(off, tmp_path / "runs") == {"killed": [], "queued": [],
                                                         "synced": []}
    assert not (tmp_path / "off.sqlite").exists() and not (tmp_path / "q2").exists()


def test_a_silent_server_delays_the_run_by_the_connect_timeout_only(tmp_path: Path) -> None:
    """A port that takes the connection and never answers (a hung server): the record is
    queued after the ~2 s connect timeout."""
    rec = make_recording(tmp_path / "runs", "R", record=make_record("R"))
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(8)
        port = srv.getsockname()[1]
        s = ArchiveSettings(f"postgresql+psycopg://bench@127.0.0.1:{port}/db", tmp_path / "q",
                            connect_timeout_s=2.0)
        t0 = time.monotonic()
        assert archive_run(s, rec) == "queued"
        took = time.monotonic() - t0
    assert 1.5 < took < 8.0, took
    assert len(queued(tmp_path / "q")) == 1


def test_a_run_does_not_wait_for_a_hung_archive_at_its_start_or_its_end(tmp_path: Path) -> None:
    """``RunArchive``: the start's database work (a killed run to store, the queue to send)
    goes to the background — begin() has returned while its connection to a server that never
    answers is still pending — and at the end, the database known out of reach, the run's
    record is queued at once: no second connection is tried."""
    runs = tmp_path / "runs"
    killed = make_recording(runs, "20261120T090000Z_SN-2", close=None, serial="SN-2")
    age(killed, 600)
    rec = make_recording(runs, "20261120T100000Z_SN-3", record=make_record(
        "20261120T100000Z_SN-3", serial="SN-3"))
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(8)
        srv.settimeout(30.0)  # generous: a loaded machine
        port = srv.getsockname()[1]
        s = ArchiveSettings(f"postgresql+psycopg://bench@127.0.0.1:{port}/db", tmp_path / "q",
                            connect_timeout_s=2.0)
        ra = RunArchive(s, runs)
        ra.begin()
        conn, _ = srv.accept()  # the background thread's connection, waiting for a reply
        with conn:
            assert ra.reachable is None  # begin() did not wait for it
            assert ra.end(rec) == "queued"
        assert ra.reachable is False
        assert ra.start_result["queued"] == [killed.name]  # the killed run, queued too
        srv.settimeout(0.0)
        with pytest.raises(BlockingIOError):  # the end tried no second connection
            srv.accept()
    assert sorted(p.name for p in queued(tmp_path / "q")) == [
        f"{killed.name}.json", f"{rec.name}.json"]


def test_a_run_archive_stores_at_its_end_what_it_found_reachable(url: str, tmp_path: Path
                                                                 ) -> None:
    runs = tmp_path / "runs"
    killed = make_recording(runs, "20261120T090000Z_SN-2", close=None, serial="SN-2")
    age(killed, 600)
    enqueue(tmp_path / "q", {"record": make_record("20261119T080000Z_SN-1"),
                             "recording_sha256": None, "source": "record.json"})
    ra = RunArchive(ArchiveSettings(url, tmp_path / "q"), runs)
    ra.begin()
    rec = make_recording(runs, "20261120T100000Z_SN-3", record=make_record(
        "20261120T100000Z_SN-3", serial="SN-3"))  # the run's own, made after begin()
    assert ra.end(rec) == "stored" and ra.reachable is True
    assert ra.start_result == {"killed": [killed.name], "queued": [],
                               "synced": ["20261119T080000Z_SN-1"]}
    with Archive(url) as a:
        assert a.run_ids() == {killed.name, rec.name, "20261119T080000Z_SN-1"}
    assert queued(tmp_path / "q") == []


def test_sync_sets_an_unreadable_entry_aside_and_fails_on_a_dead_archive(tmp_path: Path) -> None:
    q = tmp_path / "q"
    enqueue(q, {"record": make_record("ok"), "recording_sha256": None, "source": "record.json"})
    (q / "broken.json").write_text("{not json")
    (q / "no-id.json").write_text(json.dumps({"record": {"outcome": "PASS"}}))
    dead = ArchiveSettings(f"postgresql+psycopg://bench@127.0.0.1:{_closed_port()}/x", q)
    with pytest.raises(ArchiveError, match="connection"):
        sync(dead)
    assert len(queued(q)) == 3  # nothing left the queue
    res = sync(ArchiveSettings(f"sqlite:///{tmp_path / 'a.sqlite'}", q))
    # files that are not queued records are set aside with their reason, not sent again
    assert res.sent == ["ok"] and res.left == 0
    assert sorted(r.split(":")[0] for r in res.refused) == ["broken.json", "no-id.json"]
    assert sorted(r["file"] for r in refused(q)) == ["broken.json", "no-id.json"]


def test_a_second_bench_on_a_shared_postgresql_archive(
        pg: PgServer, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The README's worked example: bench 1 fills the shared database from its recordings,
    bench 2 (its own config, station and output folder, the same archive.url) adds its run;
    history from bench 1's config shows both stations."""
    import yaml
    from run_fakes import bench_config

    shared = pg.create_database(f"t_{uuid.uuid4().hex[:12]}")
    configs = []
    for n in (1, 2):
        base = bench_config(tmp_path / f"b{n}").model_dump(mode="json", exclude={"source"})
        base["station"] = f"bench-{n}"
        base["run"]["output_dir"] = str(tmp_path / f"b{n}" / "runs")
        base["archive"] = {"url": shared}
        path = tmp_path / f"bench{n}.yaml"
        path.write_text(yaml.safe_dump(base))
        configs.append(path)
    runs1 = tmp_path / "b1" / "runs"
    r1 = make_recording(runs1, "20261120T080000Z_INC-1", serial="INC-1", station="bench-1",
                        record=make_record("20261120T080000Z_INC-1", serial="INC-1"))
    assert main(["archive", "rebuild", str(runs1), "--config", str(configs[0])]) == 0
    capsys.readouterr()
    from benchctl.config import load_config

    cfg2 = load_config(configs[1])
    r2 = make_recording(cfg2.run.output_dir, "20261121T080000Z_INC-1", serial="INC-1",
                        station="bench-2", record=make_record(
                            "20261121T080000Z_INC-1", serial="INC-1", station="bench-2",
                            start="2026-11-21T08:00:00Z", outcome="FAIL"))
    assert archive_run(settings_for(cfg2), r2) == "stored"
    assert main(["history", "INC-1", "--config", str(configs[0]), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [(r["run_id"], r["station"]) for r in out["runs"]] == [
        (r1.name, "bench-1"), (r2.name, "bench-2")]
    # the unit's yield per day (its own runs, on either bench)
    assert {(d["day"], d["yield"]) for d in out["yield_per_day"]} == {
        ("2026-11-20", 1.0), ("2026-11-21", 0.0)}
    assert not (runs1 / "archive.sqlite").exists()  # nothing went to a local file


# --- two writers --------------------------------------------------------------------------------

def test_two_processes_writing_at_once_lose_nothing(url: str) -> None:
    """Two processes open the same new archive (both migrate) and store 50 runs each, 10 of
    them the same run_ids, over 5 shared serials."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); from archive_helpers import "
            "write_many; print(write_many(sys.argv[2], int(sys.argv[3]), 50, 10))")
    procs = [subprocess.Popen([sys.executable, "-c", code, str(HELPERS), url,
                               str(w)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for w in (1, 2)]
    outs = [p.communicate(timeout=240) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    assert [o[0].strip() for o in outs] == ["60", "60"]
    with Archive(url) as a:
        assert a.count() == (110, 110 * 3)
        assert len(a.history("SN-0")) == 10 + 10 + 2
        ids = a.run_ids()
        assert {f"w{w}-{i:03d}" for w in (1, 2) for i in range(50)} <= ids
        with a.engine.connect() as conn:
            from sqlalchemy import func, select

            from benchctl.archive.schema import units
            assert conn.execute(select(func.count()).select_from(units)).scalar_one() == 5


# --- a run through the session --------------------------------------------------------------


def test_a_run_is_archived_at_its_end_with_the_killed_and_queued_before_it(
        tmp_path: Path, vclock: VirtualClock) -> None:
    """run_test with in-process fakes of the stand and the instrument, on simulated time (the
    archive's database on the host's): at its start the killed run left in the output folder
    is stored ABORTED and the queue is sent; at its end the run itself is stored from its own
    record.json."""
    from run_fakes import FakeSensor, FakeStand, bench_config

    from benchctl.run.prepare import RunOptions
    from benchctl.run.session import run_test

    cfg = bench_config(tmp_path)
    s = settings_for(cfg)
    killed = make_recording(tmp_path, "20261120T080000Z_OLD", serial="OLD", close=None)
    age(killed, 3600)
    enqueue(s.queue_dir, {"record": make_record("queued-1"), "recording_sha256": None,
                          "source": "record.json"})
    profile = tmp_path / "sine.yaml"
    profile.write_text(SINE)
    stand = FakeStand(("roll",), clock=vclock)
    sensor = FakeSensor(stand, gain=1.05)
    res = run_test(cfg, profile, RunOptions("SN-A", "tester"),
                   device_factory=lambda c, p: (stand, sensor), clock=vclock)
    assert res.state == "done" and res.report is not None, res.reason
    assert res.recording is not None
    with Archive(s.url) as a:
        assert a.run_ids() == {killed.name, "queued-1", res.recording.name}
        old = a.show(killed.name)
        run = a.show(res.recording.name)
    assert queued(s.queue_dir) == []
    assert old is not None and old["outcome"] == "ABORTED"
    assert old["abort"] == {"kind": "software", "reason": KILLED_REASON}
    assert run is not None
    assert run["outcome"] == res.report.verdict
    assert run["serial"] == "SN-A" and run["station"] == "test-bench"
    assert run["operator"] == "tester" and run["profile"]["name"] == "archive_sine"
    assert run["sigma"]["roll"] == pytest.approx(res.report.axes["roll"].sigma_deg, rel=1e-9)
    assert run["recording"]["sha256"] == recording_sha256(res.recording)
    assert run["source"] == "record.json"  # the run's own record (benchctl.results.record)
    own = json.loads((res.recording / "record.json").read_text())
    assert run["record"] == own
    assert [m["name"] for m in run["measurements"]] == [m["name"] for m in own["measurements"]]
    assert run["report_json"]["sha256"] == own["files"]["report_json"]["sha256"]


def test_an_aborted_run_is_archived_with_its_abort(tmp_path: Path, vclock: VirtualClock) -> None:
    """An E-stop mid-motion (simulated time): the run is ABORTED (equipment) and so is its
    archived row."""
    from run_fakes import FakeSensor, FakeStand, bench_config

    from benchctl.run.prepare import RunOptions
    from benchctl.run.session import run_test

    cfg = bench_config(tmp_path)
    profile = tmp_path / "sine.yaml"
    profile.write_text(SINE)
    stand = FakeStand(("roll",), clock=vclock)
    stand.estop_at = 1.0
    sensor = FakeSensor(stand)
    res = run_test(cfg, profile, RunOptions("SN-E", "tester"),
                   device_factory=lambda c, p: (stand, sensor), clock=vclock)
    assert res.state == "aborted" and res.recording is not None
    with Archive(settings_for(cfg).url) as a:
        run = a.show(res.recording.name)
    assert run is not None and run["outcome"] == "ABORTED" and run["exit_code"] == 2
    assert res.abort is not None
    assert run["abort"] == {"kind": res.abort["kind"], "reason": res.reason}
    assert run["abort"]["kind"] == "equipment" and "E-stop" in run["abort"]["reason"]


# --- the CLI ------------------------------------------------------------------------------------

class _Page(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[str] = []
        self.classes: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        self.classes += [v or "" for k, v in attrs if k == "class"]


def test_cli_history_show_and_html(url: str, tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    with Archive(url) as a:
        a.store(make_record("r1", serial="A", start="2026-11-20T08:00:00Z", sigma=0.2))
        a.store(make_record("r2", serial="A", start="2026-11-21T08:00:00Z", sigma=0.3,
                            operator="<script>alert(1)</script>"))
        a.store(make_record("r3", serial="B", start="2026-11-21T09:00:00Z", outcome="FAIL"))
    assert main(["history", "--url", url, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [r["run_id"] for r in out["runs"]] == ["r1", "r2", "r3"]
    assert {(d["day"], d["yield"]) for d in out["yield_per_day"]} == {
        ("2026-11-20", 1.0), ("2026-11-21", 0.5)}
    assert main(["history", "A", "--since", "2026-11-21", "--url", url, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [r["run_id"] for r in out["runs"]] == ["r2"]
    assert [s["run_id"] for s in out["sigma"]] == ["r2"]
    assert main(["history", "--station", "bench-1", "--url", url, "--csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("run_id,start_utc,serial") and len(lines) == 4
    page = tmp_path / "h.html"
    assert main(["history", "A", "--url", url, "--html", str(page)]) == 0
    text = capsys.readouterr().out
    assert "r1" in text and "r2" in text and "r3" not in text
    html = page.read_text()
    assert "<script" not in html and "&lt;script&gt;" in html  # escaped, no script at all
    assert "http" not in html.replace('xmlns="http://www.w3.org/2000/svg"', "")
    p = _Page()
    p.feed(html)
    assert p.tags.count("svg") == 2  # σ over runs, yield per day (bench-1)
    assert p.classes.count("limit") == 1 and p.classes.count("sigma") == 1
    assert p.classes.count("yield") == 2
    assert main(["show", "r2", "--url", url, "--json"]) == 0
    shown = json.loads(capsys.readouterr().out)
    assert shown["run_id"] == "r2" and shown["record"]["run_id"] == "r2"
    assert main(["show", "r2", "--url", url]) == 0
    assert "sigma roll" in capsys.readouterr().out
    assert main(["show", "nope", "--url", url]) == 2
    assert "not in the archive" in capsys.readouterr().err
    with pytest.raises(SystemExit) as bad:  # argparse: a usage error, exit 2
        main(["history", "--since", "yesterday", "--url", url])
    assert bad.value.code == 2
    assert "expected a date YYYY-MM-DD" in capsys.readouterr().err


def test_cli_archive_rebuild_and_sync(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    runs = tmp_path / "runs"
    rec = make_recording(runs, "20261120T080000Z_SN-1", record=make_record(
        "20261120T080000Z_SN-1"))
    assert main(["archive", "rebuild", str(runs), "--out", str(runs), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stored"] == [rec.name]
    assert (runs / "archive.sqlite").is_file()
    s = settings_for(None, runs)
    enqueue(s.queue_dir, {"record": make_record("queued-1"), "recording_sha256": None,
                          "source": "record.json"})
    assert main(["archive", "sync", "--out", str(runs)]) == 0
    assert "sent 1 run(s)" in capsys.readouterr().out
    assert main(["history", "--out", str(runs), "--json"]) == 0
    ids = [r["run_id"] for r in json.loads(capsys.readouterr().out)["runs"]]
    assert sorted(ids) == sorted([rec.name, "queued-1"])
    assert main(["archive", "sync", "--url", "mysql://x/y"]) == 2
    assert "--url" in capsys.readouterr().err
    empty = tmp_path / "empty"
    assert main(["history", "--out", str(empty)]) == 2
    assert "no such file" in capsys.readouterr().err and not empty.exists()

