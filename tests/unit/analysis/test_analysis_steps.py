"""The linearity table from sine steps (benchctl.analysis.steps): exact on noise-free steps
through a known lag, gain and latency; 95 % intervals that cover; the verdict; the CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import cont2discrete, lfilter

from benchctl.analysis.steps import (
    StepWindow,
    analyze_steps,
    estimate_step,
    noise_harmonics,
    step_windows,
)
from benchctl.profiles import parse_profile, synthesize

SPEC = {
    "name": "steps_test",
    "kind": "sine_steps",
    "seed": 0,
    "axes": ["roll"],
    "periods_s": [3, 7],
    "amplitudes_deg": [2, 5],
    "cycles": 3,
    "fade_cycles": 1,
    "rest_s": 1,
}
GAIN, LAG, LATENCY = 0.993, 0.08, 0.012


def _exact(f: float) -> complex:
    w = 2 * math.pi * f
    return complex(GAIN * np.exp(-1j * w * LATENCY) / (1 + 1j * w * LAG))


def _through_instrument(motion: object, t_out: np.ndarray, t0: float) -> np.ndarray:
    """GAIN · lag(x)(t − LATENCY): the lag integrated exactly for an input linear between
    1 ms steps (first-order hold), then read at the output instants (linear between 1 ms)."""
    h = 1e-3
    tf = np.arange(0.0, motion.duration_s + 1.0, h)  # type: ignore[attr-defined]
    xf = motion.evaluate(tf)["roll"]  # type: ignore[attr-defined]
    num, den, _ = cont2discrete(([1.0], [LAG, 1.0]), h, method="foh")[:3]
    yf = GAIN * lfilter(np.ravel(num), np.ravel(den), xf)
    return np.asarray(np.interp(t_out - t0 - LATENCY, tf, yf))


def test_noise_free_steps_match_the_closed_form_with_gaps_and_jitter() -> None:
    motion = synthesize(parse_profile(SPEC))
    t0 = 1000.0  # the motion's start on the analysis clock
    wins = step_windows(motion, "roll", t0)
    assert [(w.period_s, w.amplitude_deg, w.cycles) for w in wins] == [
        (3.0, 2.0, 3), (3.0, 5.0, 3), (7.0, 2.0, 3), (7.0, 5.0, 3)]
    # the first window starts after the rest and the fade: 1 s + 1 period
    assert wins[0].start_s == pytest.approx(t0 + 1.0 + 3.0)
    rng = np.random.default_rng(3)
    dur = motion.duration_s
    # reference at ~100 Hz, instrument at ~50 Hz, each with jittered instants of its own
    tr = np.arange(0.0, dur, 0.01) + rng.uniform(-2e-3, 2e-3, math.ceil(dur / 0.01))
    td = np.arange(0.0, dur, 0.02) + 0.0037 + rng.uniform(-4e-3, 4e-3, math.ceil(dur / 0.02))
    tr, td = np.sort(tr[tr > 0]), np.sort(td[td > 0])
    # gaps: 0.7 s of instrument samples lost in the 3 s × 5° step, 0.3 s of reference in the
    # 7 s × 2° step
    w1, w2 = wins[1], wins[2]
    td = td[~((td > w1.start_s - t0 + 2.0) & (td < w1.start_s - t0 + 2.7))]
    tr = tr[~((tr > w2.start_s - t0 + 5.0) & (tr < w2.start_s - t0 + 5.3))]
    x = motion.evaluate(tr)["roll"]
    y = _through_instrument(motion, td + t0, t0)
    res = analyze_steps(tr + t0, x, td + t0, y, wins, spread_limit=0.01)
    assert not res.warnings
    # the window starts where the fade ends: the lag's settling from the fade costs 1e-4
    # of the gain at 3 s (physical, not the estimator's: a window one cycle later, 4e-7)
    for s in res.steps:
        h = _exact(1.0 / s.window.period_s)
        assert s.gain == pytest.approx(abs(h), rel=5e-4), s.window
        assert s.phase_deg == pytest.approx(math.degrees(np.angle(h)), abs=0.05), s.window
        assert s.reference_amplitude_deg == pytest.approx(s.window.amplitude_deg, rel=1e-4)
        assert s.gain is not None and s.gain_ci95 is not None
        assert s.gain_ci95[0] <= s.gain <= s.gain_ci95[1]
    # gain 0.9793 at 3 s, 0.9904 at 7 s: a spread of 0.0111, over a limit of 0.01
    assert res.spread == pytest.approx(abs(_exact(1 / 7)) - abs(_exact(1 / 3)), abs=2e-4)
    assert res.verdict == "FAIL"
    assert analyze_steps(tr + t0, x, td + t0, y, wins, spread_limit=0.012).verdict == "PASS"


def test_an_amplitude_dependent_gain_fails_linearity() -> None:
    """A saturating instrument (gain falls with amplitude) spreads its gains beyond the limit."""
    w_small = StepWindow("roll", 5.0, 2.0, 0.0, 4)
    w_big = StepWindow("roll", 5.0, 10.0, 30.0, 4)
    t = np.arange(0.0, 50.0, 0.01)
    x = np.where(t < 25.0, 2.0, 10.0) * np.sin(2 * np.pi * t / 5.0)
    y = x * (1.0 - 0.002 * np.abs(np.where(t < 25.0, 2.0, 10.0)))  # 0.996 and 0.980
    res = analyze_steps(t, x, t, y, [w_small, w_big], spread_limit=0.01)
    assert [s.gain for s in res.steps] == pytest.approx([0.996, 0.980], rel=1e-9)
    assert res.spread == pytest.approx(0.016, rel=1e-6) and res.verdict == "FAIL"
    assert res.amplitude_spread == pytest.approx(0.016, rel=1e-6)


def test_too_few_samples_or_cycles_is_a_note_not_a_number() -> None:
    t = np.arange(0.0, 20.0, 0.01)
    x = np.sin(2 * np.pi * t / 5.0)
    one_cycle = StepWindow("roll", 5.0, 1.0, 0.0, 1)
    empty = StepWindow("roll", 5.0, 1.0, 100.0, 3)
    res = analyze_steps(t, x, t, x, [one_cycle, empty])
    assert all(s.gain is None for s in res.steps)
    assert "at least 2 needed" in res.steps[0].note and "0 samples" in res.steps[1].note
    assert res.verdict == "FAIL" and len(res.warnings) == 3
    d = res.to_dict()
    assert d["steps"][0]["gain"] is None and d["linearity"]["spread"] is None


def test_noise_harmonics_leave_out_the_sine_and_its_harmonics() -> None:
    assert noise_harmonics(5) == [1, 2, 3, 4, 6, 7, 8, 9]
    assert noise_harmonics(2) == [1, 3, 5, 7, 9, 11, 13, 15]


def _coverage(noise: str, records: int, seed: int) -> tuple[float, float]:
    """Share of records whose gain and phase intervals hold the true H."""
    rng = np.random.default_rng(seed)
    period, cycles, amp = 5.0, 5, 2.0
    win = StepWindow("roll", period, amp, 0.0, cycles)
    h = 0.99 * np.exp(-0.2j)
    hit_g = hit_p = 0
    for _ in range(records):
        n = 1300
        t = np.sort(rng.uniform(-0.5, 25.5, n))  # non-uniform instants
        ph = rng.uniform(0, 2 * np.pi)
        x = amp * np.cos(2 * np.pi * t / period + ph)
        y = abs(h) * amp * np.cos(2 * np.pi * t / period + ph + np.angle(h))
        if noise == "white":
            e = rng.normal(0.0, 0.1, n)
        else:  # coloured: AR(1) on the instants' order (about 50 Hz), corner ≈ 1.6 Hz
            e = lfilter([1.0], [1.0, -0.8], rng.normal(0.0, 0.06, n))
        xr = x + rng.normal(0.0, 0.005, n)
        s = estimate_step(t, xr, t, y + e + 0.01 * t, win)  # and a drift
        assert s.gain_ci95 is not None and s.phase_ci95_deg is not None
        hit_g += s.gain_ci95[0] <= abs(h) <= s.gain_ci95[1]
        hit_p += s.phase_ci95_deg[0] <= math.degrees(np.angle(h)) <= s.phase_ci95_deg[1]
    return hit_g / records, hit_p / records


@pytest.mark.parametrize("noise", ["white", "coloured"])
def test_intervals_cover_95_percent(noise: str) -> None:
    g, p = _coverage(noise, 600, 11 if noise == "white" else 12)
    assert 0.92 <= g <= 0.98 and 0.92 <= p <= 0.98, (g, p)


def test_analyze_json_of_a_step_recording_has_the_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`benchctl analyze REC --json` on a recording of a sine_steps profile gives `steps` and
    `linearity` (a recording written here with the recording writer, no bench); the limit is
    the recording's bench config's `run.linearity_spread_limit`."""
    from benchctl.cli import main
    from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
    from benchctl.recording import RecordingWriter

    motion = synthesize(parse_profile(SPEC))
    rec = tmp_path / "rec"
    meta = {"profile": {"spec": SPEC, "source": None}, "seed": 0,
            "duration_s": motion.duration_s, "scale": 1.0,
            "config": {"run": {"limit_sigma_deg": 0.4, "linearity_spread_limit": 0.004}}}
    w = RecordingWriter(rec, ("roll",), meta)
    t0 = 50.0
    w.event("motion_start", t_host=t0, mode="buffered")
    status = StandStatus(ready=True, enabled=True, moving=True, fault=False, estop=False,
                         limit=False)
    rng = np.random.default_rng(5)
    ts = np.arange(0.0, motion.duration_s, 0.01)
    x = motion.evaluate(ts)["roll"]
    for t, v in zip((ts + t0).tolist(), x.tolist(), strict=True):
        w.write_stand(StandSample(t_host=t, rtt_s=0.002, angle_deg={"roll": v},
                                  rate_deg_s={"roll": 0.0}, setpoint_deg={"roll": v},
                                  status=status))
    td = ts + t0 + 0.004
    y = _through_instrument(motion, td, t0) + rng.normal(0, 0.01, td.size)
    for i, (t, v) in enumerate(zip(td.tolist(), y.tolist(), strict=True)):
        w.write_instrument(InstrumentSample(t_host=t, angle_deg={"roll": v}, counter=i))
    w.close("done", analysis_window=[t0, t0 + motion.duration_s])
    capsys.readouterr()
    assert main(["analyze", str(rec), "--axis", "roll", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    steps = out["steps"]
    assert [(s["period_s"], s["amplitude_deg"]) for s in steps] == [
        (3.0, 2.0), (3.0, 5.0), (7.0, 2.0), (7.0, 5.0)]
    for s in steps:
        h = _exact(1.0 / s["period_s"])
        lo, hi = s["gain_ci95"]
        assert lo < s["gain"] < hi and abs(s["gain"] - abs(h)) < 3 * (hi - lo)
        assert set(s) >= {"period_s", "amplitude_deg", "gain", "gain_ci95", "phase_deg",
                          "phase_ci95_deg"}
    lin = out["linearity"]
    assert lin["limit"] == 0.004  # from the recording's bench config
    assert lin["spread"] > 0.004
    assert lin["verdict"] == "FAIL"  # 0.9793 … 0.9904: a spread of 0.0111 > 0.004
    assert main(["analyze", str(rec), "--axis", "roll"]) == 0
    text = capsys.readouterr().out
    assert "sine steps" in text and "linearity" in text and "FAIL" in text
