"""Excitation fidelity (benchctl.analysis.excitation) on synthetic stand motions.

The stand's motion is made as the target lines times a known complex response H(f) (the
simulated servo's own discrete model, or a constant gain), sampled at jittered instants with
gaps, plus white noise: the achieved dB per line must be 20·log10|H(f_k)| (exactly without
noise; within its stated interval with noise), the band dB 10·log10(Σ|H|²A²/ΣA²), and the
judgement must follow the alarm/abort levels, leaving weak, unreachable and uncertain lines
and bands unjudged.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from repo_paths import ROOT

from benchctl.analysis.excitation import excitation_fidelity, format_fidelity
from benchctl.analysis.fidelitylimits import FidelityLimits, StandReach, third_octave_bands
from benchctl.analysis.runningfidelity import ABORT_CONFIRM, RunningFidelity
from benchctl.config import load_config
from benchctl.errors import ConfigError, DataError
from benchctl.harmonics import HarmonicTable
from benchctl.sim.servo import ServoModel

T0 = 1000.0  # the motion's start on the stand's clock
FADE = 3.0
RESONANT = ServoModel(0.8, 0.3, 60.0, 300.0, 1e-3)


def _lines(k: np.ndarray, period: float, seed: int = 1) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    return k / period, rng.uniform(0.3, 1.0, k.size), rng.uniform(0, 2 * np.pi, k.size)


def _motion(
    freq: np.ndarray, amp: np.ndarray, phase: np.ndarray, h: np.ndarray, span: float,
    noise: float = 0.0, seed: int = 2, gap: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """The stand's angle: Re Σ H_k A_k e^{j(2πf_k(t−T0)+φ_k)} + 0.2° offset + noise, at ~100 Hz
    jittered instants from before the window to after it, one 1 s gap inside."""
    rng = np.random.default_rng(seed)
    t = T0 + FADE - 1.0 + np.cumsum(rng.uniform(0.007, 0.013, int((span + 2) * 100)))
    if gap:
        t = t[~((t > T0 + FADE + 4.0) & (t < T0 + FADE + 5.0))]
    c = h * amp * np.exp(1j * phase)
    x = np.zeros(t.size)
    for ck, fk in zip(c, freq, strict=True):
        x += np.real(ck * np.exp(2j * np.pi * fk * (t - T0)))
    return t, x + 0.2 + noise * rng.standard_normal(t.size)


def _window(span: float) -> tuple[float, float]:
    return T0 + FADE, T0 + FADE + span


def test_noise_free_resonant_stand_exact() -> None:
    period = 19.0
    freq, amp, phase = _lines(np.arange(2, 10), period)
    h = RESONANT.response(freq)
    t, x = _motion(freq, amp, phase, h, period)
    fid = excitation_fidelity(t, x, freq, amp, phase, period, _window(period), T0)
    expect = 20 * np.log10(np.abs(h))
    assert fid.n_periods == 1 and fid.noise_method == "unexcited"
    assert np.max(np.abs(fid.error_db - expect)) < 1e-6
    assert np.max(np.abs(fid.phase_deg - np.degrees(np.angle(h)))) < 1e-4
    assert np.max(np.abs(fid.amp_sd)) < 1e-6  # nothing but rounding is left
    # bands: exact power ratios over the lines in each band
    for b in fid.bands:
        inb = (freq >= b["lo_hz"]) & (freq < b["hi_hz"])
        ref = 10 * math.log10(np.sum(np.abs(h[inb]) ** 2 * amp[inb] ** 2) / np.sum(amp[inb] ** 2))
        assert b["error_db"] == pytest.approx(ref, abs=1e-6)
        assert b["n_lines"] == int(inb.sum())
    assert sum(b["n_lines"] for b in fid.bands) == freq.size
    ratio = np.sum(np.abs(h) ** 2 * amp**2) / np.sum(amp**2)
    assert fid.variance_ratio == pytest.approx(ratio, rel=1e-9)
    assert fid.variance_measured == pytest.approx(fid.variance_lines, rel=1e-3)
    w = amp**2
    rms = math.sqrt(np.sum(w * expect**2) / np.sum(w))
    assert fid.rms_error_db == pytest.approx(rms, rel=1e-6)
    # the resonance lifts the upper lines beyond 1.5 dB: the upper bands alarm, none aborts
    assert fid.judgement == "alarm"
    judged = {round(b["centre_hz"], 3): b["judgement"] for b in fid.bands}
    assert judged[0.398] == "alarm" and judged[0.501] == "alarm" and judged[0.1] == "ok"
    assert fid.worst_band is not None and fid.worst_band["centre_hz"] == pytest.approx(0.5012, 1e-3)
    d = fid.to_dict()
    assert d["judgement"] == "alarm" and len(d["lines"]) == 8
    assert d["lines"][0]["status"] == "judged"
    assert "ALARM" in format_fidelity(d)


def test_noisy_within_interval_and_tolerance() -> None:
    """Two periods of 40 lines with 0.02° of noise: each line's dB within 0.1 dB of the
    servo's and inside its 95 % interval for nearly all lines (coverage)."""
    period = 20.0
    freq, amp, phase = _lines(np.arange(2, 42), period, seed=4)
    h = RESONANT.response(freq)
    inside, total = 0, 0
    for seed in range(5):
        t, x = _motion(freq, amp, phase, h, 2 * period, noise=0.02, seed=10 + seed)
        fid = excitation_fidelity(t, x, freq, amp, phase, period, _window(2 * period), T0)
        assert fid.n_periods == 2
        expect = 20 * np.log10(np.abs(h))
        assert np.max(np.abs(fid.error_db - expect)) < 0.1
        lo, hi = fid.error_ci95_db[:, 0], fid.error_ci95_db[:, 1]
        inside += int(np.sum((lo <= expect) & (expect <= hi)))
        total += freq.size
        # the stated sd is the scatter's: the white noise's 2σ²/N_v per component
        assert np.median(fid.amp_sd) == pytest.approx(0.02 * math.sqrt(2 / x.size * 1.0),
                                                      rel=0.35)
    assert inside / total >= 0.88, inside / total


def test_dense_lines_use_the_local_polynomial_noise() -> None:
    """Every bin near the lines excited (one period, lines 1…120 of 60 s, the 8 Hz servo):
    the noise from the local polynomial method on the achieved against the target
    amplitudes; the errors within 0.05 dB and mostly inside their intervals."""
    period = 60.0
    freq, amp, phase = _lines(np.arange(1, 121), period, seed=5)
    amp = amp * 0.1
    h = ServoModel(8.0, 0.8, 60.0, 300.0, 1e-3).response(freq)
    t, x = _motion(freq, amp, phase, h, period, noise=0.002, gap=False)
    fid = excitation_fidelity(t, x, freq, amp, phase, period, _window(period), T0)
    assert fid.noise_method in ("lpm", "mixed")
    expect = 20 * np.log10(np.abs(h))
    assert np.max(np.abs(fid.error_db - expect)) < 0.05
    lo, hi = fid.error_ci95_db[:, 0], fid.error_ci95_db[:, 1]
    assert np.mean((lo <= expect) & (expect <= hi)) >= 0.85
    assert fid.judgement == "ok"


@pytest.mark.parametrize(
    ("gain", "verdict"),
    [(1.1, "ok"), (0.9, "ok"), (1.25, "alarm"), (0.8, "alarm"), (1.5, "abort"), (0.6, "abort")],
)
def test_judgement_levels(gain: float, verdict: str) -> None:
    period = 19.0
    freq, amp, phase = _lines(np.arange(2, 10), period)
    h = np.full(freq.size, gain, dtype=complex)
    t, x = _motion(freq, amp, phase, h, period, noise=0.001)
    fid = excitation_fidelity(t, x, freq, amp, phase, period, _window(period), T0)
    assert fid.judgement == verdict
    assert all(b["judgement"] == verdict for b in fid.bands)
    assert fid.rms_error_db == pytest.approx(abs(20 * math.log10(gain)), abs=0.01)


def _one_odd_line(change: Callable[[np.ndarray, np.ndarray], None]) -> tuple[Any, np.ndarray]:
    """Lines 2…9 of 19 s followed exactly (H = 1) but the last (0.47 Hz, alone in its band)
    played at 3× (+9.5 dB); ``change`` edits the amplitudes and H first."""
    period = 19.0
    freq, amp, phase = _lines(np.arange(2, 10), period)
    h = np.ones(freq.size, dtype=complex)
    h[-1] = 3.0
    change(amp, h)
    t, x = _motion(freq, amp, phase, h, period, noise=1e-5)
    return (t, x, freq, amp, phase, period), h


def test_weak_line_is_reported_not_judged() -> None:
    def weak(amp: np.ndarray, h: np.ndarray) -> None:
        amp[-1] = amp.max() * 10 ** (-40 / 20)  # −40 dB: below the −30 dB of the strongest

    (t, x, freq, amp, phase, period), _h = _one_odd_line(weak)
    fid = excitation_fidelity(t, x, freq, amp, phase, period, _window(period), T0)
    assert fid.line_status[-1] == "weak" and fid.line_status[:-1] == ["judged"] * 7
    assert fid.error_db[-1] == pytest.approx(20 * math.log10(3.0), abs=0.05)  # still reported
    last = fid.bands[-1]
    assert last["judgement"] == "weak" and last["error_db"] == pytest.approx(9.54, abs=0.05)
    assert fid.judgement == "ok"
    # the same line at full strength is judged: abort
    (t, x, freq, amp, phase, period), _h = _one_odd_line(lambda a, h: None)
    fid = excitation_fidelity(t, x, freq, amp, phase, period, _window(period), T0)
    assert fid.line_status[-1] == "judged" and fid.judgement == "abort"


def test_unreachable_line_is_reported_and_left_out() -> None:
    def strong(amp: np.ndarray, h: np.ndarray) -> None:
        amp[-1] = amp.max()  # the highest line, as strong as any: the most acceleration

    (t, x, freq, amp, phase, period), _h = _one_odd_line(strong)
    w = 2 * np.pi * freq
    # an acceleration limit the last line alone exceeds, every other line within it
    accel = float(np.max(amp[:-1] * w[:-1] ** 2)) * 1.01
    assert amp[-1] * w[-1] ** 2 > accel
    fid = excitation_fidelity(t, x, freq, amp, phase, period, _window(period), T0,
                              reach=StandReach(30.0, 30.0, accel))
    assert fid.line_status[-1] == "unreachable"
    assert fid.bands[-1]["judgement"] == "unreachable" and fid.bands[-1]["n_unreachable"] == 1
    assert fid.judgement == "ok"
    assert fid.to_dict()["lines"][-1]["status"] == "unreachable"


def test_uncertain_band_is_not_judged() -> None:
    """Motion buried in noise: the bands' intervals are wider than 0.5 dB, nothing is judged
    however far the estimate lies; with a looser max_ci_db they are."""
    period = 19.0
    freq, amp, phase = _lines(np.arange(2, 10), period)
    h = np.full(freq.size, 1.5, dtype=complex)
    t, x = _motion(freq, amp * 0.05, phase, h, period, noise=0.3)
    fid = excitation_fidelity(t, x, freq, amp * 0.05, phase, period, _window(period), T0)
    assert {b["judgement"] for b in fid.bands} == {"uncertain"}
    assert fid.judgement == "not judged" and fid.worst_band is None
    loose = excitation_fidelity(t, x, freq, amp * 0.05, phase, period, _window(period), T0,
                                limits=FidelityLimits(max_ci_db=40.0))
    assert loose.judgement in ("ok", "alarm", "abort")


def test_custom_band_edges() -> None:
    period = 19.0
    freq, amp, phase = _lines(np.arange(2, 10), period)
    h = RESONANT.response(freq)
    t, x = _motion(freq, amp, phase, h, period)
    fid = excitation_fidelity(t, x, freq, amp, phase, period, _window(period), T0,
                              limits=FidelityLimits(band_edges_hz=(0.05, 0.3, 0.6)))
    assert [b["n_lines"] for b in fid.bands] == [4, 4]
    hi = freq >= 0.3
    ref = 10 * math.log10(np.sum(np.abs(h[hi]) ** 2 * amp[hi] ** 2) / np.sum(amp[hi] ** 2))
    assert fid.bands[1]["error_db"] == pytest.approx(ref, abs=1e-6)


def test_third_octave_bands_are_base_ten() -> None:
    bands = third_octave_bands(0.08, 0.5)
    centres = [c for _lo, c, _hi in bands]
    assert centres[0] == pytest.approx(10 ** -1.1) and centres[-1] == pytest.approx(10 ** -0.3)
    assert len(bands) == 9
    for (_a, _c, b), (a2, _c2, _b2) in itertools.pairwise(bands):
        assert b == pytest.approx(a2)  # contiguous
    for lo, c, hi in bands:
        assert hi / lo == pytest.approx(10**0.1) and c == pytest.approx(math.sqrt(lo * hi))


def test_less_than_a_period_or_no_line_refused() -> None:
    period = 19.0
    freq, amp, phase = _lines(np.arange(2, 10), period)
    t, x = _motion(freq, amp, phase, np.ones(freq.size), period)
    with pytest.raises(DataError, match="holds no whole period of 19 s"):
        excitation_fidelity(t, x, freq, amp, phase, period, (T0 + FADE, T0 + FADE + 15.0), T0)
    with pytest.raises(DataError, match="no line"):
        excitation_fidelity(t, x, freq, amp * 0, phase, period, _window(period), T0)
    with pytest.raises(DataError, match="not whole harmonics"):
        excitation_fidelity(t, x, freq * 1.013, amp, phase, period, _window(period), T0)


def _config(tmp_path: Path, excitation: dict[str, Any]) -> Path:
    data = yaml.safe_load((ROOT / "config/sim_resonant.yaml").read_text())
    data["stand"]["register_map"] = str(ROOT / "drivers/stand_generic.yaml")
    data["instrument"]["eds"] = str(ROOT / "drivers/cia410_inclinometer.eds")
    data["run"]["excitation"] = excitation
    f = tmp_path / "bench.yaml"
    f.write_text(yaml.safe_dump(data))
    return f


def test_config_section(tmp_path: Path) -> None:
    cfg = load_config(ROOT / "config/sim_resonant.yaml")
    assert cfg.run.excitation.alarm_db == 1.5 and cfg.run.excitation.abort_db == 3.0
    assert cfg.sim is not None and cfg.sim.stand.bandwidth_hz == 0.8
    assert load_config(ROOT / "config/sim.yaml").run.excitation.max_ci_db == 0.5  # default
    ok = load_config(_config(tmp_path, {"alarm_db": 1.0, "abort_db": 2.0,
                                        "band_edges_hz": [0.1, 0.2, 0.4]}))
    assert ok.run.excitation.band_edges_hz == (0.1, 0.2, 0.4)
    with pytest.raises(ConfigError, match=r"run\.excitation.*abort_db = 1: expected ≥ alarm_db"):
        load_config(_config(tmp_path, {"alarm_db": 2.0, "abort_db": 1.0}))
    with pytest.raises(ConfigError, match=r"run\.excitation\.band_edges_hz.*strictly ascending"):
        load_config(_config(tmp_path, {"band_edges_hz": [0.2, 0.1]}))
    with pytest.raises(ConfigError, match=r"run\.excitation\.alarm_db"):
        load_config(_config(tmp_path, {"alarm_db": -1}))
    with pytest.raises(ConfigError, match=r"run\.excitation\.alarm_dB"):
        load_config(_config(tmp_path, {"alarm_dB": 1}))


# ------------------------------------------------------------------- the running estimate
def _feed(rf: RunningFidelity, t: np.ndarray, x: np.ndarray, every: int = 100) -> list[float]:
    """Feed the samples in blocks of ``every``, updating after each; the instants at which an
    abort was reported."""
    aborts = []
    for j in range(0, t.size, every):
        for tj, xj in zip(t[j:j + every], x[j:j + every], strict=True):
            rf.add(float(tj), float(xj))
        rf.update()
        if rf.abort_reason():
            aborts.append(float(t[min(j + every, t.size) - 1]))
    return aborts


def test_running_estimate_confirms_an_abort_level_only_when_meaningful() -> None:
    period = 19.0
    freq, amp, phase = _lines(np.arange(2, 10), period)
    table = HarmonicTable(freq, amp, phase, duration_s=25.0, period_s=period)
    gain = 1.6  # +4.08 dB on every line
    t, x = _motion(freq, amp, phase, np.full(freq.size, gain, dtype=complex), 2 * period,
                   noise=0.001)
    rf = RunningFidelity(table, _window(2 * period), T0, axis="roll")
    assert len(rf.bands) == 7  # every third-octave band with a line (none weak here)
    assert rf.resolve_s == pytest.approx(period)  # the lines 1/19 Hz apart
    aborts = _feed(rf, t, x)
    assert aborts, "a +4.1 dB stand never reached the abort level"
    # not before one whole period of the lines (before it neighbouring bands' lines are not
    # told apart) and ABORT_CONFIRM updates
    assert aborts[0] >= T0 + FADE + period + (ABORT_CONFIRM - 1) * 1.0 - 0.05
    why = rf.abort_reason()
    assert why is not None and why.startswith("excitation roll: the stand's motion in the band")
    assert "beyond the abort level ±3 dB" in why
    for b in rf.estimate:
        assert b["error_db"] == pytest.approx(20 * math.log10(gain), abs=0.02)
    assert rf.estimate[-1]["judged"]
    # before one whole period nothing is judged, however sure each band's own interval looks
    early = RunningFidelity(table, _window(2 * period), T0, axis="roll")
    k = t < T0 + FADE + 0.9 * period
    _feed(early, t[k], x[k])
    assert early.estimate and not any(b["judged"] for b in early.estimate)
    # +2.3 dB: within the abort level, never an abort
    t, x = _motion(freq, amp, phase, np.full(freq.size, 1.3, dtype=complex), 2 * period,
                   noise=0.001)
    rf = RunningFidelity(table, _window(2 * period), T0, axis="roll")
    assert _feed(rf, t, x) == []
    assert rf.estimate[-1]["error_db"] == pytest.approx(20 * math.log10(1.3), abs=0.02)


def test_running_estimate_is_the_power_weighted_response_and_skips_the_unjudged() -> None:
    """Over whole periods of uniform samples a band's gain is Σ A²H / Σ A² over its lines;
    samples outside the window or NaN do not count; weak bands and unreachable lines are left
    out."""
    period = 19.0
    freq, amp, phase = _lines(np.arange(2, 10), period)
    amp[-1] = amp.max() * 10 ** (-40 / 20)  # the 0.47 Hz line alone in its band: weak
    table = HarmonicTable(freq, amp, phase, duration_s=25.0, period_s=period)
    h = RESONANT.response(freq)
    lo, hi = _window(period)
    t = lo + (np.arange(1900) + 0.5) * 0.01  # one period, uniform
    c = h * amp * np.exp(1j * phase)
    x = np.real(np.exp(2j * np.pi * np.outer(t - T0, freq)) @ c) + 0.2
    w = 2 * np.pi * freq
    reach = StandReach(30.0, 30.0, float(amp[-2] * w[-2] ** 2) * 0.99)  # 0.42 Hz unreachable
    rf = RunningFidelity(table, (lo, hi), T0, reach=reach)
    assert [round(cb, 3) for _lo, cb, _hi in rf.bands] == [0.1, 0.158, 0.2, 0.251, 0.316, 0.398]
    _feed(rf, t, x)
    for (blo, _c, bhi), b in zip(rf.bands, rf.estimate, strict=True):
        inb = (freq >= blo) & (freq < bhi) & (np.arange(freq.size) < freq.size - 2)
        g = np.sum(amp[inb] ** 2 * h[inb]) / np.sum(amp[inb] ** 2)
        assert b["error_db"] == pytest.approx(20 * math.log10(abs(g)), abs=1e-9)
        assert b["span_s"] == pytest.approx(period, abs=0.011)
    # junk outside the window and NaN readings change nothing
    junk = RunningFidelity(table, (lo, hi), T0, reach=reach)
    tj = np.concatenate(([lo - 1.0, lo - 0.5], t, [hi + 0.5]))
    xj = np.concatenate(([50.0, 50.0], x, [50.0]))
    tj = np.insert(tj, 500, t[497] + 0.001)
    xj = np.insert(xj, 500, np.nan)
    _feed(junk, tj, xj)
    for a, b in zip(rf.estimate, junk.estimate, strict=True):
        assert a["error_db"] == pytest.approx(b["error_db"], abs=1e-12)
