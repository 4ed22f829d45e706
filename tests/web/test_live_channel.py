"""The run's live channel (``benchctl.web.live``): what it publishes, and that it never blocks
or raises into the run — no reader, a reader that does not read, a value that is not JSON."""

from __future__ import annotations

import json
import time
from pathlib import Path

from panel import live_socket

from benchctl.run.display import NullDisplay, Snapshot
from benchctl.web.live import LiveDisplay, LivePublisher, live_display


class Recorder(NullDisplay):
    def __init__(self) -> None:
        self.calls: list[str] = []

    def state(self, state: str, reason: str = "") -> None:
        self.calls.append(f"state {state}")

    def update(self, snap: Snapshot) -> None:
        self.calls.append("update")

    def message(self, text: str) -> None:
        self.calls.append(f"message {text}")

    def verdict(self, verdict: str, detail: str = "") -> None:
        self.calls.append(f"verdict {verdict}")

    def close(self) -> None:
        self.calls.append("close")


def test_each_call_goes_to_the_run_display_and_the_panel(tmp_path: Path) -> None:
    inner = Recorder()
    with live_socket(tmp_path, 5.0) as r:
        d = live_display(inner, tmp_path / "live.sock")
        assert isinstance(d, LiveDisplay)
        d.state("running", "")
        d.update(Snapshot(state="running", elapsed_s=1.5, stand_deg={"roll": 2.0},
                          sigma_deg={"roll": float("nan")}, serial="<b>SN</b>"))
        d.message("line\x1b[2J")
        d.verdict("PASS", "roll σ 0.2°")
        d.close()
        got = [json.loads(r.recv(65536)) for _ in range(5)]
    assert inner.calls == ["state running", "update", "message line\x1b[2J", "verdict PASS",
                           "close"]
    assert [g["kind"] for g in got] == ["state", "snapshot", "message", "verdict", "close"]
    assert [g["seq"] for g in got] == [0, 1, 2, 3, 4]
    snap = got[1]
    assert snap["elapsed_s"] == 1.5 and snap["stand_deg"] == {"roll": 2.0}
    assert snap["sigma_deg"] == {"roll": None}  # NaN: null, valid JSON
    assert snap["serial"] == "<b>SN</b>"  # data, escaped where it is shown
    assert got[2]["text"] == "line\x1b[2J"
    assert got[4]["dropped"] == 0


def test_no_reader_drops_and_never_raises(tmp_path: Path) -> None:
    d = LiveDisplay(NullDisplay(), LivePublisher(tmp_path / "nobody.sock"))
    for _ in range(10):
        d.update(Snapshot(state="running"))
    d.message("x" * 100_000)  # cut to fit a datagram
    d.close()
    assert d.publisher.dropped == 12


def test_a_reader_that_does_not_read_never_holds_the_run(tmp_path: Path) -> None:
    with live_socket(tmp_path, 5.0):  # bound, never read: its queue fills
        pub = LivePublisher(tmp_path / "live.sock")
        t0 = time.monotonic()
        sent = sum(pub.send("snapshot", payload="x" * 2000) for _ in range(5000))
        took = time.monotonic() - t0
        pub.close()
    assert pub.dropped > 0 and sent + pub.dropped == 5000
    assert took < 10.0  # each send returns at once (generous: a loaded machine)


def test_a_value_that_is_not_json_is_dropped(tmp_path: Path) -> None:
    pub = LivePublisher(tmp_path / "nobody.sock")
    assert pub.send("message", text=object()) is False
    assert pub.dropped == 1


def test_without_a_socket_the_run_display_is_unchanged() -> None:
    inner = NullDisplay()
    assert live_display(inner, None) is inner
