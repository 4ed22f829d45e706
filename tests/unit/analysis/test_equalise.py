"""Equalisation (benchctl.analysis.equalise) on synthetic stands, and its run plumbing.

The stand is the simulated servo's own physics (``benchctl.sim.servo.servo_step``, limits far
away) stepped in the time domain: the pre-test's measured response must be the servo's
discrete model ``ServoModel.response`` at the lines, and the corrected drive played through
the same servo must give the target lines within 0.05 dB and 0.5°. A correction needing more
than the stand's rate/acceleration is capped (reported) and the drive stays within the limits.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from repo_paths import ROOT

from benchctl.analysis.equalise import (
    _peaks,
    corrected_table,
    estimate_response,
    pretest_design,
    response_at,
)
from benchctl.analysis.excitation import fidelity_of_table
from benchctl.analysis.fidelitylimits import StandReach
from benchctl.clock.virtual import VirtualClock
from benchctl.config import load_config
from benchctl.errors import ConfigError, DataError
from benchctl.harmonics import HarmonicTable
from benchctl.profiles import load_profile, synthesize
from benchctl.run.prepare import RunOptions, prepare_motion
from benchctl.run.state import RunState, StateMachine, TransitionError
from benchctl.sim.servo import AxisState, ServoModel, servo_step

T0 = 500.0  # the motion's start on the stand's clock
TICK = 0.001
SERVO = ServoModel(0.8, 0.3, 1e4, 1e6, TICK)  # config/sim_resonant.yaml's stand, no limits
WIDE = StandReach(30.0, 30.0, 60.0)  # config/sim_resonant.yaml's limits


def ci_short_table() -> HarmonicTable:
    motion = synthesize(load_profile(ROOT / "profiles/ci_short.yaml"), setpoint_rate_hz=100.0)
    assert motion.tables is not None
    return motion.tables["roll"]


def play(table: HarmonicTable, model: ServoModel = SERVO, every: int = 10,
         noise_deg: float = 0.0, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """The servo's angle (every ``every`` ticks, from T0) driven by ``table`` tick by tick."""
    n = round(table.duration_s / model.tick_s) + 200
    t = np.arange(n) * model.tick_s
    r = table.evaluate(t)
    s = AxisState()
    x = np.empty(n)
    for k in range(n):
        x[k] = s.angle_deg
        servo_step(model, s, float(r[k]))
    keep = slice(0, n, every)
    xs = x[keep] + np.random.default_rng(seed).normal(0.0, noise_deg, x[keep].size)
    return T0 + t[keep], xs


def test_pretest_on_the_profiles_own_lines() -> None:
    tab = ci_short_table()
    d = pretest_design(tab, level=0.2, periods=1, max_period_s=20.0, fade_s=2.0, settle_s=3.0)
    assert d.own_lines and d.period_s == pytest.approx(19.0)
    use = tab.amp_deg > 0
    np.testing.assert_allclose(d.table.freq_hz, tab.freq_hz[use])
    np.testing.assert_allclose(d.table.amp_deg, 0.2 * tab.amp_deg[use])
    np.testing.assert_allclose(d.table.phase_rad, tab.phase_rad[use])
    assert d.analysis_start_s == pytest.approx(5.0)
    assert d.table.duration_s == pytest.approx(2 + 3 + 19 + 2)


def test_pretest_on_a_shorter_period_for_a_long_profile() -> None:
    f = np.arange(12, 61) / 120.0  # T_p 120 s: 0.1 … 0.5 Hz
    a = np.linspace(1.0, 0.2, f.size)
    tab = HarmonicTable(f, a, np.zeros_like(f), 130.0, 5.0, 5.0, 120.0)
    d = pretest_design(tab, level=0.2, max_period_s=20.0)
    assert not d.own_lines and d.period_s == pytest.approx(20.0)
    assert d.table.duration_s < 30.0  # seconds, not minutes
    # lines on 1/20 s nearest the profile's, with 0.2² of the profile's power
    np.testing.assert_allclose(d.table.freq_hz * 20.0, np.round(d.table.freq_hz * 20.0))
    assert d.table.freq_hz.min() == pytest.approx(0.1) and d.table.freq_hz.max() == pytest.approx(
        0.5)
    assert np.sum(d.table.amp_deg**2) == pytest.approx(0.04 * np.sum(a**2))


def test_pretest_needs_a_period() -> None:
    tab = HarmonicTable(np.array([0.1]), np.array([1.0]), np.zeros(1), 20.0, 2.0, 2.0, None)
    with pytest.raises(DataError, match="period"):
        pretest_design(tab)


def test_response_and_corrected_drive_through_the_servo() -> None:
    tab = ci_short_table()
    d = pretest_design(tab, level=0.2)
    t, x = play(d.table, noise_deg=0.002)
    resp = estimate_response(t, x, d, T0)
    true = SERVO.response(resp.freq_hz)
    err_db = resp.gain_db - 20 * np.log10(np.abs(true))
    err_ph = np.degrees(np.angle(resp.h / true))
    strong = d.table.amp_deg > 0.1 * d.table.amp_deg.max()
    assert np.max(np.abs(err_db[strong])) < 0.05, err_db
    assert np.max(np.abs(err_ph[strong])) < 0.5, err_ph
    # the uncorrected profile misses (the resonance lifts its upper lines by ~1 … 3 dB)
    use = tab.amp_deg > 0
    win = (T0 + tab.fade_in_s, T0 + tab.duration_s - tab.fade_out_s)
    t0, x0 = play(tab)
    before = fidelity_of_table(t0, x0, tab, win, T0)
    assert np.max(before.error_db) > 2.0
    # the corrected drive played through the same servo gives the target lines
    h, sd = response_at(resp, tab.freq_hz)
    corr = corrected_table(tab, h, sd, WIDE, 100.0)
    assert all(s == "corrected" for s, u in zip(corr.status, use, strict=True) if u)
    t1, x1 = play(corr.drive)
    after = fidelity_of_table(t1, x1, tab, win, T0)
    judged = after.target_amp > 0.1 * after.target_amp.max()
    assert np.max(np.abs(after.error_db[judged])) < 0.05, after.error_db
    assert np.max(np.abs(after.phase_deg[judged])) < 0.5, after.phase_deg
    assert abs(after.variance_ratio - 1.0) < 0.005
    assert abs(before.variance_ratio - 1.0) > 0.05


def test_response_interpolated_between_the_pretest_lines() -> None:
    from benchctl.analysis.equalise import Response

    fc = np.arange(2, 11) / 20.0
    resp = Response(fc, SERVO.response(fc), np.full(fc.size, 1e-4), 1)
    f = np.arange(12, 61) / 120.0
    h, sd = response_at(resp, f)
    true = SERVO.response(f)
    assert np.max(np.abs(20 * np.log10(np.abs(h / true)))) < 0.3
    assert np.max(np.abs(np.degrees(np.angle(h / true)))) < 3.0
    assert np.all(sd > 0)


def test_boost_beyond_the_limits_is_capped_and_reported() -> None:
    # lines above a slow stand's resonance: it moves them −5 … −23 dB, so the drive would need
    # up to 10× the amplitude (the lines below −20 dB are not corrected at all); the
    # acceleration limit allows much less
    from benchctl.analysis.equalise import _schroeder

    f = np.arange(10, 31) / 20.0  # 0.5 … 1.5 Hz
    a = np.full(f.size, 0.1)
    tab = HarmonicTable(f, a, _schroeder(f.size), 26.0, 3.0, 3.0, 20.0)
    slow = ServoModel(0.4, 0.7, 1e4, 1e6, TICK)
    h = slow.response(f)
    reach = StandReach(30.0, 15.0, 60.0)
    assert max(_peaks(tab, 100.0)[2], 0.0) < reach.accel_deg_s2  # the target itself fits
    corr = corrected_table(tab, h, np.full(f.size, 1e-4), reach, 100.0, max_boost_db=40.0)
    pa, pr, pacc = _peaks(corr.drive, 100.0)
    assert pa <= reach.angle_deg and pr <= reach.rate_deg_s and pacc <= reach.accel_deg_s2
    weak = 20 * np.log10(np.abs(h)) < -20.0
    assert [s == "weak_response" for s in corr.status] == list(weak)
    assert all(s == "capped" for s, w in zip(corr.status, weak, strict=True) if not w)
    assert len(corr.not_corrected) == f.size
    assert all(r["applied_db"] < r["wanted_db"] for r in corr.not_corrected)
    assert 0.0 < corr.boost_fraction < 1.0 and corr.notes
    # without limits in the way every line above −20 dB gets its whole correction
    free = corrected_table(tab, h, np.full(f.size, 1e-4), StandReach(1e3, 1e4, 1e6), 100.0,
                           max_boost_db=40.0)
    assert all(s == "corrected" for s, w in zip(free.status, weak, strict=True) if not w)
    np.testing.assert_allclose(free.applied_db[~weak], free.wanted_db[~weak])
    assert _peaks(free.drive, 100.0)[2] > reach.accel_deg_s2  # what the limits stopped


def test_weak_and_uncertain_lines_are_not_corrected() -> None:
    f = np.array([0.1, 0.2, 0.3])
    tab = HarmonicTable(f, np.ones(3), np.zeros(3), 26.0, 3.0, 3.0, 20.0)
    h = np.array([1.2 * np.exp(-0.3j), 0.05 + 0j, 0.9 * np.exp(-0.5j)])
    sd = np.array([1e-3, 1e-3, 0.2])  # the last: ±1.9 dB, over 0.5 dB
    corr = corrected_table(tab, h, sd, WIDE, 100.0)
    assert corr.status == ["corrected", "weak_response", "uncertain"]
    np.testing.assert_allclose(corr.drive.amp_deg, [1 / 1.2, 1.0, 1.0])
    np.testing.assert_allclose(corr.drive.phase_rad, [0.3, 0.0, 0.0])
    assert [r["status"] for r in corr.not_corrected] == ["weak_response", "uncertain"]


def test_state_machine_equalising_is_optional() -> None:
    sm = StateMachine()
    sm.to(RunState.PRECHECKS)
    sm.advance_to(RunState.RUNNING)  # no pre-test: straight to fade-in
    assert RunState.EQUALISING not in [s for s, _ in sm.history]
    sm = StateMachine()
    sm.to(RunState.PRECHECKS)
    sm.to(RunState.EQUALISING)
    sm.advance_to(RunState.RUNNING)
    assert [s for s, _ in sm.history][-3:] == [RunState.EQUALISING, RunState.FADE_IN,
                                              RunState.RUNNING]
    with pytest.raises(TransitionError):
        sm.to(RunState.EQUALISING)
    sm = StateMachine()
    sm.to(RunState.PRECHECKS)
    with pytest.raises(TransitionError):
        sm.advance_to(RunState.EQUALISING)


def _config(tmp_path: Path, equalise: dict[str, object]) -> Path:
    data = yaml.safe_load((ROOT / "config/sim_resonant.yaml").read_text())
    data["stand"]["register_map"] = str(ROOT / "drivers/stand_generic.yaml")
    data["instrument"]["eds"] = str(ROOT / "drivers/cia410_inclinometer.eds")
    data["run"]["output_dir"] = str(tmp_path / "runs")
    data["run"]["equalise"] = equalise
    p = tmp_path / "bench.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def test_config_rejects_a_bad_level(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"run\.equalise\.level"):
        load_config(_config(tmp_path, {"enabled": True, "level": 1.5}))


def test_prepare_checks_the_pretest(tmp_path: Path) -> None:
    cfg = load_config(_config(tmp_path, {"enabled": True}))
    prep = prepare_motion(cfg, ROOT / "profiles/ci_short.yaml", RunOptions("s", "o"))
    assert prep.pretest is not None
    assert prep.pretest.check["ok"] and prep.pretest.plan.duration_s == pytest.approx(26.0)
    assert prep.meta["equalise_requested"] is True
    assert math.isclose(prep.meta["equalise_pretest"]["axes"]["roll"]["period_s"], 19.0)
    off = prepare_motion(cfg, ROOT / "profiles/ci_short.yaml",
                         RunOptions("s", "o", equalise=False))
    assert off.pretest is None


def test_equalise_refuses_a_profile_without_lines(tmp_path: Path) -> None:
    cfg = load_config(_config(tmp_path, {"enabled": False}))
    with pytest.raises(ConfigError, match=r"--equalise.*harmonic table"):
        prepare_motion(cfg, ROOT / "profiles/linearity_sine_steps.yaml",
                       RunOptions("s", "o", equalise=True))


# ---- the pre-test in the session, against in-process fakes (tests/helpers/run_fakes.py), on
# simulated time: a loaded host cannot stall the stand loop ("stand loop stalled: no cycle for
# 4.1 s")
def _fake_session(
    tmp_path: Path, clock: VirtualClock, mode: str = "stream"
) -> tuple[Any, Any, Any]:
    from run_fakes import FakeSensor, FakeStand, bench_config, sine_motion

    from benchctl.profiles.motion import TableMotion
    from benchctl.run.prepare import prepare_pretest
    from benchctl.run.session import Session

    cfg = bench_config(tmp_path, equalise={"enabled": True, "fade_s": 0.5, "settle_s": 0.5})
    cfg = cfg.model_copy(update={"stand": cfg.stand.model_copy(update={"mode": mode})})
    tab = HarmonicTable(np.array([0.5, 1.0]), np.array([4.0, 1.0]), np.array([0.0, 0.3]),
                        5.0, 0.5, 0.5, 2.0)
    motion = TableMotion("fake-lines", "harmonics", {"roll": tab}, {"roll": None}, 1)
    prep = sine_motion(("roll",), duration_s=5.0, mode=mode, fade_s=0.5)
    plan = dataclasses.replace(prep.plan, tables={"roll": tab}, values={
        "roll": tab.evaluate(np.arange(prep.plan.n_slots) * prep.plan.period_s)})
    prep = dataclasses.replace(prep, motion=motion, plan=plan,
                               pretest=prepare_pretest(cfg, motion, 100.0, "test"))
    stand = FakeStand(("roll",), clock=clock)
    sensor = FakeSensor(stand)
    sess = Session(cfg, prep, RunOptions("SN-EQ", "tester"),
                   device_factory=lambda c, p: (stand, sensor), clock=clock)
    return sess, stand, sensor


@pytest.mark.parametrize("mode", ["stream", "table"])
def test_session_pretest_on_a_stand_that_follows(
    tmp_path: Path, mode: str, vclock: VirtualClock
) -> None:
    """A stand that follows its setpoints exactly: |H_s| = 0 dB, the drive unchanged in
    amplitude; the pre-test is a state of its own, before the profile's motion_start."""
    from benchctl.recording import load_recording

    sess, _, _ = _fake_session(tmp_path, vclock, mode)
    res = sess.run()
    assert res.state == "done", res.reason
    rec = load_recording(res.recording)
    states = [e["to"] for e in rec.events if e["kind"] == "state"]
    assert states == ["prechecks", "equalising", "fade-in", "running", "fade-out", "analysing",
                      "done"]
    kinds = [e["kind"] for e in rec.events]
    assert kinds.index("equalise_done") < kinds.index("motion_start")
    roll = rec.meta["equalisation"]["axes"]["roll"]
    assert np.max(np.abs(roll["gain_db"])) < 0.05, roll
    assert roll["status"] == ["corrected", "corrected"]
    assert res.report.meta["equalisation"]["axes"]["roll"]["gain_db"] == roll["gain_db"]
    if mode == "table":  # the pre-test's table, then the corrected one
        assert kinds.count("table_uploaded") == 2


def test_session_fault_during_the_pretest_takes_the_one_cleanup_path(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    from benchctl.recording import load_recording

    sess, stand, sensor = _fake_session(tmp_path, vclock)
    stand.fault_at = 1.5  # the pre-test's motion time
    res = sess.run()
    assert res.state == "aborted" and res.exit_code == 2 and "fault code" in res.reason
    rec = load_recording(res.recording)
    assert rec.state == "aborted"
    states = [e["to"] for e in rec.events if e["kind"] == "state"]
    assert states == ["prechecks", "equalising", "aborted"]
    kinds = [e["kind"] for e in rec.events]
    assert "equalise_motion_start" in kinds and "motion_start" not in kinds
    assert "equalise_done" not in kinds
    assert stand.ramped and stand.enabled is False and stand.closed
    assert sensor.closed
