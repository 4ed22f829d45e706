"""Unit tests of the run layer's pieces: state machine, histogram, running σ, plan, prechecks,
supervisor, recorder format extensions and the stream loop's deadline discipline."""

from __future__ import annotations

import dataclasses
import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from repo_paths import ROOT
from run_fakes import FakeSensor, FakeStand, bench_config, sine_motion, wait_for

from benchctl.analysis.departures import departures_of
from benchctl.clock.virtual import VirtualClock
from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
from benchctl.errors import ConnectionLost, SafetyAbort
from benchctl.recording import RecordingWriter, load_recording
from benchctl.run import prechecks as pc
from benchctl.run.live import Histogram, RunningSigma
from benchctl.run.recorder import Recorder
from benchctl.run.serialized_stand import SerializedStand
from benchctl.run.stand_loop import LoopLimits, StandLoop, start_instrument
from benchctl.run.state import RunState, StateMachine, TransitionError
from benchctl.run.supervisor import Supervisor

# ----------------------------------------------------------------------------- state machine


def test_state_machine_normal_order_and_events() -> None:
    sm = StateMachine()
    seen: list[tuple[str, str]] = []
    sm.subscribe(lambda old, new, t, reason: seen.append((str(old), str(new))))
    sm.to(RunState.PRECHECKS)
    sm.advance_to(RunState.RUNNING)  # passes through fade-in
    sm.to(RunState.FADE_OUT)
    sm.to(RunState.ANALYSING)
    sm.to(RunState.DONE)
    assert seen == [
        ("idle", "prechecks"),
        ("prechecks", "fade-in"),
        ("fade-in", "running"),
        ("running", "fade-out"),
        ("fade-out", "analysing"),
        ("analysing", "done"),
    ]
    assert sm.final
    with pytest.raises(TransitionError):
        sm.to(RunState.ABORTED)
    assert sm.abort("late") is False


@pytest.mark.parametrize(
    ("start", "bad"),
    [
        (RunState.IDLE, RunState.RUNNING),
        (RunState.PRECHECKS, RunState.DONE),
        (RunState.RUNNING, RunState.FADE_IN),
        (RunState.FADE_IN, RunState.ANALYSING),
    ],
)
def test_state_machine_refuses_illegal_moves(start: RunState, bad: RunState) -> None:
    sm = StateMachine()
    if start is not RunState.IDLE:
        sm.advance_to(start)
    with pytest.raises(TransitionError, match=f"{start} cannot move to {bad}"):
        sm.to(bad)
    assert sm.state is start


def test_every_non_final_state_can_abort() -> None:
    for target in (RunState.IDLE, RunState.PRECHECKS, RunState.RUNNING, RunState.ANALYSING):
        sm = StateMachine()
        if target is not RunState.IDLE:
            sm.advance_to(target)
        assert sm.abort("why") is True
        assert sm.state is RunState.ABORTED
        assert sm.history[-1][0] is RunState.ABORTED


# ----------------------------------------------------------------------------- statistics


def test_histogram_quantiles_match_numpy_within_resolution() -> None:
    rng = np.random.default_rng(0)
    x = rng.exponential(0.002, 5000)
    h = Histogram(resolution_s=1e-5)
    for v in x:
        h.add(float(v))
    for q in (0.5, 0.99):
        assert abs(h.quantile(q) - np.quantile(x, q)) <= 1.5e-5
    assert h.max == pytest.approx(x.max())
    assert h.n == 5000


def test_running_sigma_of_a_known_error() -> None:
    """x a ramp sampled at 100 Hz; y = x(t) + 0.3 + ±0.2 alternating at instants between stand
    samples: the interpolation is exact for a ramp, so σ = 0.2·√(n/(n−1)) exactly."""
    rs = RunningSigma(("roll",))
    rs.active = True
    n = 200
    for k in range(n + 2):
        t = k * 0.01
        if k >= 1:
            tm = t - 0.005
            e = 0.2 if k % 2 else -0.2
            rs.add_instrument(InstrumentSample(tm, {"roll": 3.0 * tm + 0.3 + e}))
        rs.add_stand(t, {"roll": 3.0 * t})
    m = rs.n["roll"]
    assert m == n + 1
    expect = 0.2 * math.sqrt(m / (m - 1)) if m % 2 == 0 else None
    sig = rs.sigma()["roll"]
    # with an odd count the mean is off by 0.2/m; compute the exact sample σ directly
    e = np.array([0.2 if k % 2 else -0.2 for k in range(1, n + 2)])
    assert sig == pytest.approx(float(np.std(e, ddof=1)), rel=1e-9)
    if expect is not None:
        assert sig == pytest.approx(expect, rel=1e-9)


def test_plan_grid_and_states() -> None:
    prep = sine_motion(duration_s=4.0, fade_s=1.0)
    plan = prep.plan
    assert plan.n_slots == 401
    assert plan.values["roll"][0] == 0.0 and abs(plan.values["roll"][-1]) < 1e-12
    assert plan.state_at(0.5) is RunState.FADE_IN
    assert plan.state_at(2.0) is RunState.RUNNING
    assert plan.state_at(3.5) is RunState.FADE_OUT
    t = 2.003  # between grid points: linear interpolation of the exact sine within 1e-3°
    assert plan.at(t)["roll"] == pytest.approx(5.0 * math.cos(2 * math.pi * 0.5 * t), abs=2e-3)


# ----------------------------------------------------------------------------- prechecks


def _status(**kw: bool) -> StandStatus:
    base = dict(ready=True, enabled=False, moving=False, fault=False, estop=False, limit=False)
    base.update(kw)
    return StandStatus(**base)  # type: ignore[arg-type]


def _sample(angle: float = 0.0, rate: float = 0.0) -> StandSample:
    return StandSample(0.0, 0.001, {"roll": angle}, {"roll": rate}, {"roll": 0.0}, _status())


def test_precheck_stand_ready_names_the_problem() -> None:
    ok = pc.check_stand_ready(_status(), _sample(), ("roll",))
    assert ok.ok
    r = pc.check_stand_ready(_status(estop=True, ready=False), _sample(rate=2.0), ("roll", "pitch"))
    assert not r.ok
    for part in ("E-stop", "not ready", "moving at +2.00°/s", "no axis ['pitch']"):
        assert part in r.detail
    with pytest.raises(pc.PrecheckFailed, match="stand ready and at rest"):
        pc.require(r)


def test_precheck_instrument_rate_and_static() -> None:
    samples = [InstrumentSample(i * 0.01, {"roll": 1.05}) for i in range(100)]
    assert pc.check_instrument_rate(samples, 1.0, 100.0, 0.2, ("roll",)).ok
    slow = pc.check_instrument_rate(samples[:50], 1.0, 100.0, 0.2, ("roll",))
    assert not slow.ok and "50.0 Hz, expected 100 Hz" in slow.detail
    assert not pc.check_instrument_rate(samples, 1.0, 100.0, 0.2, ("roll", "pitch")).ok
    st = pc.check_static_agreement(samples, {"roll": 1.0}, 0.1, ("roll",))
    assert st.ok and st.values["difference_deg"]["roll"] == pytest.approx(0.05)
    bad = pc.check_static_agreement(samples, {"roll": 0.5}, 0.1, ("roll",))
    assert not bad.ok and "+0.550°" in bad.detail


def test_precheck_disk(tmp_path: Path) -> None:
    assert pc.check_disk(tmp_path / "not" / "yet", 1.0).ok
    r = pc.check_disk(tmp_path, 1e15)
    assert not r.ok and "run.min_free_disk_mb" in r.detail


# ----------------------------------------------------------------------------- supervisor


def test_supervisor_first_fault_wins_and_threads_never_die_quietly() -> None:
    sup = Supervisor()

    def boom() -> None:
        raise ConnectionLost("link gone")

    t = sup.thread("reader", boom)
    t.start()
    t.join()
    sup.fault(SafetyAbort("second"), "other")
    assert sup.stop_event.is_set()
    assert sup.first is not None and sup.first.reason == "reader: ConnectionLost: link gone"
    assert [f.reason for f in sup.later] == ["other: second"]
    with pytest.raises(SafetyAbort, match="link gone"):
        sup.check()


# ----------------------------------------------------------------------------- recording


def test_writer_setpoint_slot_column_and_meta_update(tmp_path: Path) -> None:
    w = RecordingWriter(tmp_path / "r", ("roll", "pitch"), {"serial": "X"})
    w.write_setpoint(10.5, {"roll": 1.25, "pitch": -0.5}, t_slot=10.49)
    w.update_meta(devices={"stand": {"vendor": "v"}})
    w.close("done", "PASS")
    rec = load_recording(tmp_path / "r")
    assert rec.streams["setpoints"]["t_slot"].tolist() == [10.49]
    assert rec.streams["setpoints"]["pitch_deg"].tolist() == [-0.5]
    assert rec.meta["serial"] == "X" and rec.meta["devices"]["stand"]["vendor"] == "v"
    assert rec.state == "done"


# ----------------------------------------------------------------------------- stand loop


def _loop(tmp_path: Path, stand: FakeStand, sensor: FakeSensor, duration: float = 1.0):
    """The stand loop and what it writes to, on the fake stand's clock (the tests': simulated
    time, the ``vclock`` fixture)."""
    clock = stand.clock
    w = RecordingWriter(tmp_path / "rec", stand.axes, {})
    sup = Supervisor(clock=clock)
    rec = Recorder(w, sup, stand.axes, clock=clock)
    rec.attach(stand)
    sm = StateMachine(clock)
    sm.to(RunState.PRECHECKS)
    prep = sine_motion(stand.axes, duration_s=duration, fade_s=0.25)
    lim = LoopLimits(20.0, 0.5, 1.0, 0.5, 0.1, 100.0, 0.05, rate_deg_s=50.0, accel_deg_s2=1000.0)
    loop = StandLoop(SerializedStand(stand, clock=clock).as_stand(), rec, sup, sm, prep.plan, lim,
                     clock=clock)
    return w, sup, rec, sm, loop


def test_stream_loop_rejoins_after_a_stall_without_a_jump(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    """A 0.2 s stall at 100 Hz: ~19 slots are missed and counted (never sent late in a burst);
    the stand held its last setpoint, so the loop rejoins the profile from there along a path
    within the limits (an event in the recording), then sends the profile's own slots again."""
    stand = FakeStand(clock=vclock)
    stand.stall_at, stand.stall_s = 0.3, 0.2
    sensor = FakeSensor(stand)
    w, sup, rec, sm, loop = _loop(tmp_path, stand, sensor)
    start_instrument(sensor, rec)
    loop.start()
    loop.begin_motion()
    assert wait_for(lambda: loop.motion_done.is_set() or sup.faulted, 10.0, vclock)
    loop.stop()
    sensor.stop()
    w.close("done")
    assert not sup.faulted, sup.first
    assert 15 <= loop.missed_cycles <= 40
    assert loop.rejoins >= 1
    recd = load_recording(tmp_path / "rec")
    sp = recd.streams["setpoints"]
    assert sp["t_send"].size + loop.missed_cycles >= 101  # every slot sent or counted missed
    slots = np.round((sp["t_slot"] - sp["t_slot"][0]) / 0.01).astype(int)
    assert np.allclose(sp["t_slot"] - sp["t_slot"][0], slots * 0.01, atol=1e-9)  # on the grid
    d = np.diff(slots)
    assert np.all(d >= 1)  # one setpoint per slot at most
    big = int(np.argmax(d))
    assert d[big] >= 15  # the stall: skipped over, not caught up
    # the commanded sequence, judged as the stand plays it (from rest after the hold)
    x = sp["roll_deg"]
    v = np.diff(x) / 0.01
    v_prev = np.concatenate([[0.0], v[:-1]])
    v_prev[d > 1] = 0.0  # the stand held over the stall (and any other missed slot)
    assert np.max(np.abs(v)) <= 50.0 + 1e-9
    assert np.max(np.abs((v - v_prev) / 0.01)) <= 1000.0 + 1e-6
    assert loop.cmd.max_rate_deg_s["roll"] <= 50.0 + 1e-9
    # the rejoin ends on the profile: the last setpoints are the profile's own slot values
    prof = loop.plan.values["roll"]
    k_last = slots[-1] + round((sp["t_slot"][0] - loop.t_motion_start) / 0.01)
    assert x[-1] == pytest.approx(prof[min(k_last, prof.size - 1)], abs=1e-12)
    events = [e for e in recd.events if e["kind"] == "rejoin"]
    assert events and events[0]["points"] >= 1
    assert sm.state is RunState.FADE_OUT
    # what the analysis leaves out (benchctl.analysis.departures), from what the loop wrote:
    # from the setpoint the stand held over the stall to the end of the rejoin's path
    rej = next(e for e in events if e["t_slot"] == pytest.approx(sp["t_slot"][big + 1]))
    dep = next(d for d in departures_of(recd, settle_s=0.5).items
               if d.start_s <= sp["t_slot"][big + 1] <= d.end_s)
    assert dep.start_s <= sp["t_slot"][big] + 1e-9
    assert dep.back_s >= sp["t_slot"][big + 1] + rej["duration_s"] - 1e-9
    assert dep.end_s == pytest.approx(dep.back_s + 0.5)


def test_table_loop_plays_and_polls(tmp_path: Path, vclock: VirtualClock) -> None:
    stand = FakeStand(clock=vclock)
    sensor = FakeSensor(stand)
    w, sup, rec, _sm, loop = _loop(tmp_path, stand, sensor)
    loop.plan = dataclasses.replace(loop.plan, mode="table")
    assert loop.plan.tables is not None
    stand.upload_table(loop.plan.tables)
    start_instrument(sensor, rec)
    loop.start()
    loop.begin_motion()
    assert wait_for(lambda: loop.motion_done.is_set() or sup.faulted, 10.0, vclock)
    loop.stop()
    sensor.stop()
    w.close("done")
    assert not sup.faulted, sup.first
    assert "start_table" in stand.calls and "stop_table" in stand.calls
    st = load_recording(tmp_path / "rec").streams["stand"]
    t = st["t_host"] - loop.t_motion_start
    inside = (t > 0) & (t < 1.0)
    assert inside.sum() >= 50  # polled at ~100 Hz over 1 s on a noisy machine
    expect = loop.plan.tables["roll"].evaluate(t[inside])
    assert np.max(np.abs(st["roll_deg"][inside] - expect)) < 0.05  # sampled vs stamped instants


def test_loop_fault_reaches_the_supervisor_at_once(tmp_path: Path, vclock: VirtualClock) -> None:
    stand = FakeStand(clock=vclock)
    stand.fault_at = 0.2
    sensor = FakeSensor(stand)
    w, sup, rec, _sm, loop = _loop(tmp_path, stand, sensor)
    start_instrument(sensor, rec)
    loop.start()
    loop.begin_motion()
    assert wait_for(lambda: sup.faulted, 5.0, vclock)
    t_fault = sup.first.t_host  # type: ignore[union-attr]
    assert t_fault - stand.t_motion < 0.2 + 0.5  # type: ignore[operator]
    loop.stop()
    sensor.stop()
    w.close("aborted")
    assert "fault code 7" in sup.first.reason  # type: ignore[union-attr]
    assert not loop.alive


def test_serialized_stand_excludes_concurrent_calls() -> None:
    inside = []
    lock_seen = threading.Lock()

    class Slow:
        axes = ("roll",)
        limits = None

        def op(self) -> None:
            if not lock_seen.acquire(blocking=False):
                inside.append("overlap")
                return
            time.sleep(0.01)
            lock_seen.release()

    s = SerializedStand(Slow())  # type: ignore[arg-type]
    ts = [threading.Thread(target=lambda: [s.op() for _ in range(5)]) for _ in range(3)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert inside == []


# ----------------------------------------------------------------------------- display


def test_displays_tty_redraws_in_place_and_log_prints_lines() -> None:
    import io

    from benchctl.run.display import LogDisplay, Snapshot, TtyDisplay, make_display

    snap = Snapshot(
        "running",
        elapsed_s=65.0,
        remaining_s=835.0,
        stand_deg={"roll": 1.234},
        instrument_deg={"roll": 1.3},
        tracking_error_deg={"roll": 0.012},
        sigma_deg={"roll": float("nan")},
    )
    tty = io.StringIO()
    d = TtyDisplay(tty, fps=1e6)
    d.update(snap)
    d.update(snap)
    out = tty.getvalue()
    # the second frame overwrote the first (7 lines up: state, stand, instrument, tracking,
    # σ, health and the line a health warning takes)
    assert "\x1b[7F\x1b[J" in out
    assert "elapsed 01:05  remaining 13:55" in out and "roll   +1.23°" in out
    d.message("state → fade-out")
    assert "state → fade-out" in tty.getvalue()
    log = io.StringIO()
    ld = LogDisplay(log, period_s=3600.0)
    ld.update(snap)
    ld.update(snap)  # within the period: not printed again
    ld.state("aborted", "interrupted by SIGINT")
    lines = log.getvalue().splitlines()
    assert len(lines) == 2 and "\x1b" not in log.getvalue()
    assert lines[1].endswith("state → aborted (interrupted by SIGINT)")
    assert isinstance(make_display(io.StringIO()), LogDisplay)  # not a terminal


def test_resolve_batches_dates_back_one_read() -> None:
    from benchctl.recording.reader import resolve_batches

    t = np.array([1.00, 1.01, 1.04, 1.04, 1.04, 1.05])
    # no device time: dated back by the median interval (10 ms) from the batch's receipt
    assert np.allclose(resolve_batches(t), [1.00, 1.01, 1.02, 1.03, 1.04, 1.05])
    dev = np.array([0.0, 0.01, 0.02, 0.025, 0.03, 0.04])  # the instrument's own times
    assert np.allclose(resolve_batches(t, dev), [1.00, 1.01, 1.03, 1.035, 1.04, 1.05])
    # a batch right after the previous sample: spread evenly after it
    t2 = np.array([1.00, 1.01, 1.015, 1.015, 1.015])
    out = resolve_batches(t2)
    assert np.all(np.diff(out) > 0) and out[-1] == 1.015 and out[1] == 1.01
    inc = np.array([1.0, 1.1, 1.3])
    assert resolve_batches(inc) is inc  # already increasing: untouched


def test_pair_of_a_finished_recording_is_its_analysis_window(tmp_path: Path) -> None:
    w = RecordingWriter(tmp_path / "r", ("roll",), {})
    st = StandStatus(True, True, False, False, False, False)
    for k in range(1000):
        t = 10.0 + 0.01 * k
        w.write_stand(StandSample(t, 0.001, {"roll": 1.0}, {"roll": 0.0}, {"roll": 1.0}, st))
        w.write_instrument(InstrumentSample(t + 0.003, {"roll": 1.0}))
    w.close("done", "PASS", analysis_window=[13.0, 17.0])
    rec = load_recording(tmp_path / "r")
    tr, _, td, _ = rec.pair("roll")
    assert td.min() >= 13.0 and td.max() <= 17.0 and td.size == 400
    assert tr.min() == pytest.approx(12.0) and tr.max() == pytest.approx(18.0)
    assert rec.pair("roll", window=False)[2].size == 1000


def test_buffered_mode_needs_a_stand_with_a_queue(tmp_path: Path) -> None:
    """stand.mode buffered on a register map without a trajectory queue is refused before
    anything opens, naming the field and the map."""
    import yaml

    from benchctl.errors import ConfigError
    from benchctl.run import RunOptions
    from benchctl.run.prepare import prepare_motion

    root = ROOT
    raw = yaml.safe_load((root / "drivers/stand_generic.yaml").read_text())
    raw.pop("trajectory")
    raw["control_bits"].pop("start_trajectory")
    raw["status_bits"].pop("trajectory_running")
    plain = tmp_path / "plain.yaml"
    plain.write_text(yaml.safe_dump(raw))
    cfg = bench_config(tmp_path)
    stand = cfg.stand.model_copy(update={"mode": "buffered", "register_map": plain})
    cfg = cfg.model_copy(update={"stand": stand})
    with pytest.raises(ConfigError, match=r"stand\.mode = 'buffered'.*no trajectory queue"):
        prepare_motion(cfg, root / "profiles/ci_short.yaml", RunOptions("S", "O"))


def test_stand_samples_with_an_uncertain_stamp_are_left_out(tmp_path: Path) -> None:
    """A stand sample is stamped at its request/reply midpoint: one whose round trip took far
    longer than usual (held up mid-request) has a stamp uncertain by ±rtt/2 and is left out."""
    w = RecordingWriter(tmp_path / "r", ("roll",), {})
    st = StandStatus(True, True, False, False, False, False)
    for k in range(500):
        t = 10.0 + 0.01 * k
        rtt = 0.2 if k in (100, 300) else 0.0005 + 0.0001 * (k % 3)
        w.write_stand(StandSample(t, rtt, {"roll": float(k)}, {"roll": 0.0}, {"roll": 0.0}, st))
    w.close("done")
    tr, xr, _, _ = load_recording(tmp_path / "r").pair("roll", window=False)
    assert tr.size == 498 and 100.0 not in xr and 300.0 not in xr
