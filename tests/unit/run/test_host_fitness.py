"""The host fitness check (``run.host_check``) and ``run.realtime_priority``.

The figures and the verdict are pure functions, checked on exact synthetic lateness arrays
(closed form) and by a property test; the session's refusal and warning through an injected
measurement on simulated time (no real latency needed); the real priority request through an
injected setter (granted, EPERM). What measures on the host's clock is ``realtime`` and asserts
only structure, counts and signs — never a timing that load could break. A whole run on the
host's clock that measures it and has its priority refused: tests/e2e/test_run_e2e.py's run over
ptys (``_HostCheckAndPriority``).
"""

from __future__ import annotations

import errno
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from repo_paths import ROOT
from run_fakes import FakeSensor, FakeStand, Lines, bench_config, sine_motion

from benchctl.cli import main
from benchctl.clock import REAL, Clock, EventLike
from benchctl.clock.virtual import VirtualClock
from benchctl.config import BenchConfig
from benchctl.recording import RecordingWriter, load_recording
from benchctl.run import fitness
from benchctl.run.latency import (
    Bound,
    judge,
    lateness_stats,
    margin_text,
    quantile,
    stand_bounds,
    summary,
)
from benchctl.run.prepare import RunOptions
from benchctl.run.realtime import RealtimeResult, request_realtime
from benchctl.run.recorder import Recorder
from benchctl.run.serialized_stand import SerializedStand
from benchctl.run.session import RunResult, Session
from benchctl.run.stand_loop import LoopLimits, StandLoop
from benchctl.run.state import StateMachine
from benchctl.run.supervisor import Supervisor


# ------------------------------------------------------------------ the figures (pure)
def test_stats_of_a_thousand_evenly_spread_lateness_values_in_closed_form() -> None:
    """k/1000 s for k = 1 … 1000, in any order: max 1 s, the median the 500th value, p99 the
    990th, p99.9 the 999th (nearest rank); wakes later than 0.1 s: k > 100, 900 of them."""
    lateness = [k / 1000 for k in range(1000, 0, -1)]
    s = lateness_stats(lateness, 0.001, 2.0, thresholds_s=(0.1, 0.5, 1.0))
    assert (s.count, s.max_s, s.median_s, s.p99_s, s.p999_s) == (1000, 1.0, 0.5, 0.99, 0.999)
    assert s.over == ((0.1, 900), (0.5, 500), (1.0, 0))
    assert s.to_dict()["over"] == {"0.1": 900, "0.5": 500, "1": 0}


def test_one_late_wake_among_many_shows_in_the_max_and_p999_only() -> None:
    """1999 wakes 50 µs late and one 3 ms late: median and p99 50 µs; p99.9 (rank 1998) still
    50 µs, the max 3 ms; one wake later than 1 ms."""
    s = lateness_stats([50e-6] * 1999 + [3e-3], 0.001, 2.0)
    assert (s.median_s, s.p99_s, s.p999_s, s.max_s) == (50e-6, 50e-6, 50e-6, 3e-3)
    assert dict(s.over) == {1e-4: 1, 1e-3: 1, 1e-2: 0, 1e-1: 0}
    s = lateness_stats([50e-6] * 998 + [3e-3] * 2, 0.001, 1.0)  # 2 of 1000: p99.9 sees them
    assert (s.p999_s, s.p99_s) == (3e-3, 50e-6)


def test_quantiles_by_nearest_rank_and_an_empty_window() -> None:
    assert [quantile([1.0, 2.0, 3.0], p) for p in (0.0, 0.33, 0.5, 0.99, 1.0)] == \
        [1.0, 1.0, 2.0, 3.0, 3.0]
    s = lateness_stats([], 0.001, 2.0)
    assert s.count == 0 and all(math.isnan(x) for x in (s.max_s, s.median_s, s.p999_s))
    v = judge(s.max_s, [Bound("buffer", 1.0, "the stand's 1 s buffer")], 4.0)
    assert not v.ok  # nothing measured is never fit
    assert summary(s, v, "warn") == ("no wake measured over 2 s — poor: nothing to judge "
                                     "(run.host_check.on_poor: warn)")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 10.0, allow_nan=False), min_size=1, max_size=300),
       st.lists(st.floats(1e-6, 100.0), min_size=1, max_size=4),
       st.floats(1.0, 100.0))
def test_the_figures_and_the_verdict_hold_for_any_lateness(
    lateness: list[float], bound_s: list[float], required: float
) -> None:
    s = lateness_stats(lateness, 0.001, 1.0, thresholds_s=(1e-3, 1e-2, 1.0))
    assert s.count == len(lateness)
    assert min(lateness) <= s.median_s <= s.p99_s <= s.p999_s <= s.max_s == max(lateness)
    for q in (s.median_s, s.p99_s, s.p999_s):
        assert q in lateness
    for p, q in ((0.5, s.median_s), (0.99, s.p99_s), (0.999, s.p999_s)):
        assert sum(1 for x in lateness if x > q) <= (1 - p) * len(lateness) + 1e-9
        assert sum(1 for x in lateness if x >= q) >= 1
    counts = [n for _, n in s.over]
    assert counts == sorted(counts, reverse=True)
    bounds = [Bound(f"b{i}", b, f"bound {i}") for i, b in enumerate(bound_s)]
    v = judge(s.max_s, bounds, required)
    assert v.bound is not None and v.bound.seconds == min(bound_s)
    assert v.ok == (s.max_s * required <= min(bound_s))
    if s.max_s > 0:
        assert v.margin == pytest.approx(min(bound_s) / s.max_s)
        assert v.ok == (v.margin >= required * (1 - 1e-12)) or \
            v.margin == pytest.approx(required)


# ------------------------------------------------------------------ the stand's bounds (pure)
def test_what_each_stand_mode_tolerates() -> None:
    def bounds(mode: str, watchdog: float | None = 2.0) -> list[tuple[str, float]]:
        return [(b.name, b.seconds) for b in stand_bounds(
            mode=mode, buffer_s=1.0, setpoint_rate_hz=100.0, send_window=0.25,
            watchdog_s=watchdog, exchange_s=1.6)]

    assert bounds("buffered") == [("buffer", 1.0), ("watchdog", pytest.approx(0.4))]
    assert bounds("stream") == [("send window", 0.0025), ("watchdog", pytest.approx(0.4))]
    assert bounds("table") == [("watchdog", pytest.approx(0.4))]
    assert bounds("table", None) == []
    assert bounds("buffered", 1.5) == [("buffer", 1.0), ("watchdog", 0.0)]  # none left


def test_the_verdict_against_the_tightest_bound_in_closed_form() -> None:
    buffer = Bound("buffer", 1.0, "the stand's 1 s buffer")
    watchdog = Bound("watchdog", 0.4, "the 0.4 s left of the stand's 2 s watchdog")
    v = judge(0.1, [buffer, watchdog], 4.0)  # 0.1 × 4 = 0.4: just fits (exact in binary)
    assert v.ok and v.bound is watchdog and v.margin == 4.0
    v = judge(0.2, [buffer, watchdog], 4.0)
    assert not v.ok and v.margin == 2.0
    v = judge(0.0, [buffer], 4.0)
    assert v.ok and v.margin == math.inf and margin_text(v.margin) == "×∞"
    v = judge(0.5, [], 4.0)
    assert v.ok and v.bound is None  # nothing to judge against (table mode, no watchdog)
    assert [margin_text(m) for m in (1190.4, 12.4, 3.84, 0.214)] == ["×1190", "×12", "×3.8",
                                                                      "×0.21"]


def test_the_operators_line_ok_and_poor() -> None:
    s = lateness_stats([0.31e-3] * 999 + [0.84e-3], 0.001, 2.0)
    buffer = Bound("buffer", 1.0, "the stand's 1 s buffer")
    assert summary(s, judge(s.max_s, [buffer], 4.0), "warn") == (
        "max 0.84 ms, p99.9 0.31 ms over 2 s, 1000 wakes "
        "(margin ×1190 against the stand's 1 s buffer) — ok")
    send = Bound("send window", 0.0025, "the stand loop's 2.5 ms send window")
    assert summary(s, judge(s.max_s, [send], 4.0), "refuse") == (
        "max 0.84 ms, p99.9 0.31 ms over 2 s, 1000 wakes (margin ×3 against the stand "
        "loop's 2.5 ms send window) — poor: run.host_check.margin asks ×4, a worst lateness "
        "of at most 0.62 ms (run.host_check.on_poor: refuse)")


# ------------------------------------------------------------------ config → bounds
def _cfg(tmp_path: Path, stand: dict[str, Any] | None = None, **run: Any) -> BenchConfig:
    cfg = bench_config(tmp_path, **run)
    if stand:
        cfg = cfg.model_copy(update={"stand": cfg.stand.model_copy(update=stand)})
    return cfg


def test_the_config_gives_the_periods_and_the_bounds(tmp_path: Path) -> None:
    cfg = _cfg(tmp_path, {"mode": "buffered", "buffer_s": 1.5, "watchdog_s": 1.0,
                          "timeout_s": 0.3, "retries": 1, "heartbeat_period_s": 0.1,
                          "sample_rate_hz": 50.0})
    assert fitness.periods_s(cfg) == [0.001, 0.02]  # 1 ms and the loop's poll period
    assert [(b.name, round(b.seconds, 9)) for b in fitness.bounds(cfg)] == \
        [("buffer", 1.5), ("watchdog", 0.3)]  # 1.0 − (0.3 × 2 + 0.1)
    stream = _cfg(tmp_path, {"setpoint_rate_hz": 200.0})
    assert fitness.periods_s(stream) == [0.001, 0.005]
    assert [(b.name, b.seconds) for b in fitness.bounds(stream)] == [("send window", 0.00125)]
    defaults = bench_config(tmp_path).run.host_check
    assert (defaults.enabled, defaults.window_s, defaults.period_s, defaults.margin,
            defaults.on_poor) == (True, 2.0, 0.001, 4.0, "warn")
    assert bench_config(tmp_path).run.realtime_priority is None


# ------------------------------------------------------------------ measuring (the clock's)
def test_measuring_on_simulated_time_wakes_exactly_on_time(vclock: VirtualClock) -> None:
    """The measurement waits on the clock it is handed: on simulated time every wake is on
    its deadline (a count of window / period, lateness 0) — nothing of the host reaches it."""
    out: list[float] = []
    t = vclock.thread(lambda: out.extend(
        fitness.measure_lateness(vclock, 0.01, 0.5, vclock.event())), name="measure")
    t.start()
    t.join(10.0)
    assert len(out) == 50 and max(out) == 0.0


def test_a_stop_ends_the_measurement_at_once(vclock: VirtualClock) -> None:
    stop = vclock.event()
    stop.set()
    assert fitness.measure_lateness(vclock, 0.001, 60.0, stop) == []


@pytest.mark.realtime
def test_measuring_the_host_gives_counts_and_non_negative_lateness() -> None:
    """On the host's clock, 0.3 s at 1 ms and 10 ms: structure, counts and signs only."""
    calls: list[int] = []
    got = fitness.measure_host(REAL, [0.001, 0.01], 0.3, REAL.event(), priority=50,
                               setter=calls.append)
    assert set(got.series) == {0.001, 0.01} and calls == [50, 50]  # each thread asked
    assert got.realtime == RealtimeResult(50, True, "real-time priority 50: granted (SCHED_FIFO)")
    assert 1 <= len(got.series[0.001]) <= 300 and 1 <= len(got.series[0.01]) <= 30
    assert all(x >= 0.0 for s in got.series.values() for x in s)


# ------------------------------------------------------------------ real-time priority
def _denied(err: int) -> Any:
    def setter(priority: int) -> None:
        raise OSError(err, __import__("os").strerror(err))
    return setter


def test_a_real_time_priority_granted_or_refused() -> None:
    asked: list[int] = []
    assert request_realtime(50, asked.append) == RealtimeResult(
        50, True, "real-time priority 50: granted (SCHED_FIFO)")
    assert asked == [50]
    assert request_realtime(50, _denied(errno.EPERM)).detail == (
        "real-time priority 50: not granted: Operation not permitted (run as a user with "
        "CAP_SYS_NICE, or with rtprio 50 or more in /etc/security/limits.conf)")
    r = request_realtime(99, _denied(errno.EINVAL))
    assert not r.granted and r.detail == "real-time priority 99: not granted: Invalid argument"


def test_no_real_time_scheduling_on_this_system(monkeypatch: pytest.MonkeyPatch) -> None:
    from benchctl.run import realtime

    monkeypatch.setattr(realtime, "os_setter", lambda: None)
    assert realtime.request_realtime(10).detail == (
        "real-time priority 10: not granted: this operating system has no SCHED_FIFO "
        "scheduling")


@pytest.mark.realtime
@pytest.mark.parametrize("setter, granted", [(None, True), (_denied(errno.EPERM), False)],
                         ids=["granted", "EPERM"])
def test_the_stand_loop_thread_asks_for_its_priority(tmp_path: Path, setter: Any,
                                                     granted: bool) -> None:
    """The request is made from the loop's own thread (pid 0: that thread)."""
    from benchctl.run.stand_loop import threading as loop_threading

    asked: list[tuple[int, int]] = []

    def fake(priority: int) -> None:
        asked.append((priority, loop_threading.get_ident()))
        if setter is not None:
            setter(priority)

    stand = FakeStand()
    w = RecordingWriter(tmp_path / "rec", ("roll",), {})
    sup = Supervisor()
    rec = Recorder(w, sup, ("roll",))
    rec.attach(stand)
    loop = StandLoop(SerializedStand(stand).as_stand(), rec, sup, StateMachine(REAL),
                     sine_motion(("roll",)).plan,
                     LoopLimits(20.0, 0.5, 1.0, 0.5, 0.1, 100.0, 0.05),
                     realtime_priority=50, priority_setter=fake)
    loop.start()
    try:
        assert loop.realtime_known.wait(10.0)
    finally:
        loop.stop()
        w.close("done")
    assert loop.realtime is not None and loop.realtime.granted is granted
    assert [p for p, _ in asked] == [50] and asked[0][1] == loop._ident


# ------------------------------------------------------------------ the run (simulated time)
def _probe(lateness_s: float, n: int = 2000) -> tuple[fitness.Probe, list[Any]]:
    calls: list[Any] = []

    def probe(clock: Clock, periods: Sequence[float], window_s: float, stop: EventLike,
              priority: int | None, setter: Any = None) -> fitness.HostLatency:
        calls.append((list(periods), window_s, priority))
        return fitness.HostLatency(window_s, {p: [lateness_s] * n for p in periods})

    return probe, calls


def _session(tmp_path: Path, vclock: VirtualClock, cfg: BenchConfig,
             probe: fitness.Probe | None = None, **kw: Any) -> tuple[RunResult, FakeStand, Lines]:
    stand = FakeStand(("roll",), clock=vclock)
    sensor = FakeSensor(stand, gain=1.0)
    lines = Lines()
    prep = sine_motion(("roll",), duration_s=3.0, mode="stream", fade_s=0.5)
    res = Session(cfg, prep, RunOptions("I1", "tester"), display=lines,
                  device_factory=lambda c, p: (stand, sensor), clock=vclock,
                  host_probe=probe, **kw).run()
    return res, stand, lines


def _record(res: RunResult) -> dict[str, Any]:
    assert res.recording is not None
    return json.loads((res.recording / "record.json").read_text())


def _host_line(lines: Lines) -> str:
    return next(m for m in lines.messages if m.startswith("host latency"))


def test_a_poor_host_is_refused_before_the_stand_moves(tmp_path: Path,
                                                       vclock: VirtualClock) -> None:
    """1 ms worst lateness × 4 > the 2.5 ms send window of a 100 Hz stream: refused."""
    probe, calls = _probe(0.001)
    cfg = _cfg(tmp_path, host_check={"on_poor": "refuse"})
    res, stand, lines = _session(tmp_path, vclock, cfg, probe)
    assert calls == [([0.001, 0.01], 2.0, None)]
    poor = ("max 1.00 ms, p99.9 1.00 ms over 2 s, 4000 wakes (margin ×2.5 against the stand "
            "loop's 2.5 ms send window (0.25 of its 10 ms period: a later setpoint is a missed "
            "slot)) — poor: run.host_check.margin asks ×4, a worst lateness of at most 0.62 ms "
            "(run.host_check.on_poor: refuse)")
    assert _host_line(lines) == f"host latency: {poor}: the run is refused before the stand moves"
    assert res.exit_code == 2 and res.state == "aborted"
    assert res.reason == f"run: precheck 'host latency' failed: {poor}"
    assert "enable" not in stand.calls and not any("setpoint" in c for c in stand.calls)
    rec = _record(res)
    row = next(m for m in rec["measurements"] if m["name"] == "precheck: host latency")
    assert row["outcome"] == "FAIL" and row["note"] == poor
    assert rec["outcome"] == "ABORTED" and rec["abort"]["kind"] == "equipment"
    assert rec["files"]["report_html"] is not None  # before the loop's first cycle: drawn
    assert rec["warnings"] == []
    ev = next(e for e in load_recording(res.recording).events  # type: ignore[arg-type]
              if e["kind"] == "precheck" and e["name"] == "host latency")
    assert ev["ok"] is False and ev["values"]["all"]["count"] == 4000
    assert ev["values"]["verdict"]["bound"]["name"] == "send window"


def test_a_poor_host_under_warn_runs_with_a_warning(tmp_path: Path,
                                                    vclock: VirtualClock) -> None:
    probe, _ = _probe(0.001)
    res, stand, lines = _session(tmp_path, vclock, _cfg(tmp_path), probe)  # on_poor: warn
    assert res.exit_code == 0 and res.state == "done", res.reason
    line = _host_line(lines)
    assert line.endswith("(run.host_check.on_poor: warn): the run goes on, with a warning in "
                         "its record")
    rec = _record(res)
    row = next(m for m in rec["measurements"] if m["name"] == "precheck: host latency")
    assert row["outcome"] == "PASS" and "— poor:" in row["note"]
    assert rec["warnings"] == [line.removesuffix(": the run goes on, with a warning in its "
                                                 "record")]
    assert "enable" in stand.calls
    assert rec["warnings"][0] in (res.recording / "report.txt").read_text()  # type: ignore[operator]


def test_a_fit_host_is_a_passed_precheck(tmp_path: Path, vclock: VirtualClock) -> None:
    probe, _ = _probe(0.0001)  # 0.1 ms × 4 within 2.5 ms
    res, _, lines = _session(tmp_path, vclock, _cfg(tmp_path), probe)
    assert res.exit_code == 0, res.reason
    assert _host_line(lines) == (
        "host latency: max 0.10 ms, p99.9 0.10 ms over 2 s, 4000 wakes (margin ×25 against "
        "the stand loop's 2.5 ms send window (0.25 of its 10 ms period: a later setpoint is a "
        "missed slot)) — ok")
    assert _record(res)["warnings"] == []


def test_on_simulated_time_the_host_is_not_measured(tmp_path: Path,
                                                    vclock: VirtualClock) -> None:
    """No probe handed in: skipped with its reason recorded; no precheck row; a priority
    asked for is not requested on simulated time, and says so."""
    asked: list[int] = []
    res, _, lines = _session(tmp_path, vclock, _cfg(tmp_path, realtime_priority=50),
                             priority_setter=asked.append)
    assert res.exit_code == 0, res.reason
    assert "simulated time: host latency not measured" in lines.messages
    assert "real-time priority not requested: simulated time" in lines.messages
    assert asked == []
    r = load_recording(res.recording)  # type: ignore[arg-type]
    host = [e for e in r.events if e["kind"] == "host_check"]
    assert [(e["skipped"], e["reason"]) for e in host] == \
        [(True, "simulated time: host latency not measured")]
    assert [e["detail"] for e in r.events if e["kind"] == "realtime_priority"] == \
        ["real-time priority not requested: simulated time"]
    assert not any(m["name"] == "precheck: host latency" for m in _record(res)["measurements"])


def test_a_disabled_check_is_not_measured(tmp_path: Path, vclock: VirtualClock) -> None:
    probe, calls = _probe(1.0)
    res, _, lines = _session(tmp_path, vclock, _cfg(tmp_path, host_check={"enabled": False}),
                             probe)
    assert res.exit_code == 0 and calls == []
    assert "host latency not measured: run.host_check.enabled is false" in lines.messages


# ------------------------------------------------------------------ benchctl host-check
def _config_file(tmp_path: Path, **run: Any) -> Path:
    """The hardware example (a table-mode stand, watchdog 1 s, exchange 0.7 s) with ``run``."""
    data = yaml.safe_load((ROOT / "config" / "hardware_example.yaml").read_text())
    data["run"].update(run, output_dir=str(tmp_path))
    data["stand"]["register_map"] = str(ROOT / "drivers" / "stand_generic.yaml")
    data["instrument"]["eds"] = str(ROOT / "drivers" / "cia410_inclinometer.eds")
    path = tmp_path / "bench.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_host_check_prints_the_figures_and_the_verdict(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    probe, calls = _probe(0.0005, n=1000)
    monkeypatch.setattr(fitness, "measure_host", probe)
    cfg = _config_file(tmp_path)
    assert main(["host-check", "--config", str(cfg), "--window", "0.5"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert calls == [([0.001, 0.01], 0.5, None)]
    assert out == [
        "host latency: max 0.50 ms, p99.9 0.50 ms over 0.5 s, 2000 wakes (margin ×600 against "
        "the 0.3 s left of the stand's 1 s watchdog after its longest exchange (0.7 s)) — ok",
        "  every 1 ms: 1000 wakes, median 0.500 ms, p99 0.500 ms, p99.9 0.500 ms, max 0.500 ms; "
        "later than 0.1 ms: 1000, 1 ms: 0, 10 ms: 0, 100 ms: 0",
        "  every 10 ms: 1000 wakes, median 0.500 ms, p99 0.500 ms, p99.9 0.500 ms, "
        "max 0.500 ms; later than 0.1 ms: 1000, 1 ms: 0, 10 ms: 0, 100 ms: 0",
        "  against the 0.3 s left of the stand's 1 s watchdog after its longest exchange "
        "(0.7 s) (the tightest)",
    ]


def test_host_check_exits_1_on_a_poor_host_and_prints_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    probe, _ = _probe(0.1, n=10)  # 0.1 s × 4 > 0.3 s
    monkeypatch.setattr(fitness, "measure_host", probe)
    cfg = _config_file(tmp_path, host_check={"on_poor": "refuse"})
    assert main(["host-check", "--config", str(cfg), "--json"]) == 1
    got = json.loads(capsys.readouterr().out)
    assert got["line"].startswith("host latency: max 100.00 ms") and "— poor:" in got["line"]
    assert got["verdict"]["ok"] is False and got["verdict"]["margin"] == pytest.approx(3.0)
    assert got["window_s"] == 2.0 and got["all"]["count"] == 20


def test_host_check_refuses_a_bad_window(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["host-check", "--config", str(_config_file(tmp_path)), "--window", "0"]) == 2
    assert capsys.readouterr().err.strip() == \
        "benchctl host-check: error: --window 0: expected seconds, 0 < S ≤ 60"


def test_host_check_help(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as done:
        main(["host-check", "--help"])
    assert done.value.code == 0
    out = " ".join(capsys.readouterr().out.split())
    assert out.startswith("usage: benchctl host-check [-h] --config CONFIG [--window S] [--json]")
    assert "Measure this computer's scheduling latency" in out and "Exit 0" in out


@pytest.mark.realtime
def test_host_check_on_this_host(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The real measurement, 0.3 s: the lines' structure only (ok or poor, either exit)."""
    code = main(["host-check", "--config", str(_config_file(tmp_path)), "--window", "0.3"])
    out = capsys.readouterr().out.splitlines()
    assert code in (0, 1)
    assert out[0].startswith("host latency: max ") and out[0].endswith(("— ok", "warn)"))
    assert out[1].startswith("  every 1 ms: ") and out[2].startswith("  every 10 ms: ")
