"""The whole session against in-process fakes of the Stand and AngleSensor protocols: the
state machine's course, the verdict, and the one cleanup path for each way out. On simulated
time (the ``vclock`` fixture): the fakes, the run's threads and its waits on one VirtualClock.

(The end-to-end tests over the real protocols and simulators are in test_run_e2e.py; a real
SIGINT mid-motion, on the host's time — the OS runs its handler in the main thread whenever it
arrives, outside a virtual clock's one-thread-at-a-time schedule —, with the run's cleanup
checked step by step: tests/e2e/test_plan_sim.py's Ctrl-C in a plan, ``realtime``.)
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from run_fakes import FakeSensor, FakeStand, bench_config, sigma_sine_gain, sine_motion

from benchctl.clock import Clock
from benchctl.clock.virtual import VirtualClock
from benchctl.config import BenchConfig
from benchctl.recording import load_recording
from benchctl.run.prepare import RunOptions
from benchctl.run.session import RunResult, Session

DURATION, FADE = 5.0, 0.5  # steady part 4 s: whole periods of 0.5 Hz and 1 Hz
#: the fake instrument's white noise where a σ's interval is checked: on simulated time nothing
#: else is random (without it the interval is a point, and σ's 0.01 % from the stand's 100 Hz
#: steps lies outside it)
NOISE_DEG = 0.01


def _run(
    tmp_path: Path,
    stand: FakeStand,
    sensor: FakeSensor,
    *,
    mode: str = "table",
    cfg: BenchConfig | None = None,
    duration: float = DURATION,
) -> RunResult:
    cfg = cfg or bench_config(tmp_path)
    prep = sine_motion(stand.axes, duration_s=duration, mode=mode, fade_s=FADE)
    clock: Clock = stand.clock
    sess = Session(
        cfg, prep, RunOptions("SN-1", "tester"), device_factory=lambda c, p: (stand, sensor),
        clock=clock,
    )
    return sess.run()


def _events(path: Path) -> list[dict[str, Any]]:
    return load_recording(path).events


def _states(path: Path) -> list[str]:
    return [e["to"] for e in _events(path) if e["kind"] == "state"]


@pytest.mark.parametrize("axes", [("roll",), ("roll", "pitch")])
def test_full_run_pass_per_axis_sigma(
    tmp_path: Path, axes: tuple[str, ...], vclock: VirtualClock
) -> None:
    """Gain 1.05 on a 5° sine over whole periods: σ = 0.05·5/√2 = 0.177° per axis → PASS.

    On simulated time nothing jitters: the instrument's white noise of 0.01° (a real one has
    some) is what the interval covers, and the stated σ includes it: √(0.177² + 0.01²)."""
    stand = FakeStand(axes, clock=vclock)
    sensor = FakeSensor(stand, gain=1.05)
    sensor.noise = NOISE_DEG
    res = _run(tmp_path, stand, sensor)
    assert res.state == "done" and res.exit_code == 0, res.reason
    assert res.report is not None and res.report.verdict == "PASS"
    expect = math.hypot(sigma_sine_gain(5.0, 1.05), NOISE_DEG)
    for a in axes:
        v = res.report.axes[a]
        assert v.sigma_deg == pytest.approx(expect, rel=0.02)
        assert v.sigma_ci95_deg[0] <= expect <= v.sigma_ci95_deg[1]
    rec = load_recording(res.recording)  # type: ignore[arg-type]
    assert rec.state == "done" and rec.end is not None and rec.end["reason"] == "PASS"
    assert _states(rec.path) == ["prechecks", "fade-in", "running", "fade-out", "analysing", "done"]
    assert rec.meta["serial"] == "SN-1" and rec.meta["operator"] == "tester"
    assert rec.meta["station"] == "test-bench" and rec.meta["seed"] == 1
    assert rec.meta["devices"]["stand"]["model"] == "stand"
    assert rec.meta["config"]["run"]["limit_sigma_deg"] == 0.4
    rep = json.loads((rec.path / "report.json").read_text())
    assert rep["verdict"] == "PASS" and set(rep["axes"]) == set(axes)
    assert "PASS" in (rec.path / "report.txt").read_text()
    index = (tmp_path / "index.jsonl").read_text().splitlines()
    assert json.loads(index[-1])["verdict"] == "PASS"
    assert stand.enabled is False and stand.closed and sensor.closed
    names = [e["name"] for e in _events(rec.path) if e["kind"] == "precheck"]
    assert names[:2] == ["disk space", "profile within limits"]
    assert "static agreement" in names and "stand at zero" in names


def test_full_run_fail_and_stream_mode(tmp_path: Path, vclock: VirtualClock) -> None:
    """Gain 1.2: σ = 0.2·5/√2 = 0.707° > 0.4° → FAIL, exit 1 (stream mode). On a busy host
    the streaming stand holds and rejoins: when those departures touch every period of the
    window, σ is not judged — INCONCLUSIVE, exit 3, saying so — never a FAIL on another
    motion."""
    stand = FakeStand(clock=vclock)
    sensor = FakeSensor(stand, gain=1.2)
    res = _run(tmp_path, stand, sensor, mode="stream")
    assert res.report is not None and res.report.axes["roll"].sigma_deg > 0.4
    dep = res.report.axes["roll"].analysis["departures"]
    if dep is not None and dep["too_little"]:
        assert res.state == "done" and res.exit_code == 3 and res.stats["rejoins"] >= 1
        assert res.report.verdict == "INCONCLUSIVE"
    else:
        assert res.state == "done" and res.exit_code == 1
        assert res.report.verdict == "FAIL"
    rec = load_recording(res.recording)  # type: ignore[arg-type]
    sp = rec.streams["setpoints"]
    st = res.stats
    # every slot of the profile sent, missed or stale (a busy host); a rejoin near the end
    # adds its own points past the last slot
    extra = sum(e["points"] for e in rec.events if e["kind"] == "rejoin")
    slots = int(DURATION * 100) + 1
    n = sp["t_send"].size + st["missed_cycles"] + st["stale_setpoints"]
    assert slots <= n <= slots + extra


def test_a_motion_that_was_not_the_profiles_is_not_judged(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    """Stream mode, the host held up 0.3 s at 2 s into the motion: the stand held, the loop
    rejoined. With the bench's 3 s of settling that leaves less than half of the 4 s window
    under the profile's motion: σ (0.177°, well within 0.4°) is not judged — INCONCLUSIVE,
    exit 3 — and the report, report.html and record.json say why."""
    stand = FakeStand(clock=vclock)
    stand.stall_at, stand.stall_s = 2.0, 0.3
    sensor = FakeSensor(stand, gain=1.05)
    cfg = bench_config(tmp_path, analysis={"departure_settle_s": 3.0})
    res = _run(tmp_path, stand, sensor, mode="stream", cfg=cfg)
    assert res.state == "done" and res.exit_code == 3, res.reason
    assert res.report is not None and res.report.verdict == "INCONCLUSIVE"
    assert res.stats["rejoins"] >= 1
    v = res.report.axes["roll"]
    assert v.sigma_outcome == "INCONCLUSIVE" and v.sigma_inconclusive is not None
    dep = v.analysis["departures"]
    assert dep["too_little"] and dep["rejoins"] >= 1 and dep["settle_s"] == 3.0
    folder = res.recording
    assert folder is not None
    rep = json.loads((folder / "report.json").read_text())
    assert rep["verdict"] == "INCONCLUSIVE" and rep["axes"]["roll"]["sigma_inconclusive"]
    assert "σ not judged (INCONCLUSIVE)" in (folder / "report.txt").read_text()
    assert "motion not the profile&#39;s" in (folder / "report.html").read_text()
    record = json.loads((folder / "record.json").read_text())
    sigma = next(m for m in record["measurements"] if m["name"] == "sigma")
    assert sigma["outcome"] == "INCONCLUSIVE" and "not judged" in sigma["note"]
    assert record["outcome"] == "INCONCLUSIVE" and record["exit_code"] == 3
    assert any("not the profile's" in w for w in record["warnings"])


def _assert_aborted(
    res: RunResult, stand: FakeStand, sensor: FakeSensor, match: str
) -> dict[str, Any]:
    assert res.state == "aborted" and res.exit_code == 2
    assert match in res.reason, res.reason
    assert res.recording is not None
    rec = load_recording(res.recording)
    assert rec.state == "aborted" and match in rec.end["reason"]  # type: ignore[index]
    assert _states(rec.path)[-1] == "aborted"
    assert not stand.enabled and "disable" in stand.calls
    assert stand.closed and sensor.stopped
    # what the recording holds is readable by the analysis
    from benchctl.evaluate import analyze_recording

    if rec.streams["instrument"]["t_host"].size > 50:
        r = analyze_recording(rec.path, stand.axes[0])
        assert math.isfinite(r.sigma)
    return rec.end  # type: ignore[return-value]


@pytest.mark.parametrize(
    ("inject", "match"),
    [
        ("fault", "fault code 7"),
        ("estop", "E-stop"),
        ("drop", "ConnectionLost"),
        ("exception", "unexpected RuntimeError"),
        ("silent", "instrument silent"),
        ("reader", "instrument reader"),
        ("tracking", "tracking error"),
        ("limit", "limit breach: roll angle"),
        ("departure", "departs from the profile on roll"),
    ],
)
def test_every_way_out_takes_the_one_cleanup_path(
    tmp_path: Path, inject: str, match: str, vclock: VirtualClock
) -> None:
    stand = FakeStand(clock=vclock)
    sensor = FakeSensor(stand)
    at = 1.2
    if inject == "fault":
        stand.fault_at = at
    elif inject == "estop":
        stand.estop_at = at
    elif inject == "drop":
        stand.drop_at = at
    elif inject == "exception":
        stand.raise_at = at
    elif inject == "silent":
        sensor.silent_after = at
    elif inject == "reader":
        sensor.error_after = at
    elif inject == "tracking":

        def off(tm: float) -> None:
            if tm >= at:
                stand.offset_deg = 0.8

        stand.on_motion_time = off
    elif inject == "departure":  # follows its own setpoint, but its motion is 1.3× the profile
        stand.motion_gain = 1.3
    elif inject == "limit":  # the stand itself goes beyond its angle limit (20°) while moving

        def beyond(tm: float) -> None:
            if tm >= at:
                stand.offset_deg = 30.0

        stand.on_motion_time = beyond
    cfg = bench_config(tmp_path)
    res = _run(tmp_path, stand, sensor, mode="stream", cfg=cfg)
    end = _assert_aborted(res, stand, sensor, match)
    steps = {s["step"]: s["ok"] for s in end["shutdown"]}
    assert steps["stop loops"] and steps["disable"]
    if inject == "drop":
        assert steps["ramp to zero"] is False  # the stand did not answer: noted, cleanup went on
    else:
        assert stand.ramped and steps["ramp to zero"]
    assert end["stats"]["setpoints_sent"] > 50  # it was moving when it happened


def test_precheck_failure_never_moves_the_stand(tmp_path: Path, vclock: VirtualClock) -> None:
    """An instrument 1° off the stand at rest: refused in prechecks, the stand never enabled."""
    stand = FakeStand(clock=vclock)
    sensor = FakeSensor(stand, bias=1.0)
    res = _run(tmp_path, stand, sensor)
    assert res.exit_code == 2 and "static agreement" in res.reason and "+1.000°" in res.reason
    assert "enable" not in stand.calls and "ramp_to_zero" not in stand.calls
    assert load_recording(res.recording).state == "aborted"  # type: ignore[arg-type]


def test_precheck_slow_instrument(tmp_path: Path, vclock: VirtualClock) -> None:
    stand = FakeStand(clock=vclock)
    sensor = FakeSensor(stand, rate_hz=40.0)
    res = _run(tmp_path, stand, sensor)
    assert (
        res.exit_code == 2
        and "instrument streams" in res.reason
        and "expected 100 Hz" in res.reason
    )
    assert "enable" not in stand.calls
