"""On the simulators: an odd two-axis multisine run finds the simulated instrument's cubic term
(nonlinear distortion detected) and its cross-axis coupling (within 5 %); a linear instrument
without coupling shows neither. Each run has 36 s of steady motion."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from live_bench import live_bench

from benchctl.clock.virtual import VirtualClock
from benchctl.config import CrossAxisConfig, SimInstrumentConfig
from benchctl.evaluate import analyze_recording
from benchctl.run import RunOptions, run_test

# T_p 18 s, two whole periods; roll on k ≡ 1, pitch on k ≡ 3 (mod 4) of 1/18 Hz, 0.06–1 Hz
PROFILE = """
name: e2e_odd_two_axis
description: odd random-phase multisine on two axes, disjoint lines (tests)
reference: exp-cos roll model (as ci_short), shortened
kind: roll_spectrum
duration_s: 40
fade_in_s: 2
fade_out_s: 2
repeat_period_s: 18
seed: 9
band_hz: [0.06, 1.0]
multisine: {odd: true, interleave_axes: true}
axes:
  roll: {model: exp_cos, sigma_deg: 2.0, period_s: 4.0, damping: 0.3}
  pitch: {model: exp_cos, sigma_deg: 2.0, period_s: 3.0, damping: 0.3}
"""


def _run(tmp_path: Path, model: SimInstrumentConfig, clock: VirtualClock) -> dict[str, Any]:
    profile = tmp_path / "odd.yaml"
    profile.write_text(PROFILE)
    # buffered: a streaming stand on a busy host holds and rejoins, so its motion is no longer
    # the periodic multisine, and the lines' noise floor — distortion, cross-axis intervals —
    # would measure the host's load instead of the instrument
    with live_bench(tmp_path, model=model, stand={"mode": "buffered"}, clock=clock) as b:
        res = run_test(b.cfg, profile, RunOptions("NL-1", "ci"), clock=clock)
        assert res.state == "done", res.reason
    assert res.recording is not None
    report = {a: v.analysis for a, v in res.report.axes.items()}  # type: ignore[union-attr]
    again = analyze_recording(res.recording, "roll").to_dict()  # benchctl analyze's path
    for d in (again, report["roll"], report["pitch"]):
        assert d["distortion"] is not None and d["cross_axis"] is not None, d["warnings"]
    assert again["distortion"]["detected"] == report["roll"]["distortion"]["detected"]
    assert again["cross_axis"]["coefficient"] == pytest.approx(
        report["roll"]["cross_axis"]["coefficient"], rel=1e-6)
    return report


@pytest.mark.slow
def test_cubic_instrument_shows_odd_distortion(tmp_path: Path, vclock: VirtualClock) -> None:
    model = SimInstrumentConfig(lag_s=0.05, noise_deg=0.01, rate_hz=100.0,
                                cubic_per_deg2=0.005)
    rep = _run(tmp_path, model, vclock)
    for axis in ("roll", "pitch"):
        d = rep[axis]["distortion"]
        assert d is not None and d["n_periods"] == 2
        assert d["detected"] and d["odd"]["detected"], (axis, d["odd"])
        assert d["odd_deg"] > 2 * d["noise_deg"]


@pytest.mark.slow
def test_cross_axis_coupling_found_and_linear_instrument_clean(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    model = SimInstrumentConfig(lag_s=0.05, noise_deg=0.01, rate_hz=100.0,
                                cross_axis=CrossAxisConfig(roll_from_pitch=0.02))
    rep = _run(tmp_path, model, vclock)
    roll, pitch = rep["roll"]["cross_axis"], rep["pitch"]["cross_axis"]
    assert roll["input_axis"] == "pitch" and pitch["input_axis"] == "roll"
    assert roll["coefficient"] == pytest.approx(0.02, rel=0.05), roll
    assert abs(pitch["coefficient"]) < 0.001, pitch  # no coupling into pitch: ≈ 0
    lo, hi = pitch["coefficient_ci95"]
    assert hi - lo < 0.004
    # a linear instrument: the unexcited lines hold noise only. The F test flags up to
    # α = 1 % of a linear instrument's records by design (two axes: up to 2 % of these runs),
    # so the check is on the levels, from the other side of the cubic test's: within twice
    # the noise beside them, where a cubic of this size puts them above it
    for axis in ("roll", "pitch"):
        d = rep[axis]["distortion"]
        assert d is not None and d["n_periods"] == 2
        assert d["odd_deg"] < 2 * d["noise_deg"] and d["even_deg"] < 2 * d["noise_deg"], (
            axis, d["odd_deg"], d["even_deg"], d["noise_deg"], d["detected"])
