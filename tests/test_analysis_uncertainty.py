"""The 95 % interval of σ: closed forms, and its coverage over repeated synthetic records.

Coverage: R independent records; the number that cover the true σ is binomial(R, p). With
R = 800 and p = 0.95 its standard deviation is 0.0077; we accept 0.95 ± 0.03 (≈ 3.9 σ), so a
correct interval fails this by chance about once in 10⁴ runs (and the seeds are fixed).
"""

from __future__ import annotations

import numpy as np
import pytest
from analysis_synthetic import Multisine, gain
from scipy.signal import lfilter
from scipy.stats import chi2

from benchctl.analysis import analyze
from benchctl.analysis.uncertainty import (
    dof_of_variance,
    duration_for_precision,
    sigma_interval,
)

REPS = 800
TOL = 0.03


def test_interval_closed_form() -> None:
    lo, hi = sigma_interval(2.0, 50.0)
    assert lo == pytest.approx(2.0 * np.sqrt(50.0 / chi2.ppf(0.975, 50.0)))
    assert hi == pytest.approx(2.0 * np.sqrt(50.0 / chi2.ppf(0.025, 50.0)))
    assert sigma_interval(1.0, float("inf")) == (1.0, 1.0)


def test_dof_of_white_noise_is_sample_count() -> None:
    f = np.linspace(0, 50, 1001)  # fs = 100 Hz, T = 100 s → N = 10000
    g = np.full_like(f, 2 * 1.0 / 100)  # σ² = 1
    nu = dof_of_variance(f, np.zeros_like(f), g, 100.0, dof_per_freq=1e12)
    assert nu == pytest.approx(10000, rel=1e-6)


def test_deterministic_part_adds_only_its_cross_term() -> None:
    f = np.linspace(0, 50, 1001)
    inc = np.full_like(f, 0.02)
    lin = np.where((f > 1) & (f < 2), 1.0, 0.0)
    nu_known = dof_of_variance(f, lin, inc, 100.0, 1e12)
    nu_random = dof_of_variance(f, lin, inc, 100.0, 1e12, motion_random=True)
    lin_area, inc_area = np.trapezoid(lin, f), np.trapezoid(inc, f)  # 0.975, 1.0 deg²
    expected = 2 * 100 * (lin_area + inc_area) ** 2 / (0.02**2 * 50 + 2 * 0.02 * lin_area)
    assert nu_known == pytest.approx(expected, rel=1e-9)
    assert nu_random == pytest.approx(
        2 * 100 * (lin_area + inc_area) ** 2 / np.trapezoid((lin + inc) ** 2, f), rel=1e-9
    )


def test_duration_for_precision() -> None:
    # ν = 2·(1.96/0.05)² / 2 ≈ 1537 for ±5 %; a record with ν = 768 needs twice its length
    assert duration_for_precision(100.0, 0.5 * (1.959964 / 0.05) ** 2 / 2) == pytest.approx(200.0)


def _coverage(make_error, true_sigma: float) -> float:
    t = np.arange(3000) / 10.0  # 300 s at 10 Hz
    x = MS.reference(t)
    rng = np.random.default_rng(2024)
    hits = 0
    for _ in range(REPS):
        r = analyze(t, x, t, x + make_error(t, x, rng))
        hits += r.sigma_ci95[0] <= true_sigma <= r.sigma_ci95[1]
    return hits / REPS


MS = Multisine(period_s=100.0, f_lo=0.05, f_hi=1.0, rms_deg=5.0)


@pytest.mark.slow
def test_coverage_multisine_gain_plus_white_noise() -> None:
    h, sn = gain(0.98), 0.1
    true_sigma = np.sqrt(MS.error_variance(h) + sn**2)
    cov = _coverage(lambda t, x, rng: MS.through(h, t) - x + rng.normal(0, sn, t.size), true_sigma)
    assert abs(cov - 0.95) < TOL, cov


@pytest.mark.slow
def test_coverage_coloured_gaussian_error() -> None:
    a, sn = 0.6, 0.1  # AR(1) noise, variance sn²

    def err(t, x, rng):
        e = rng.normal(0, sn * np.sqrt(1 - a * a), t.size + 200)
        return lfilter([1.0], [1.0, -a], e)[200:]

    cov = _coverage(err, sn)
    assert abs(cov - 0.95) < TOL, cov
