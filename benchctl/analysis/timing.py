"""Timing in the analysis: which instants to trust, and what their errors do to σ.

**Stamps or instants?** A stream's stamps scatter about the uniform clock fitted through them
(``clockfit.fit_slots``) by ``d_i``. Either the samples were taken on that clock and the stamps
are late or early by ``d_i`` (receipt times, a logger's jitter, stamps rounded to 1 ms), or the
samples really were taken at the stamps (an instrument that samples when it is asked). The data
tell which: an instant off by ``d`` moves the reference read there by ``ẋ·d``, so the error
formed at the stamps is

    ε = ε₀ − β_dev·ẋ·d_dev + β_ref·ẋ·D_ref

with ``D_ref`` the reference's scatter carried through the interpolating spline to the device's
instants and ``β`` the share of each stream's scatter that is the stamps' error (1: stamps
jitter about the instants; 0: the stamps are the instants). ``ε₀`` — the instrument's error —
does not depend on when the host happened to stamp a sample, so least squares of ε on the two
regressors (with ``x`` and ``ẋ`` beside them, which take up a linear dynamic error and so
narrow the estimate) gives each ``β`` with its standard error (``stamp_shares``). The default
time base (``"auto"``) of a stream whose stamps scatter is then the fitted clock when
``β ≥ AUTO_SHARE`` and the stamps otherwise.

**The timing budget** (``timing_budget``). What the instants' remaining errors do to σ²:

- random errors of rms ``δ`` add ``σ_ẋ²·δ²`` (the stamps' share ``β`` of a stream used as
  given, the fitted clock's error for a fitted one), a bias: σ² is read high by it;
- the same random errors move σ² through the error itself, ``−2·mean(ε·ẋ·δ)``: zero on
  average, of standard deviation ``2·rms(ε·ẋ)·δ/√N``;
- an offset ``δ₀`` common to the record (what a fitted clock or a stand clock leaves unknown, of
  standard uncertainty ``u₀``) adds ``−2·δ₀·cov(ε, ẋ) + δ₀²σ_ẋ²``. For a lagging instrument ε
  is mostly ``−τ·ẋ``: the first term is first-order in ``δ₀`` (0.75 ms against an 80 ms lag:
  σ² +1.9 %), of standard uncertainty ``2·|cov(ε, ẋ)|·u₀``. A clock fitted through stamps
  (block levels of ``WANDER_BLOCK`` samples) has independent errors from block to block: the
  offset common to the record is its rms error over √(blocks) (``Aligned.offset_u_s``).

σ's interval ``[lo, hi]`` (from the record's statistics) becomes, in σ², the statistical
half-widths about its centre each combined in quadrature with 1.96 × the two standard
deviations above (``cross``), and
the lower end moved down by the bias: the truth is σ̂² less the bias, and the bias is known
to no better than itself (the stamps' share of the scatter, the clock's error are estimates).
The timing is worth a warning when it moves the interval noticeably: when bias + 1.96 × the
cross term exceeds ``WARN_SHARE_OF_HALF_WIDTH`` of the statistical lower half-width (a fixed
share of σ², warned at 1 % whatever the record, is too late for a long record — its interval
is narrower than that — and too early for a short one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis.sums import dot

FloatArray = NDArray[np.float64]

AUTO_SHARE = 0.5  # the fitted clock when at least this share of the scatter is the stamps'
WARN_SHARE_OF_HALF_WIDTH = 0.25  # warn when timing moves σ² by this share of the half-width
Z95 = 1.959963984540054


@dataclass(frozen=True)
class StampShare:
    """The share ``beta`` of a stream's scatter about its clock that is the stamps' own error,
    and its standard error (NaN: not measurable — no scatter, or the two streams' scatter one
    and the same)."""

    beta: float
    se: float

    @property
    def measured(self) -> bool:
        return math.isfinite(self.beta) and math.isfinite(self.se)

    def to_dict(self) -> dict[str, float | None]:
        return {"stamp_share": self.beta if self.measured else None,
                "stamp_share_se": self.se if self.measured else None}


NOT_MEASURED = StampShare(math.nan, math.nan)


def stamp_shares(
    eps: FloatArray, x: FloatArray, xdot: FloatArray, d_dev: FloatArray, d_ref: FloatArray
) -> tuple[StampShare, StampShare]:
    """``β`` of the device's and the reference's scatter (module notes), by least squares of
    ``eps`` on ``1, x, ẋ, −ẋ·d_dev, ẋ·d_ref`` (all at the device's samples). A regressor with
    no spread, or two that are one (a single CSV's shared time column), is not measured."""
    n = len(eps)
    cols = [np.ones(n), x - x.mean(), xdot - xdot.mean()]
    names: list[str] = []
    for name, u in (("dev", -xdot * d_dev), ("ref", xdot * d_ref)):
        if dot(u, u) > 0.0 and np.all(np.isfinite(u)):
            cols.append(u)
            names.append(name)
    out = {"dev": NOT_MEASURED, "ref": NOT_MEASURED}
    if not names or n <= len(cols) + 2:
        return out["dev"], out["ref"]
    a = np.column_stack(cols)
    scale = np.sqrt(np.sum(a * a, axis=0))
    scale[scale == 0.0] = 1.0
    an = a / scale
    gram = an.T @ an
    if np.linalg.cond(gram) > 1e10:  # the two scatters the same (one time column): neither
        return out["dev"], out["ref"]
    coef = np.linalg.solve(gram, an.T @ eps)
    resid = eps - an @ coef
    s2 = dot(resid, resid) / (n - len(cols))
    cov = s2 * np.linalg.inv(gram)
    for j, name in enumerate(names, start=3):
        out[name] = StampShare(float(coef[j] / scale[j]), float(math.sqrt(cov[j, j]) / scale[j]))
    return out["dev"], out["ref"]


@dataclass(frozen=True)
class TimingBudget:
    """What timing does to σ² (deg²): ``bias`` (random instant errors: σ² read high by it),
    ``cross`` (the standard uncertainty of σ² from an offset common to the record, first order
    in it: ``2|cov(ε, ẋ)|·u₀``); the statistical interval and the one with timing in it."""

    bias: float
    cross: float
    cov_eps_rate: float  # cov(ε, ẋ), deg²/s
    offset_u_s: float  # u₀, s
    ci_statistical: tuple[float, float]
    ci: tuple[float, float]
    warn: bool

    def fields(self) -> dict[str, Any]:
        return {
            "timing_bias_variance": self.bias,
            "timing_offset_u_s": self.offset_u_s,
            "timing_cross_variance_u": self.cross,
            "error_rate_covariance": self.cov_eps_rate,
            "sigma_ci95_statistical": list(self.ci_statistical),
            "timing_in_interval": self.ci != self.ci_statistical,
        }


def timing_budget(
    sigma: float,
    ci: tuple[float, float],
    bias: float,
    cov_eps_rate: float,
    offset_u_s: float,
    random_cross: float = 0.0,
) -> TimingBudget:
    """σ's interval with timing in it, and whether it is worth a warning (module notes).

    ``sigma``: the centre of the interval (σ̂, or σ̂ with the mean removal added back, deg);
    ``ci``: its statistical 95 % interval; ``bias``: the variance random
    instant errors add (deg²); ``cov_eps_rate``: cov(ε, ẋ) (deg²/s); ``offset_u_s``: the
    standard uncertainty of an offset common to the record between the two streams' instants;
    ``random_cross``: the standard deviation of σ² from random instant errors through the
    error itself, ``2·rms(ε·ẋ)·δ/√N`` (deg²).
    """
    lo, hi = float(ci[0]), float(ci[1])
    v = min(max(sigma * sigma, lo * lo), hi * hi)
    cross = math.hypot(2.0 * abs(cov_eps_rate) * offset_u_s, random_cross)
    ext = Z95 * cross
    h_lo = max(v - lo * lo, 0.0)
    h_hi = max(hi * hi - v, 0.0)
    lo2 = v - math.hypot(h_lo, ext) - max(bias, 0.0)
    hi2 = v + math.hypot(h_hi, ext)
    new = (math.sqrt(max(lo2, 0.0)), math.sqrt(max(hi2, 0.0)))
    moved = max(bias, 0.0) + ext
    if moved <= 0.0 or not math.isfinite(moved):
        new = (lo, hi)
    warn = moved > WARN_SHARE_OF_HALF_WIDTH * max(h_lo, 1e-300) and moved > 1e-18
    return TimingBudget(max(bias, 0.0), cross, cov_eps_rate, offset_u_s, (lo, hi), new, warn)


def error_rate_covariance(eps: FloatArray, xdot: FloatArray) -> float:
    """cov(ε, ẋ) over the samples (deg²/s)."""
    if len(eps) < 2:
        return 0.0
    return float(np.mean((eps - eps.mean()) * (xdot - xdot.mean())))


__all__ = ["AUTO_SHARE", "StampShare", "TimingBudget", "error_rate_covariance", "stamp_shares",
           "timing_budget"]
