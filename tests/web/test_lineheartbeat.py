"""The station's heartbeat kept going, on simulated time: published at once on start and on
every change, every 5 s between, a database out of reach logged once and outlived, the
thread ended by stop(); and against a real PostgreSQL once, on the host's clock."""

from __future__ import annotations

from typing import Any

import pytest

from benchctl.archive.store import Archive
from benchctl.clock.virtual import VirtualClock
from benchctl.errors import ArchiveError, InputError
from benchctl.web.lineheartbeat import HeartbeatPublisher
from benchctl.web.linestations import StationBoard, StationState


class _Board:
    def __init__(self, clock: VirtualClock, fail: set[int] | None = None) -> None:
        self.clock = clock
        self.calls: list[tuple[float, str, str, dict[str, Any]]] = []
        self.fail = fail or set()

    def publish(self, station: str, state: StationState, **fields: Any) -> None:
        n = len(self.calls)
        self.calls.append((round(self.clock.monotonic(), 6), station, state.value, fields))
        if n in self.fail:
            raise ArchiveError("archive x: cannot publish: unreachable (refused)",
                               "unreachable")


def test_beats_and_changes_on_simulated_time(vclock: VirtualClock) -> None:
    board = _Board(vclock)
    t0 = vclock.monotonic()
    with HeartbeatPublisher(board.publish, "bench-1", every_s=5.0, clock=vclock) as beat:
        vclock.sleep(12.0)  # beats at 0, 5, 10
        beat.set(StationState.RUNNING, serial="A1", phase="ramp-in")  # at 12, at once
        vclock.sleep(6.0)  # and at 17
        beat.set("idle", last_outcome="PASS")  # at 18
        vclock.sleep(1.0)  # stop at 19: the last state once more
    times = [round(t - t0, 6) for t, *_ in board.calls]
    assert times == [0.0, 5.0, 10.0, 12.0, 17.0, 18.0, 19.0]
    assert [c[2] for c in board.calls] == ["idle"] * 3 + ["running"] * 2 + ["idle"] * 2
    assert board.calls[3][3] == {"serial": "A1", "phase": "ramp-in"}
    assert board.calls[5][3] == {"last_outcome": "PASS"}
    assert all(c[1] == "bench-1" for c in board.calls)


def test_a_database_out_of_reach_is_logged_once_and_outlived(
        vclock: VirtualClock, caplog: pytest.LogCaptureFixture) -> None:
    board = _Board(vclock, fail={1, 2, 3})
    beat = HeartbeatPublisher(board.publish, "bench-2", every_s=5.0, clock=vclock)
    with caplog.at_level("WARNING", logger="benchctl.web.lineheartbeat"):
        beat.start()
        vclock.sleep(21.0)  # 0 ok, 5 10 15 fail, 20 ok
        beat.stop()  # 21 ok
    assert len(board.calls) == 6 and beat.published == 3
    msgs = [r.getMessage() for r in caplog.records]
    assert len(msgs) == 2, msgs
    assert "heartbeat not published" in msgs[0] and "unreachable" in msgs[0]
    assert "published again" in msgs[1]


def test_bad_arguments() -> None:
    with pytest.raises(InputError, match="every_s"):
        HeartbeatPublisher(lambda *a, **k: None, "b", every_s=0)
    beat = HeartbeatPublisher(lambda *a, **k: None, "b")
    with pytest.raises(InputError, match="state = 'busy'"):
        beat.set("busy")


def test_on_postgresql(line_archive: Archive) -> None:
    board = StationBoard(line_archive)
    with HeartbeatPublisher(board.publish, "bench-9", StationState.RUNNING, serial="Q1"):
        pass  # at least one publish, however soon it stops
    (hb,) = board.read()[1]
    assert (hb.station, hb.state, hb.serial) == ("bench-9", "running", "Q1")


def test_through_the_pages_archive(line_url: str, caplog: pytest.LogCaptureFixture) -> None:
    """The station server's way: LineArchive.publish opens the archive when it first can."""
    from archive_helpers import free_port

    from benchctl.web.line import LineArchive

    down = LineArchive(f"postgresql+psycopg://bench@127.0.0.1:{free_port()}/nowhere")
    with caplog.at_level("WARNING", logger="benchctl.web.lineheartbeat"), \
            HeartbeatPublisher(down.publish, "bench-3"):
        pass
    down.close()
    assert any("unreachable" in r.getMessage() for r in caplog.records)
    up = LineArchive(line_url)
    try:
        with HeartbeatPublisher(up.publish, "bench-3", serial=None) as beat:
            beat.set("running", serial="R1")
        (hb,) = up.get()[1].read()[1]
        assert (hb.station, hb.state, hb.serial) == ("bench-3", "running", "R1")
    finally:
        up.close()
