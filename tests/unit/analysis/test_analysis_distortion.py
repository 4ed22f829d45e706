"""Nonlinear distortion from one odd random-phase multisine, and the cross-axis response of a
two-axis run: pure synthetic records against closed forms and stated rates."""

from __future__ import annotations

import itertools
import math
from collections import Counter

import numpy as np
import pytest

from benchctl.analysis import analyze
from benchctl.analysis.crossaxis import cross_axis_response
from benchctl.analysis.lines import LineSet, line_set_from_tables
from benchctl.analysis.linewise import analyze_lines
from benchctl.profiles import parse_profile, synthesize
from benchctl.profiles.synthesis import select_lines

FS, TP, P = 10.0, 20.0, 3  # 10 Hz, T_p 20 s, three whole periods
N = int(FS * TP * P)
T = np.arange(N) / FS
SEL = select_lines(np.arange(2, 31), odd=True, detection_group=4, seed=3)  # 0.1 … 1.5 Hz
K = SEL.kept
AMP = np.full(K.size, 2.0 / math.sqrt(K.size / 2.0))  # 2° rms
MASK = np.ones(N, dtype=bool)
LINES = LineSet(TP, K, "profile", odd=True)


def _multisine(phase: np.ndarray, k: np.ndarray = K, amp: np.ndarray = AMP) -> np.ndarray:
    return np.asarray((amp[:, None] * np.cos(2 * np.pi * k[:, None] / TP * T[None, :]
                                               + phase[:, None])).sum(axis=0))


PHASE = np.random.default_rng(5).uniform(0, 2 * np.pi, K.size)
X = _multisine(PHASE)


def _distortion(y: np.ndarray, x: np.ndarray = X):  # type: ignore[no-untyped-def]
    d = analyze_lines(x, y, MASK, 1 / FS, LINES).distortion
    assert d is not None
    return d


def _cubic_lines(c: float, harmonics: np.ndarray) -> np.ndarray:
    """Closed form: c·x³ at harmonic k is ``c Σ a_i a_j a_l`` over the ordered triples of the
    two-sided lines (``a_{±k} = A_k e^{±jφ_k}/2``) with ``i + j + l = k``; a line's variance
    is ``2|X_k|²``."""
    two = {int(k): a / 2 * np.exp(1j * p) for k, a, p in zip(K, AMP, PHASE, strict=True)}
    two |= {-k: np.conj(v) for k, v in list(two.items())}
    out = []
    for h in harmonics:
        s = sum(two[i] * two[j] * two[int(h) - i - j]
                for i, j in itertools.product(two, two) if int(h) - i - j in two)
        out.append(2 * abs(c * s) ** 2)
    return np.asarray(out)


def test_selection_keeps_odd_lines_and_leaves_one_of_every_group_out() -> None:
    odd = np.arange(3, 31, 2)
    assert set(K) | set(SEL.detection) == set(odd) and not set(K) & set(SEL.detection)
    assert SEL.detection.size == odd.size // 4  # one of every whole group of 4
    for g in range(odd.size // 4):
        assert np.isin(odd[4 * g:4 * g + 4], SEL.detection).sum() == 1
    again = select_lines(np.arange(2, 31), odd=True, detection_group=4, seed=3)
    np.testing.assert_array_equal(again.detection, SEL.detection)  # seeded: reproducible
    roll = select_lines(np.arange(1, 40), odd=True, interleave_axes=True, stream=0).kept
    pitch = select_lines(np.arange(1, 40), odd=True, interleave_axes=True, stream=1).kept
    assert set(roll % 4) == {1} and set(pitch % 4) == {3}


def test_odd_profile_keeps_the_band_variance_and_tells_the_analysis() -> None:
    spec = {
        "name": "odd", "kind": "roll_spectrum", "seed": 4, "duration_s": 64, "fade_in_s": 2,
        "fade_out_s": 2, "band_hz": [0.1, 1.0], "repeat_period_s": 20,
        "multisine": {"odd": True, "detection_group": 3},
        "axes": {"roll": {"model": "exp_cos", "sigma_deg": 2.0, "period_s": 5.0,
                          "damping": 0.2}},
    }
    odd = synthesize(parse_profile(spec))
    full = synthesize(parse_profile({k: v for k, v in spec.items() if k != "multisine"}))
    tab = odd.tables["roll"]
    k = np.rint(tab.freq_hz * tab.period_s).astype(int)
    assert np.all(k % 2 == 1) and tab.n_lines < full.tables["roll"].n_lines / 2
    # the band's variance is kept: each kept line stands for its wider cell (Σ A²/2 is the
    # band's integral exactly; the integral itself, a trapezoid of 32 steps a cell, to 1e-3)
    target = odd.targets["roll"]
    assert target is not None
    assert tab.variance_deg2 == pytest.approx(target.variance_deg2, rel=1e-12)
    assert tab.variance_deg2 == pytest.approx(full.tables["roll"].variance_deg2, rel=1e-3)
    assert tab.meta["multisine"]["detection_harmonics"]
    ls, why = line_set_from_tables(tab, 60.0)
    assert why is None and ls is not None and ls.odd
    np.testing.assert_array_equal(ls.harmonics, k)


def test_cubic_distortion_at_the_predicted_level_at_every_unexcited_line() -> None:
    c = 0.01
    d = _distortion(X + c * X**3)  # noise-free: the levels are the cubic's own
    assert d.detected and d.odd.detected and not d.even.detected
    harm = d.odd.level.harmonics
    assert set(SEL.detection) <= set(harm) and np.all(harm % 2 == 1)
    np.testing.assert_allclose(d.odd.level.power, _cubic_lines(c, harm), rtol=1e-8, atol=1e-18)
    assert float(d.even.level.power.max()) < 1e-20  # a cubic has no even-order part


@pytest.mark.parametrize("c", [1e-3, 1e-2])
def test_distortion_detected_in_noise_and_its_level_scales_as_c(c: float) -> None:
    rng = np.random.default_rng(11)
    noise = rng.normal(0, 0.01, N)
    d = _distortion(X + c * X**3 + noise)
    assert d.detected and d.odd.detected
    excess = d.odd.level.excess_deg2
    expect = float(_cubic_lines(c, d.odd.level.harmonics).sum())
    # the distortion variance at those lines less the noise's: within the noise's spread
    assert excess == pytest.approx(expect, rel=0.1 if c == 1e-3 else 0.01)


def test_false_alarm_rate_of_a_linear_system_in_noise() -> None:
    """400 records of a linear instrument (gain, a lag by FFT, white noise): the stated rule
    (α = 1 % per record) flags about 1 %; the groups' p-values are uniform (5 % below 0.05)."""
    f = np.fft.rfftfreq(N, 1 / FS)
    y_lin = np.fft.irfft(np.fft.rfft(0.98 * X) / (1 + 2j * np.pi * f * 0.05), N)
    flagged, p_values = 0, []
    for seed in range(400):
        y = y_lin + np.random.default_rng(100 + seed).normal(0, 0.01, N)
        d = _distortion(y)
        flagged += d.detected
        p_values += [d.odd.p_value, d.even.p_value]
    assert flagged / 400 <= 0.03  # binomial(400, 0.01): 0.03 is 4 standard deviations out
    share = float(np.mean(np.asarray(p_values) < 0.05))
    assert 0.03 <= share <= 0.07, share


def test_saturation_found() -> None:
    rng = np.random.default_rng(3)
    peak = float(np.abs(X).max())
    d = _distortion(np.clip(X, -0.7 * peak, 0.7 * peak) + rng.normal(0, 0.01, N))
    assert d.detected and d.odd.detected and d.odd.level.level_deg > 10 * d.odd.level.noise_deg


def test_even_distortion_of_a_square_term() -> None:
    rng = np.random.default_rng(4)
    d = _distortion(X + 0.01 * X**2 + rng.normal(0, 0.01, N))
    assert d.even.detected and not d.odd.detected


def test_analyze_reports_distortion_in_json_only_for_an_odd_multisine() -> None:
    y = X + 0.005 * X**3 + np.random.default_rng(8).normal(0, 0.01, N)
    out = analyze(T, X, T, y, lines=LINES).to_dict()
    dist = out["distortion"]
    assert dist["detected"] and dist["odd_deg"] > dist["noise_deg"] > 0
    assert dist["odd"]["detected"] and dist["odd"]["p_value"] < 1e-6
    plain = analyze(T, X, T, y, lines=LineSet(TP, K, "profile")).to_dict()
    assert plain["distortion"] is None  # not declared odd: no distortion report


# ------------------------------------------------------------------------------ cross-axis
def _two_axis(k_cross: float, seed: int) -> tuple[np.ndarray, ...]:
    band = np.arange(6, 31)
    kr = select_lines(band, odd=True, interleave_axes=True, stream=0).kept
    kp = select_lines(band, odd=True, interleave_axes=True, stream=1).kept
    rng = np.random.default_rng(seed)
    xr = _multisine(rng.uniform(0, 2 * np.pi, kr.size), kr, np.full(kr.size, 1.0))
    xp = _multisine(rng.uniform(0, 2 * np.pi, kp.size), kp, np.full(kp.size, 1.0))
    f = np.fft.rfftfreq(N, 1 / FS)
    y = np.fft.irfft(np.fft.rfft(0.995 * (xr + k_cross * xp)) / (1 + 2j * np.pi * f * 0.08), N)
    y = y + rng.normal(0, 0.02, N)
    return xr, xp, y, kr, kp


@pytest.mark.parametrize("k_cross", [0.02, -0.05])
def test_cross_axis_coupling_found_with_its_interval(k_cross: float) -> None:
    xr, xp, y, kr, kp = _two_axis(k_cross, 1)
    d, why = cross_axis_response(T, y, (T, xr), (T, xp), LineSet(TP, kr, "profile"),
                                 LineSet(TP, kp, "profile"), axis="roll", other_axis="pitch")
    assert why is None and d is not None
    assert d["coefficient"] == pytest.approx(k_cross, rel=0.05)
    lo, hi = d["coefficient_ci95"]
    assert lo <= k_cross <= hi and hi - lo < 0.1 * abs(k_cross)


def test_cross_axis_interval_coverage_without_coupling() -> None:
    """Zero coupling: the 95 % interval holds 0 in about 95 % of 200 records."""
    covered = Counter()
    for seed in range(200):
        xr, xp, y, kr, kp = _two_axis(0.0, 50 + seed)
        d, _ = cross_axis_response(T, y, (T, xr), (T, xp), LineSet(TP, kr, "profile"),
                                   LineSet(TP, kp, "profile"), axis="roll", other_axis="pitch")
        assert d is not None
        lo, hi = d["coefficient_ci95"]
        covered[lo <= 0.0 <= hi] += 1
    assert 0.91 <= covered[True] / 200 <= 0.99, covered


def test_cross_axis_refused_when_the_axes_share_lines() -> None:
    d, why = cross_axis_response(T, X, (T, X), (T, X), LINES, LINES, axis="roll",
                                 other_axis="pitch")
    assert d is None and why is not None and "share lines" in why
