"""The line view's data against a real PostgreSQL: two stations' runs and heartbeats, every
figure checked against the runs stored (hand-counted yields, hand-computed chart lines)."""

from __future__ import annotations

import math
import threading
from datetime import UTC, date, datetime, timedelta
from pathlib import Path

import pytest
from line_helpers import (
    DAY,
    HOSTILE_SERIAL,
    HOSTILE_STATION,
    IN_100,
    IN_200,
    age_heartbeat,
    fill_two_stations,
)
from sqlalchemy import inspect

from benchctl.archive.store import Archive
from benchctl.errors import ArchiveError, InputError
from benchctl.web.linedata import line_view, sigma_charts
from benchctl.web.linestations import (
    STALE_AFTER_S,
    TABLE,
    Heartbeat,
    Presence,
    StationBoard,
    StationState,
    presence,
    publish_station_state,
)

TOL = 1e-9


def test_presence_by_age() -> None:
    t0 = datetime(2026, 11, 20, 8, 0, 0)
    hb = Heartbeat(station="b", state="running", updated_utc=t0)
    assert presence(hb, t0 + timedelta(seconds=STALE_AFTER_S)) is Presence.RUNNING
    assert presence(hb, t0 + timedelta(seconds=STALE_AFTER_S + 0.001)) is Presence.OFFLINE
    idle = Heartbeat(station="b", state="idle", updated_utc=t0)
    assert presence(idle, t0 + timedelta(seconds=3), stale_after_s=5) is Presence.IDLE
    assert presence(idle, t0 + timedelta(seconds=6), stale_after_s=5) is Presence.OFFLINE
    assert presence(None, t0) is Presence.UNKNOWN


def test_heartbeats_publish_read_keep_the_last_verdict(line_archive: Archive) -> None:
    board = StationBoard(line_archive)
    start = datetime.now(UTC) - timedelta(seconds=125)
    board.publish("bench-1", StationState.RUNNING, serial="A09", part_number="IN-100",
                  operator="anna", run_id="r9", started_utc=start, phase="ramp-in")
    now, beats = board.read()
    (hb,) = beats
    assert (hb.station, hb.state, hb.serial, hb.part_number, hb.phase) == \
        ("bench-1", "running", "A09", "IN-100", "ramp-in")
    assert hb.started_utc == start.replace(tzinfo=None)
    assert 0 <= (now - hb.updated_utc).total_seconds() < 60  # the database's clock, both
    board.publish("bench-1", "idle", last_outcome="fail", last_serial="A09", last_run_id="r9")
    board.publish("bench-1", "idle")  # a plain heartbeat: the last verdict stays
    (hb,) = board.read()[1]
    assert (hb.state, hb.serial, hb.run_id, hb.started_utc) == ("idle", None, None, None)
    assert (hb.last_outcome, hb.last_serial, hb.last_run_id) == ("FAIL", "A09", "r9")
    with pytest.raises(InputError, match="state = 'busy'"):
        board.publish("bench-1", "busy")
    with pytest.raises(InputError, match="station"):
        board.publish("  ", "idle")
    board.forget("bench-1")
    assert board.read()[1] == []


def test_publish_by_url_and_a_refused_value(line_url: str) -> None:
    publish_station_state(line_url, HOSTILE_STATION, "idle", last_outcome="PASS")
    with Archive(line_url) as a:
        board = StationBoard(a)
        assert [h.station for h in board.read()[1]] == [HOSTILE_STATION]
        with pytest.raises(ArchiveError) as e:  # PostgreSQL stores no NUL in a text
            board.publish("bench\x00x", "idle")
        assert e.value.kind == "refused"


def test_two_stations_create_the_table_at_once(line_url: str) -> None:
    errors: list[BaseException] = []
    barrier = threading.Barrier(2)

    def station(name: str) -> None:
        try:
            with Archive(line_url) as a:
                board = StationBoard(a)
                barrier.wait(timeout=60)
                board.publish(name, "idle")
        except BaseException as e:  # the test's thread reports it
            errors.append(e)

    threads = [threading.Thread(target=station, args=(f"bench-{i}",)) for i in (1, 2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=120)
    assert errors == []
    with Archive(line_url) as a:
        assert [h.station for h in StationBoard(a).read()[1]] == ["bench-1", "bench-2"]


def test_line_view_of_two_stations(line_archive: Archive) -> None:
    fill_two_stations(line_archive)
    board = StationBoard(line_archive)
    start = datetime.now(UTC) - timedelta(seconds=125)
    board.publish("bench-1", "running", serial="A09", part_number="IN-100", operator="bo",
                  started_utc=start)
    board.publish("bench-2", "idle", last_outcome="ABORTED", last_serial="B04")
    board.publish(HOSTILE_STATION, "running", serial="Z1")
    age_heartbeat(line_archive, HOSTILE_STATION, 3600)
    # stale after 10 min: a fresh heartbeat stays fresh on a loaded machine (the silent
    # station's is an hour old)
    v = line_view(line_archive, board, day=date.fromisoformat(DAY), stale_after_s=600)

    st = {s.station: s for s in v.stations}
    assert list(st) == sorted(["bench-1", "bench-2", HOSTILE_STATION])
    b1, b2, gone = st["bench-1"], st["bench-2"], st[HOSTILE_STATION]
    assert b1.presence is Presence.RUNNING and b1.heartbeat is not None
    assert b1.elapsed_s is not None and 120 <= b1.elapsed_s < 125 + 300  # a loaded machine
    assert b1.last is not None and (b1.last.serial, b1.last.outcome) == ("A08", "PASS")  # archive
    assert b2.presence is Presence.IDLE and b2.elapsed_s is None
    assert b2.last is not None and (b2.last.outcome, b2.last.serial) == ("ABORTED", "B04")
    assert gone.presence is Presence.OFFLINE and gone.age_s is not None and gone.age_s >= 3600
    assert (b1.today.runs, b1.today.passed, b1.today.failed) == (2, 1, 1)

    assert [r["serial"] for r in v.runs_today] == ["A06", "A07", "B02", HOSTILE_SERIAL, "B04"]

    ys = {g.key: g for g in v.yield_by_station}
    assert (ys["bench-1"].today.runs, ys["bench-1"].today.yield_) == (2, 0.5)
    assert (ys["bench-1"].window.runs, ys["bench-1"].window.yield_) == (5, 0.8)
    assert (ys["bench-2"].today.runs, ys["bench-2"].today.aborted) == (3, 1)
    assert ys["bench-2"].today.yield_ == 0.5
    assert (ys["bench-2"].window.runs, ys["bench-2"].window.yield_) == (5, 0.5)
    yp = {g.key: g for g in v.yield_by_part}
    assert (yp["IN-100"].today.runs, yp["IN-100"].today.yield_) == (2, 0.5)
    assert yp["IN-100"].window.runs == 6
    assert yp["IN-100"].window.yield_ == pytest.approx(5 / 6, abs=TOL)
    assert (yp["IN-200"].today.runs, yp["IN-200"].window.runs) == (3, 4)
    assert yp["IN-200"].window.yield_ == pytest.approx(1 / 3, abs=TOL)

    charts = {(c.part_number, c.axis): c for c in v.charts}
    assert set(charts) == {("IN-100", "roll"), ("IN-200", "roll")}
    c100 = charts[("IN-100", "roll")]
    assert [p.sigma for p in c100.points] == pytest.approx(IN_100, abs=TOL)
    assert c100.usl == 0.4 and not c100.limits_differ
    # by hand: x̄ = 2.52/8 = 0.315; MRs .02 .01 .02 .01 .01 .16 .15 → MR̄ = 0.38/7;
    # Σ(x − x̄)² = 0.0214 → s = √(0.0214/7); Cpk = (0.4 − 0.315)/(3 s)
    lim = c100.stats.limits
    assert lim is not None
    assert lim.centre == pytest.approx(0.315, abs=TOL)
    assert lim.mr_bar == pytest.approx(0.38 / 7, abs=TOL)
    assert lim.ucl == pytest.approx(0.315 + 2.66 * 0.38 / 7, abs=TOL)
    assert c100.stats.cpk == pytest.approx(0.085 / (3 * math.sqrt(0.0214 / 7)), abs=1e-9)
    c200 = charts[("IN-200", "roll")]  # the aborted run left out
    assert [p.sigma for p in c200.points] == pytest.approx(IN_200, abs=TOL)
    assert [p.serial for p in c200.points] == ["B01", "B02", HOSTILE_SERIAL]


def test_chart_keeps_the_newest_points(line_archive: Archive) -> None:
    fill_two_stations(line_archive)
    (c,) = sigma_charts(line_archive, points=3, part_number="IN-100")
    assert [p.serial for p in c.points] == ["A06", "A07", "A08"]  # oldest first


def test_a_station_with_runs_but_no_heartbeat(line_archive: Archive) -> None:
    fill_two_stations(line_archive)
    v = line_view(line_archive, StationBoard(line_archive), day=date.fromisoformat(DAY))
    assert {s.station: s.presence for s in v.stations} == {
        "bench-1": Presence.UNKNOWN, "bench-2": Presence.UNKNOWN}
    # reading made nothing: a reader needs no right to write
    assert not inspect(line_archive.engine).has_table(TABLE)


def test_heartbeats_on_sqlite(tmp_path: Path) -> None:
    """One bench with its SQLite archive: the same table, the same staleness."""
    with Archive(f"sqlite:///{tmp_path / 'archive.sqlite'}") as a:
        board = StationBoard(a)
        assert board.read()[1] == []
        board.publish("bench-1", "running", serial="A1", started_utc="2026-11-20T08:00:00Z")
        now, (hb,) = board.read()
        assert presence(hb, now, stale_after_s=600) is Presence.RUNNING  # even when loaded
        assert hb.started_utc == datetime(2026, 11, 20, 8, 0, 0)
        age_heartbeat(a, "bench-1", 3600)
        now, (hb,) = board.read()
        assert presence(hb, now, stale_after_s=600) is Presence.OFFLINE


def test_the_last_verdict_is_the_latest_told(line_archive: Archive) -> None:
    fill_two_stations(line_archive)  # bench-1's newest archived run: A08, 2026-11-21
    board = StationBoard(line_archive)
    board.publish("bench-1", "idle", last_outcome="FAIL", last_serial="OLD",
                  last_end_utc="2026-11-19T00:00:00Z")  # older than the archive's
    board.publish("bench-2", "idle", last_outcome="FAIL", last_serial="B05",
                  last_end_utc="2026-11-22T00:00:00Z")  # not archived yet (queued)
    v = line_view(line_archive, board, day=date.fromisoformat(DAY), stale_after_s=600)
    last = {s.station: s.last for s in v.stations}
    assert last["bench-1"] is not None and (last["bench-1"].serial,
                                            last["bench-1"].outcome) == ("A08", "PASS")
    assert last["bench-2"] is not None and (last["bench-2"].serial,
                                            last["bench-2"].outcome) == ("B05", "FAIL")
