"""The 95 % interval of σ: closed forms, and its coverage over repeated synthetic records.

Coverage: R independent records; the number that cover the true σ is binomial(R, p). Here
R = 300 records per case (``SUITE_RECORDS``): at p = 0.95 its standard deviation is 0.0126,
and we accept 0.95 ± 0.04 (3.2 of them: a correct interval fails by chance about once in
700 runs; the seeds are fixed). The long Monte Carlo — the same cases over 600–1000 records,
each coverage with its standard deviation — is ``benchmarks/sigma_coverage.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2
from sigma_coverage import (
    KINDS,
    ONE_PERIOD_KINDS,
    SUITE_RECORDS,
    coloured_gaussian,
    drift_mean_removal,
    kind_coverage,
    multisine_gain_white,
)

from benchctl.analysis.uncertainty import (
    dof_of_variance,
    duration_for_precision,
    sigma_interval,
)

TOL = 0.04  # 3.2 binomial standard deviations at 300 records


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


@pytest.mark.slow
def test_coverage_multisine_gain_plus_white_noise() -> None:
    cov = multisine_gain_white(SUITE_RECORDS["multisine"])
    assert abs(cov - 0.95) < TOL, cov


@pytest.mark.slow
def test_coverage_coloured_gaussian_error() -> None:
    cov = coloured_gaussian(SUITE_RECORDS["coloured"])
    assert abs(cov - 0.95) < TOL, cov


# The interval per kind of error (white, in-band, drift, linear-dominated) on multisine records
# over whole periods: 9 periods of 100 s (lines detected, noise at the lines from unexcited
# bins), and one period of 900 s stated (every bin a line: the local polynomial method) for the
# kinds that depend on the noise at the lines. The cases: benchmarks/sigma_coverage.py.


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(KINDS))
def test_sigma_interval_coverage_per_error_kind(kind: str) -> None:
    cov, ratio, se, drifts = kind_coverage(kind, 100.0, SUITE_RECORDS["kind"])
    assert abs(cov - 0.95) <= TOL, (kind, cov)
    if kind == "drift":  # σ̂ is low by what the mean removal takes (2.9 % of σ²): within 3.5
        # standard errors of the records' mean σ̂/σ (its square: twice the relative error)
        assert ratio**2 == pytest.approx(1 - drift_mean_removal(), abs=3.5 * 2 * se)
    else:  # no drift flagged where there is none (the long run: at most 0.001)
        assert drifts <= 0.02, (kind, drifts)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ONE_PERIOD_KINDS)
def test_sigma_interval_coverage_one_period(kind: str) -> None:
    """One period per record: the noise at the lines, which the in-band and the linear kinds
    depend on, comes from the local polynomial method."""
    cov, _, _, drifts = kind_coverage(kind, 900.0, SUITE_RECORDS["one_period"])
    assert abs(cov - 0.95) <= TOL, (kind, cov)
    assert drifts <= 0.02, (kind, drifts)
