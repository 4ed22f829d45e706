"""A test as long as its precision needs (benchctl.run.precision): the stop rule, the schedule
of the checks, the early fade-out of the plan, the options, the report's ``ended``; and the
short profiles' σ against the 15-minute profile's for the simulated instruments."""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from repo_paths import ROOT

from benchctl.cli import main
from benchctl.config import SimInstrumentConfig, SimStandConfig, load_config
from benchctl.errors import ConfigError
from benchctl.kinematics import profile_peaks
from benchctl.profiles import load_profile, synthesize
from benchctl.run import RunOptions
from benchctl.run.plan import make_plan
from benchctl.run.precision import (
    MIN_PERIODS,
    REASON_PRECISION,
    AxisCheck,
    PrecisionWatch,
    decide_stop,
    relative_halfwidth,
)
from benchctl.run.prepare import prepare_motion
from benchctl.run.report import Report, format_report
from benchctl.run.state import RunState
from benchctl.sim.instrument_model import InstrumentModel
from benchctl.sim.servo import ServoModel

SETTINGS = settings(max_examples=200, deadline=None)

# ------------------------------------------------------------------ the stop rule
precisions = st.one_of(st.floats(min_value=0.0, max_value=2.0),
                       st.sampled_from([math.inf, math.nan]))


@pytest.mark.parametrize(
    ("precision", "requested", "periods", "alarm", "stop", "why"),
    [
        ({"roll": 0.03}, 0.05, 1, None, True, REASON_PRECISION),
        ({"roll": 0.05}, 0.05, 3, None, True, REASON_PRECISION),  # on the limit: enough
        ({"roll": 0.051}, 0.05, 3, None, False, "±5.10 % on roll, ±5.00 % requested"),
        ({"roll": 0.001}, 0.05, 0, None, False, "at least 1 needed"),  # never before a period
        ({"roll": 0.01}, None, 5, None, False, "no precision requested"),
        ({"roll": 0.01, "pitch": 0.2}, 0.1, 2, None, False, "on pitch"),  # the worst axis
        ({"roll": 0.01, "pitch": 0.09}, 0.1, 2, None, True, REASON_PRECISION),
        ({"roll": 0.01}, 0.1, 2, {"roll": True}, False, "excitation beyond its alarm level"),
        ({"roll": 0.01}, 0.1, 2, {"roll": False}, True, REASON_PRECISION),
        ({"roll": math.inf}, 0.1, 2, None, False, "no finite σ interval on roll"),
        ({"roll": 0.01, "pitch": math.nan}, 0.1, 2, None, False, "no finite σ interval on pitch"),
        ({}, 0.1, 2, None, False, "no axis"),
    ],
)
def test_stop_rule_examples(
    precision: dict[str, float], requested: float | None, periods: int,
    alarm: dict[str, bool] | None, stop: bool, why: str,
) -> None:
    d = decide_stop(precision, requested, periods, alarm)
    assert d.stop is stop
    assert why in d.reason


@SETTINGS
@given(
    precision=st.dictionaries(st.sampled_from(["roll", "pitch"]), precisions, max_size=2),
    requested=st.one_of(st.none(), st.floats(min_value=1e-4, max_value=0.999)),
    periods=st.integers(min_value=-1, max_value=50),
    alarm=st.dictionaries(st.sampled_from(["roll", "pitch"]), st.booleans(), max_size=2),
)
def test_stop_rule_properties(
    precision: dict[str, float], requested: float | None, periods: int, alarm: dict[str, bool]
) -> None:
    d = decide_stop(precision, requested, periods, alarm)
    assert d.reason  # always says why
    expected = (
        requested is not None
        and periods >= MIN_PERIODS
        and bool(precision)
        and not any(alarm.values())
        and all(math.isfinite(v) and v <= requested for v in precision.values())
    )
    assert d.stop is expected
    if d.stop:
        assert d.reason == REASON_PRECISION


@pytest.mark.parametrize("bad", [0.0, 1.0, -0.1, 1.5])
def test_stop_rule_refuses_a_meaningless_precision(bad: float) -> None:
    with pytest.raises(ValueError, match="expected 0 < value < 1"):
        decide_stop({"roll": 0.01}, bad, 3)


def test_relative_halfwidth() -> None:
    assert relative_halfwidth(1.0, (0.9, 1.2)) == pytest.approx(0.2)  # the larger side
    assert relative_halfwidth(2.0, (1.9, 2.1)) == pytest.approx(0.05)
    assert relative_halfwidth(0.0, (0.0, 0.1)) == math.inf
    assert relative_halfwidth(1.0, (math.nan, 1.1)) == math.inf


# ------------------------------------------------------------------ the checks' schedule
class _Analysis:
    """A stand-in for the analysis of the recording so far: each call a given precision; the
    calls' windows are kept."""

    def __init__(self, precision: list[float]) -> None:
        self.precision = precision
        self.windows: list[tuple[float, float]] = []
        self.release = threading.Event()
        self.release.set()

    def __call__(self, window: tuple[float, float]) -> dict[str, AxisCheck]:
        assert self.release.wait(30)
        self.windows.append(window)
        p = self.precision[len(self.windows) - 1]
        return {"roll": AxisCheck(1.0, (1 - p, 1 + p), p)}


def _finish(w: PrecisionWatch, now: float) -> Any:
    w.join(30)
    return w.poll(now)


def test_checks_at_whole_periods_only_and_stop_when_precise() -> None:
    an = _Analysis([0.2, 0.08, 0.04])
    w = PrecisionWatch(an, 0.05, t_steady=100.0, period_s=60.0, max_periods=5, delay_s=1.0)
    # fade-in and the first period: no check
    for now in (50.0, 100.0, 150.0, 160.9):
        assert w.poll(now) is None
        assert not w.busy
    assert w.poll(161.0) is None  # the first period ended (plus the delay): a check starts
    c = _finish(w, 161.1)
    assert c is not None and c.periods == 1 and not c.decision.stop
    assert c.window == (100.0, 160.0)
    assert "±20.00 % on roll" in c.decision.reason
    assert w.poll(200.0) is None and not w.busy  # within the second period: nothing
    w.poll(221.5)
    c = _finish(w, 221.6)
    assert c is not None and c.periods == 2 and not c.decision.stop
    w.poll(281.5)
    c = _finish(w, 281.6)
    assert c is not None and c.periods == 3 and c.decision.stop
    assert c.decision.reason == REASON_PRECISION and c.window == (100.0, 280.0)
    assert an.windows == [(100.0, 160.0), (100.0, 220.0), (100.0, 280.0)]


def test_a_slow_check_is_followed_by_one_over_all_periods_by_then() -> None:
    an = _Analysis([0.3, 0.3, 0.3])
    an.release.clear()
    w = PrecisionWatch(an, 0.05, t_steady=0.0, period_s=10.0, max_periods=20, delay_s=0.0)
    w.poll(10.0)
    assert w.busy
    assert w.poll(35.0) is None  # still busy: no second check at once
    an.release.set()
    c = _finish(w, 35.0)
    assert c is not None and c.periods == 1
    w.poll(35.0)
    c = _finish(w, 35.0)
    assert c is not None and c.periods == 3  # the periods by then, not 2 then 3


def test_no_check_at_the_profiles_own_end_and_a_failed_check_goes_on() -> None:
    def failing(window: tuple[float, float]) -> dict[str, AxisCheck]:
        raise ConfigError("no samples")

    w = PrecisionWatch(failing, 0.05, t_steady=0.0, period_s=10.0, max_periods=2, delay_s=0.0)
    w.poll(10.0)
    c = _finish(w, 10.0)
    assert c is not None and not c.decision.stop and c.error is not None
    assert "no precision check over 1 period(s): no samples" in c.error
    w.poll(25.0)  # 2 periods = the whole profile: no check, it ends anyway
    assert not w.busy and w.poll(25.0) is None


# ------------------------------------------------------------------ the early fade-out
def _plan(duration: float = 40.0, rate: float = 100.0) -> Any:
    def evaluate(t: np.ndarray) -> dict[str, np.ndarray]:
        return {"roll": 5.0 * np.sin(2 * np.pi * 0.2 * t) + 2.0 * np.cos(2 * np.pi * 0.45 * t)}

    return make_plan(evaluate, ("roll",), duration, rate, 3.0, 3.0)


@SETTINGS
@given(k=st.integers(min_value=301, max_value=3400), fade=st.floats(min_value=0.5, max_value=6))
def test_ending_early_fades_out_from_the_slot(k: int, fade: float) -> None:
    plan = _plan()
    new = plan.ending_at(k, fade)
    v, w = plan.values["roll"], new.values["roll"]
    n_fade = round(new.fade_out_s / plan.period_s)
    assert n_fade == max(2, math.ceil(fade / plan.period_s - 1e-9))
    np.testing.assert_array_equal(w[: k + 1], v[: k + 1])  # up to the slot: as it was
    assert w.size == k + n_fade + 1 and w[-1] == 0.0  # then at rest at zero
    assert new.duration_s == pytest.approx((k + n_fade) * plan.period_s)
    assert new.state_at(k * plan.period_s - 1e-6) is RunState.RUNNING  # after the fade-in
    assert new.state_at(k * plan.period_s + 1e-6) is RunState.FADE_OUT
    # no jump: the rate and acceleration stay within what the profile and the fade need
    r0, a0 = profile_peaks(v, plan.period_s)
    r1, a1 = profile_peaks(w[max(0, k - 2):], plan.period_s)
    amp = float(np.max(np.abs(v)))
    assert r1 <= r0 + amp * math.pi / (2 * new.fade_out_s) + 1e-9
    assert a1 <= a0 + 2 * r0 * math.pi / (2 * new.fade_out_s) + amp * (
        math.pi / new.fade_out_s) ** 2 / 2 + 1e-9
    assert plan.values["roll"] is v  # the plan itself unchanged


def test_ending_early_outside_the_plan_is_refused() -> None:
    with pytest.raises(ValueError, match="outside"):
        _plan().ending_at(10_000, 3.0)


# ------------------------------------------------------------------ options and report
def _cfg_file(tmp_path: Path, **run: Any) -> Path:
    data = yaml.safe_load((ROOT / "config/sim.yaml").read_text())
    data.pop("sim")
    data["stand"]["register_map"] = str(ROOT / "drivers/stand_generic.yaml")
    data["instrument"]["eds"] = str(ROOT / "drivers/cia410_inclinometer.eds")
    data["stand"]["port"] = 1  # nothing listens: nothing may be opened
    data["run"].update(output_dir=str(tmp_path / "runs"), **run)
    p = tmp_path / "bench.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _run(cfg: Path, profile: str, *extra: str) -> int:
    return main(["run", "--config", str(cfg), "--profile", str(ROOT / profile), "--serial", "S",
                 "--operator", "O", *extra])


@pytest.mark.parametrize("bad", ["0", "1", "-0.05", "1.5", "nan", "inf"])
def test_cli_precision_out_of_range_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], bad: str
) -> None:
    assert _run(_cfg_file(tmp_path), "profiles/paper_vessel_roll_short.yaml",
                "--precision", bad) == 2
    err = capsys.readouterr().err
    assert f"--precision {float(bad)!r}" in err and "0 < value < 1" in err, err
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("bad", [0, 1, -0.2, 2.0])
def test_config_precision_out_of_range_refused(tmp_path: Path, bad: float) -> None:
    with pytest.raises(ConfigError, match=r"run\.precision"):
        load_config(_cfg_file(tmp_path, precision=bad))


def test_precision_needs_a_periodic_multisine_and_no_table_mode(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = load_config(_cfg_file(tmp_path, precision=0.05))
    with pytest.raises(ConfigError, match=r"field run.precision = 0.05.*no repetition period|"
                       r"field run.precision = 0.05.*periodic multisine"):
        prepare_motion(cfg, ROOT / "profiles/linearity_sine_steps.yaml", RunOptions("S", "O"))
    base = load_config(_cfg_file(tmp_path))
    table = base.model_copy(update={"stand": base.stand.model_copy(update={"mode": "table"})})
    with pytest.raises(ConfigError, match=r"--precision 0\.1: a precision stop needs stand\.mode"):
        prepare_motion(table, ROOT / "profiles/paper_vessel_roll_short.yaml",
                       RunOptions("S", "O", precision=0.1))
    prep = prepare_motion(cfg, ROOT / "profiles/paper_vessel_roll_short.yaml",
                          RunOptions("S", "O", precision=0.02))  # the option wins
    assert prep.meta["precision_requested"] == 0.02
    assert _run(_cfg_file(tmp_path), "profiles/linearity_sine_steps.yaml",
                "--precision", "0.05") == 2
    assert "--precision 0.05" in capsys.readouterr().err


def test_report_states_why_the_motion_ended(tmp_path: Path) -> None:
    ended = {"reason": REASON_PRECISION, "precision": 0.0412, "requested": 0.05,
             "motion_s": 81.3, "periods": 1, "period_s": 60.0}
    rep = Report({}, tmp_path, {"serial": "S"}, {}, (0.0, 60.0), ended)
    assert rep.to_dict()["ended"] == ended
    text = format_report(rep)
    assert ("ended: precision reached; precision ±4.12 % (95 %), requested ±5.00 %, "
            "1 period(s) of 60 s; motion 81.3 s") in text


# ------------------------------------------------------------------ short vs long profile σ
# the second instrument model of benchmarks/test_time.py: slower and noisier
SLOW_MODEL = {"gain": 0.98, "lag_s": 0.25, "latency_s": 0.02, "bias_deg": 0.1,
              "noise_deg": 0.2, "seed": 11}


def _sim_models(extra: dict[str, Any]) -> tuple[ServoModel, InstrumentModel]:
    data = yaml.safe_load((ROOT / "config/sim.yaml").read_text())["sim"]
    sc = SimStandConfig(**data["stand"])
    servo = ServoModel(sc.bandwidth_hz, sc.damping, sc.rate_limit_deg_s, sc.accel_limit_deg_s2,
                       1.0 / sc.tick_hz)
    return servo, InstrumentModel(SimInstrumentConfig(**{**data["instrument"], **extra}))


def _model_sigma(profile: str, servo: ServoModel, inst: InstrumentModel) -> tuple[float, float]:
    """σ the simulated bench shows for the profile's steady part (the instrument's stated
    response to the stand's motion through the servo), and the linear part's share of σ²."""
    motion = synthesize(load_profile(ROOT / profile), setpoint_rate_hz=100.0)
    assert motion.tables is not None
    tab = motion.tables["roll"]
    amp = tab.amp_deg * np.array([abs(complex(servo.response(f))) for f in tab.freq_hz])
    var = inst.expected_error_variance(amp, tab.freq_hz, resolution_deg=0.01)
    quiet = InstrumentModel(inst.cfg.model_copy(update={"noise_deg": 0.0}))
    lin = quiet.expected_error_variance(amp, tab.freq_hz)
    return math.sqrt(var), lin / var


@pytest.mark.parametrize("model", [{}, SLOW_MODEL], ids=["default", "slow-noisy"])
@pytest.mark.parametrize("short", ["paper_vessel_roll_short.yaml",
                                   "paper_vessel_roll_short120.yaml"])
def test_short_profiles_sigma_as_the_15_minute_profile(model: dict[str, Any], short: str) -> None:
    """The short profiles keep the paper profile's spectrum: the σ the simulated instrument
    shows for them is the 15-minute profile's within 1 % (their lines sample the same
    spectrum more coarsely), well inside a ±5 % interval."""
    servo, inst = _sim_models(model)
    long_sigma, share = _model_sigma("profiles/paper_vessel_roll.yaml", servo, inst)
    short_sigma, _ = _model_sigma(f"profiles/{short}", servo, inst)
    assert short_sigma == pytest.approx(long_sigma, rel=0.01), (short_sigma, long_sigma)
    assert 0.05 < share < 0.999  # a real dynamic error, not noise alone nor noise-free
