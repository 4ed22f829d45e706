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
from sigma_coverage import N4, T4, nonstationary_coverage

from benchctl.analysis import analyze
from benchctl.analysis.budget import EVALUATED, NOT_ASSESSED
from benchctl.analysis.stationarity import FALSE_ALARM, assess, low_part

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


def test_one_period_record_is_not_assessed() -> None:
    x, y = _record(np.random.default_rng(3).normal(0.0, 0.1, N4), period=900.0)
    r = analyze(T4, x, T4, y, period_s=900.0)
    assert r.uncertainty["stationarity"] is None
    line = next(c for c in r.budget.contributions if c.key == "nonstationarity")
    assert line.status == NOT_ASSESSED and "six whole periods" in line.basis


def test_assess_needs_six_periods_of_32_samples() -> None:
    r = np.random.default_rng(4).normal(size=600)
    mask = np.ones(600, dtype=bool)
    assert assess(r, r, mask, 0.25, 5, 0.0) is None
    assert assess(r, r, mask, 0.25, 20, 0.0) is None  # 30 samples a period
    st = assess(r, r, mask, 0.25, 6, 0.0)
    assert st is not None and st.segments == 6 and st.segment_s == pytest.approx(25.0)


def test_drift_term_of_white_noise_keeps_its_degrees_of_freedom() -> None:
    """White noise: 20 equal cosine coefficients, each one degree of freedom; the fitted
    shape is flat, so ν is 20 (the values alone would say about 20/3)."""
    r = np.random.default_rng(5).normal(0.0, 1.0, 3600)
    mask = np.ones(3600, dtype=bool)
    value, var, nu = low_part(r, mask, 10, 0.0, floor=1.0 / 3600)
    assert nu == pytest.approx(20.0, rel=0.05)
    assert value == pytest.approx(20.0 / 3600, rel=0.7)
    assert var == pytest.approx(2.0 * value**2 / nu)


def test_drift_term_of_a_random_walk_has_few_degrees_of_freedom() -> None:
    """A random walk's cosine coefficients fall as 1/k²: ν = (Σ1/k²)²/Σ1/k⁴ ≈ 2.2 over 20."""
    rng = np.random.default_rng(6)
    w = np.cumsum(rng.normal(0.0, 1.0, 3600))
    value, _, nu = low_part(w, np.ones(3600, dtype=bool), 10, 0.0, floor=1e-6)
    assert 1.0 <= nu <= 4.0
    assert value > 0.5 * np.var(w)


def test_random_walk_interval_coverage() -> None:
    """Against σ of the process. The long run (1000 records) reads 0.910 ± 0.007: below the 0.95
    goal, which the interval does not yet reach for a random walk (the DFT-only term it
    replaced read 0.82). The bound here holds that floor, not the goal."""
    cov, flagged, ratio, _ = nonstationary_coverage("walk", 200)
    assert cov >= 0.86
    assert flagged <= 0.03  # a walk's high frequencies are stationary: rarely flagged
    assert ratio == pytest.approx(1.0, abs=0.02)


def test_modulated_gain_is_flagged_and_covered() -> None:
    cov, flagged, ratio, _ = nonstationary_coverage("modulated", 200)
    assert flagged >= 0.95
    assert cov >= 0.93
    assert ratio == pytest.approx(1.0, abs=0.01)
