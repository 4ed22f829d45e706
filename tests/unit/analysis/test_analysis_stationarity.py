"""Non-stationary errors: the period-to-period test of the error's power, the drift's term of
σ's interval, and the budget's non-stationarity line.

Closed forms where there are: a stationary white error is not flagged and its drift term has
the degrees of freedom of its cosine coefficients; an error whose noise doubles halfway is
flagged. Monte Carlo (``benchmarks/sigma_coverage.py`` runs the long one): a random walk's
and a modulated gain's σ interval against σ of the process, over 200 records each (binomial
standard deviation 0.015 at p = 0.95).
"""

from __future__ import annotations

import numpy as np
import pytest
from analysis_synthetic import Multisine, gain
from scipy.fft import dct, idct
from scipy.stats import chi2
from sigma_coverage import N4, T4, nonstationary_coverage

from benchctl.analysis import analyze
from benchctl.analysis.budget import EVALUATED, NOT_ASSESSED
from benchctl.analysis.stationarity import (
    FALSE_ALARM,
    LowCosines,
    assess,
    fit_drift,
    low_part,
)
from benchctl.analysis.uncertainty import weighted_chi2_factors

MS = Multisine(period_s=100.0, f_lo=0.05, f_hi=1.0, rms_deg=5.0)


def _record(noise: np.ndarray, period: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    ms = Multisine(period_s=period, f_lo=0.05, f_hi=1.0, rms_deg=5.0)
    x = ms.reference(T4)
    return x, ms.through(gain(0.99), T4) + noise


def test_white_error_is_stationary_and_its_budget_line_is_zero() -> None:
    x, y = _record(np.random.default_rng(1).normal(0.0, 0.1, N4))
    r = analyze(T4, x, T4, y)
    st = r.uncertainty["stationarity"]
    assert st["stationary"] and st["segments"] == 9 and st["p_value"] >= FALSE_ALARM
    assert st["added_variance"] == 0.0
    line = next(c for c in r.budget.contributions if c.key == "nonstationarity")
    assert line.status == EVALUATED and line.u_deg == 0.0 and "stationary" in line.basis


def test_noise_that_doubles_halfway_is_flagged_and_widens_the_interval() -> None:
    rng = np.random.default_rng(2)
    noise = rng.normal(0.0, 0.1, N4) * np.where(T4 < 450.0, 1.0, 2.0)
    x, y = _record(noise)
    r = analyze(T4, x, T4, y)
    st = r.uncertainty["stationarity"]
    assert not st["stationary"] and st["p_value"] < 1e-6
    ms = np.asarray(st["segment_mean_squares"])
    assert ms[-1] / ms[0] == pytest.approx(4.0, rel=0.35)  # the power, period by period
    assert st["added_variance"] > 0.0
    assert any("not stationary" in w for w in r.warnings)
    line = next(c for c in r.budget.contributions if c.key == "nonstationarity")
    assert line.status == EVALUATED and line.u_deg > 0.0 and "NOT stationary" in line.basis


def test_one_period_record_is_assessed_on_its_noise() -> None:
    """One period: the error less the local polynomial's smooth linear part, in eight parts.
    A white error is stationary; a noise that doubles halfway is flagged."""
    rng = np.random.default_rng(3)
    x, y = _record(rng.normal(0.0, 0.1, N4), period=900.0)
    st = analyze(T4, x, T4, y, period_s=900.0).uncertainty["stationarity"]
    assert st is not None and st["stationary"] and st["segments"] == 8
    x, y = _record(rng.normal(0.0, 0.1, N4) * np.where(T4 < 450.0, 1.0, 2.0), period=900.0)
    st = analyze(T4, x, T4, y, period_s=900.0).uncertainty["stationarity"]
    assert not st["stationary"] and st["p_value"] < 1e-6


def test_three_periods_are_not_assessed() -> None:
    x, y = _record(np.random.default_rng(3).normal(0.0, 0.1, N4), period=300.0)
    r = analyze(T4, x, T4, y, period_s=300.0)
    assert r.lines.n_periods == 3 and r.uncertainty["stationarity"] is None
    line = next(c for c in r.budget.contributions if c.key == "nonstationarity")
    assert line.status == NOT_ASSESSED and "two to five" in line.basis


def test_assess_needs_six_segments_of_32_samples() -> None:
    r = np.random.default_rng(4).normal(size=600)
    mask = np.ones(600, dtype=bool)
    spec = np.fft.rfft(r)
    assert assess(r, spec, mask, 0.25, 5, 0.0) is None
    assert assess(r, spec, mask, 0.25, 20, 0.0) is None  # 30 samples a segment
    st = assess(r, spec, mask, 0.25, 6, 0.0)
    assert st is not None and st.segments == 6 and st.segment_s == pytest.approx(25.0)
    assert st.stationary and st.widening() == 0.0


def test_drift_term_of_white_noise_keeps_its_degrees_of_freedom() -> None:
    """White noise: 20 equal cosine coefficients, each one degree of freedom. Of the shapes
    near the best fit the interval takes the one with the fewest degrees of freedom, which
    for a flat truth is still near flat: ν well above the 20/3 the values alone would say."""
    r = np.random.default_rng(5).normal(0.0, 1.0, 3600)
    mask = np.ones(3600, dtype=bool)
    drift = fit_drift(r, mask, 10, floor=1.0 / 3600)
    assert not drift.steep
    value, var, nu, g, h = low_part(drift, 0.0)
    assert 10.0 <= nu <= 20.0
    # 20 coefficients of 1/3600 each: 3600·value is χ² with 20 degrees of freedom
    assert chi2.ppf(0.0005, 20) <= 3600.0 * value <= chi2.ppf(0.9995, 20)
    assert var == pytest.approx(2.0 * value**2 / nu)
    assert 0.0 < g < 1.0 < h


def test_drift_term_of_a_random_walk_has_few_degrees_of_freedom() -> None:
    """A random walk's cosine coefficients fall as 1/k²: ν = (Σ1/k²)²/Σ1/k⁴ ≈ 2.4 over 20;
    the fit is steep, so the mean removal adds back the floor's var(ε̄) only."""
    rng = np.random.default_rng(6)
    w = np.cumsum(rng.normal(0.0, 1.0, 3600))
    drift = fit_drift(w, np.ones(3600, dtype=bool), 10, floor=1e-6)
    assert drift.steep
    value, _, nu, _, h = low_part(drift, 0.0)
    assert 1.0 <= nu <= 4.0
    assert value > 0.5 * np.var(w)
    assert h > 4.0  # the pivot's 2.5 % quantile near 0.16, not Pearson's 0.28


def test_weighted_chi2_factors_closed_form_and_walk() -> None:
    """Equal weights: a χ² of as many degrees of freedom (to the table's ±2 %); 1/k²
    weights: the 2.5 % quantile 0.156 of the sum (the note of weighted_chi2_factors)."""
    g, h = weighted_chi2_factors(np.full(10, 0.1))
    assert g == pytest.approx(1.0 - 10.0 / chi2.ppf(0.975, 10), rel=0.02)
    assert h == pytest.approx(10.0 / chi2.ppf(0.025, 10) - 1.0, rel=0.02)
    k = np.arange(1, 21)
    _, h = weighted_chi2_factors(1.0 / k**2)
    assert 1.0 / (h + 1.0) == pytest.approx(0.156, rel=0.03)


def test_random_walk_interval_coverage() -> None:
    """Against σ of the process: 95 % ± 3.2 binomial standard deviations (200 records:
    0.015). The long run is benchmarks/sigma_coverage.py (the DFT-only term this replaced
    read 0.82)."""
    cov, flagged, ratio, _, drifts = nonstationary_coverage("walk", 200)
    assert abs(cov - 0.95) <= 0.05
    assert flagged <= 0.03  # a walk's high frequencies are stationary: rarely flagged
    assert drifts >= 0.90  # … but its lowest ones rise: a drift (the long run: 0.97)
    assert ratio == pytest.approx(1.0, abs=0.02)


@pytest.mark.parametrize("period", [100.0, 900.0])
def test_modulated_gain_is_flagged_and_covered(period: float) -> None:
    """Nine periods and one: flagged, and σ's widened interval holds σ of the process (the
    long run reads 1.000 on both, at 2.3 and 2.7 times the spread: conservative)."""
    cov, flagged, ratio, _, drifts = nonstationary_coverage("modulated", 200, period)
    assert flagged >= 0.95
    assert drifts <= 0.02  # a changing power, not a drift (the long run: none)
    assert cov >= 0.93
    assert ratio == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize("b", [1.0, 2.0])
def test_a_power_law_rising_to_zero_frequency_is_a_drift(b: float) -> None:
    """Cosine coefficients exactly ``∝ k^(−b/2)`` (variances ``∝ k^(−b)``) over a floor 400 times
    below them: the fit's exponent is ``b`` and a drift is flagged; the same power spread
    flat (``b = 0``, a level at zero frequency) is not a drift."""
    n = N4
    k = np.arange(1, 21)
    floor = 1e-6
    for exponent, flagged in ((b, True), (0.0, False)):
        d = np.zeros(n)
        d[1:21] = np.sqrt(n) * 0.05 * k ** (-exponent / 2.0)
        drift = fit_drift(idct(d, type=2, norm="ortho"), np.ones(n, dtype=bool), 10, floor)
        assert drift.flagged is flagged and drift.steep is flagged, exponent
        assert drift.exponent == exponent
        assert drift.excess == pytest.approx(np.sum(d[1:21] ** 2 / n) / (20 * floor) - 1.0)


def test_white_error_has_no_drift_and_a_walk_is_named() -> None:
    """White noise: no drift (its lowest coefficients are the floor's); a random walk of 0.3°
    over the record: flagged, in the result, the warnings and the budget's line."""
    rng = np.random.default_rng(5)
    x, y = _record(rng.normal(0.0, 0.1, N4))
    r = analyze(T4, x, T4, y)
    assert r.uncertainty["drift"]["flagged"] is False
    assert not any("drifts" in w for w in r.warnings)
    walk = np.cumsum(rng.normal(0.0, 0.3 / np.sqrt(N4), N4))
    x, y = _record(rng.normal(0.0, 0.1, N4) + walk)
    r = analyze(T4, x, T4, y)
    d = r.uncertainty["drift"]
    assert d["flagged"] is True and d["exponent"] >= 1.0 and d["excess"] > d["threshold"]
    assert any(w.startswith("the error drifts") for w in r.warnings)
    line = next(c for c in r.budget.contributions if c.key == "nonstationarity")
    assert "DRIFT" in line.basis


@pytest.mark.parametrize("n", [37, 999, 4000, 12_345, 90_001])
@pytest.mark.parametrize("count", [1, 21, 40])
def test_low_cosines_are_the_cosine_transforms_lowest(n: int, count: int) -> None:
    """The lowest cosine coefficients by projection, and the series less their part, are the
    DCT's and the inverse DCT's of the rest, to rounding: whole blocks, a tail, one block."""
    count = min(count, n)
    rng = np.random.default_rng(n + count)
    v = np.cumsum(rng.normal(size=n)) + rng.normal(size=n)  # a walk: large low coefficients
    full = dct(v, type=2, norm="ortho")
    low = LowCosines(n, count)
    d = low.coefficients(v)
    scale = float(np.sqrt(np.sum(full * full)))
    assert np.max(np.abs(d - full[:count])) <= 1e-13 * scale
    full[:count] = 0.0
    rest = low.remove(v.copy(), d)
    assert np.max(np.abs(rest - idct(full, type=2, norm="ortho"))) <= 1e-13 * scale
