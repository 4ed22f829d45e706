"""Is the error stationary? The residual's power period by period, against what a stationary
error's spectrum predicts; and the slow parts of σ's interval that a spectrum alone gets wrong.

The line-wise estimate's interval of σ (:mod:`benchctl.analysis.linewise`) holds for an error
whose incoherent part is stationary: its variance estimate then has the degrees of freedom its
spectrum implies. Two kinds of error break that, and each gets its own treatment here.

**A drift** (a random walk, a slow wander of the instrument's bias): Gaussian, but its power
sits below the record's first DFT bins and is not periodic over the record, so the DFT smears
it over many bins that it counts as independent. Its part of σ² has few degrees of freedom.
The cosine transform (DCT-II) of the residual is the record's natural basis for it: the
mean-removed Brownian motion's Karhunen–Loève functions are ``cos(kπt/T)``, so its coefficients
are independent, each one degree of freedom (a χ²₁). :func:`low_part` takes the lowest
coefficients (to the frequency of the DFT's lowest ``low_bins`` bins) as the low term of the
interval: value ``Σ d_k²``, variance ``Σ ⅔·d_k²·…`` (the unbiased estimate of ``2θ_k²`` for a
χ²₁), Satterthwaite's ν.

**A changing power** (a slowly modulated gain, a noise that grows): the residual's mean
square differs from period to period by more than chance. :func:`assess` tests it: the
residual, its slow part (below two cycles per segment: the drift above) taken out, is cut
into segments — the record's whole periods when it has at least ``MIN_SEGMENTS``, else that
many equal parts — and each segment's mean square ``m_j`` compared with its variance under
stationarity, ``var(m_j) = (2/n_j) Σ_τ c(τ)²`` (``c`` the residual's autocovariance, from
its smoothed periodogram; white noise: ``2σ⁴/n_j``): ``X = Σ (m_j − m̄)²/var(m_j)`` is a χ²
with J − 1 degrees of freedom for a stationary error. Above its ``1 − FALSE_ALARM`` quantile
the record is flagged *non-stationary*.

A flagged record's σ is that of its own test, not of the process: a power that changes at
the record's own time scale is averaged over too few of its cycles. The variance that adds to
σ̂² is the segment sequence's spectral level at zero frequency over J (the spectral method of
Heidelberger & Welch for a mean of correlated batches), estimated from the lowest ``ENVELOPE_TERMS``
DCT coefficients of ``m_j`` less the part of it a stationary error makes (already in the
interval); it widens the interval as a normal term, its quantile Student's for the
estimate's ``ENVELOPE_TERMS`` degrees of freedom.

**σ of the process** (what the interval is about): the root mean square of the error about
its mean that tests of this length under this motion give on average. For a stationary error
that is the error's standard deviation; for a drifting or slowly changing one it depends on
the test's length, and a single test's σ can differ from it by more than its noise implies —
which the widened interval states.

Pure computation on arrays.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.fft import dct, idct
from scipy.special import chdtrc, stdtrit

FloatArray = NDArray[np.float64]

MIN_SEGMENTS = 6  # segments of the stationarity test (whole periods when there are as many)
FALSE_ALARM = 1e-3  # the test's false-alarm rate on a stationary error
SMOOTH_BINS = 16  # periodogram bins averaged for the autocovariance's Σ c²
ENVELOPE_TERMS = 3  # DCT coefficients of the segment mean squares for the level at zero
Z975 = 1.959963984540054


@dataclass(frozen=True)
class Stationarity:
    """The period-to-period test of the residual's power (deg², per segment)."""

    segments: int
    segment_s: float
    mean_squares: FloatArray
    expected_sd: float  # a stationary error's standard deviation of one segment's mean square
    statistic: float  # X, χ² with segments − 1 degrees of freedom when stationary
    p_value: float
    stationary: bool
    extra_variance: float  # variance the changing power adds to σ̂² (deg⁴); 0 when stationary
    extra_dof: float

    def widening(self) -> float:
        """The normal-equivalent variance (deg⁴) of the changing power's term, its quantile
        Student's for ``extra_dof``: ``V·(t_ν/z)²``."""
        if self.extra_variance <= 0.0:
            return 0.0
        t = float(stdtrit(self.extra_dof, 0.975))
        return self.extra_variance * (t / Z975) ** 2

    def to_dict(self) -> dict[str, Any]:
        return {
            "stationary": self.stationary,
            "segments": self.segments,
            "segment_s": self.segment_s,
            "statistic": self.statistic,
            "dof": self.segments - 1,
            "p_value": self.p_value,
            "false_alarm": FALSE_ALARM,
            "segment_mean_squares": [float(v) for v in self.mean_squares],
            "expected_sd": self.expected_sd,
            "added_variance": self.extra_variance,
            "added_dof": self.extra_dof,
        }


def _demeaned(r: FloatArray, mask: NDArray[np.bool_]) -> FloatArray:
    out = np.where(mask, r, 0.0)
    if mask.any():
        out = np.where(mask, out - out[mask].mean(), 0.0)
    return out


def _power_law(v: FloatArray, floor: float) -> FloatArray:
    """The expected values ``θ_k = c + a·k^(−b)`` of independent χ²₁-scaled values ``v_k``
    (k = 1 …), fitted by maximum likelihood over a grid of ``a ≥ 0`` and ``0 ≤ b ≤ 4``, the
    floor ``c`` given: a drift's shape, smooth where the values themselves scatter by a
    factor of ten (one degree of freedom each)."""
    k = np.arange(1, len(v) + 1, dtype=float)
    top = max(float(v.max()), floor, 1e-300)
    a = np.concatenate(([0.0], top * np.geomspace(1e-4, 4.0, 80)))
    b = np.linspace(0.0, 4.0, 17)
    theta = floor + a[:, None, None] * k[None, None, :] ** -b[None, :, None]
    theta = np.maximum(theta, 1e-300)
    loglik = -np.sum(np.log(theta) + v / theta, axis=-1)
    i, j = np.unravel_index(int(np.argmax(loglik)), loglik.shape)
    return np.asarray(theta[i, j], dtype=float)


def low_part(residual: FloatArray, mask: NDArray[np.bool_], low_bins: int,
             mean_removal: float, floor: float) -> tuple[float, float, float]:
    """The interval's low term from the DCT-II of the residual (module notes): the lowest
    ``2·low_bins`` coefficients (frequencies ``k/(2T)``, up to the DFT's bin ``low_bins``),
    with the mean removal's share, in variance units: ``(value, variance, ν)``. ν is that of
    the coefficients' fitted shape (:func:`_power_law`; ``floor``: the noise level of one
    coefficient just above them), not of the values themselves — a record whose first
    coefficient happens to be small would otherwise get many degrees of freedom and an
    interval too narrow just when it reads low."""
    r = _demeaned(residual, mask)
    n_valid = max(int(mask.sum()), 1)
    d = dct(r, type=2, norm="ortho")[1 : 2 * low_bins + 1]
    v = d * d / n_valid
    total = float(v.sum())
    if total <= 0.0:
        return 0.0, 0.0, math.inf
    scale = 1.0 + mean_removal / total
    value = total * scale
    theta = _power_law(v, max(floor, 0.0))
    nu = float(theta.sum() ** 2 / np.sum(theta * theta))
    return value, 2.0 * value * value / nu, nu


def _sum_c2(r: FloatArray) -> float:
    """``Σ_τ c(τ)²`` of a stationary series from its periodogram, smoothed over
    ``SMOOTH_BINS`` bins and corrected for the smoothing's bias (``E Ī² = S²(1 + 1/m)``)."""
    n = len(r)
    s = np.abs(np.fft.fft(r)) ** 2 / n  # two-sided periodogram, E = S_j
    m = min(SMOOTH_BINS, n)
    kernel = np.ones(m) / m
    sm = np.convolve(np.concatenate((s[-(m // 2):], s, s[: m - m // 2 - 1])), kernel, "valid")
    return float(np.sum(sm * sm) / n / (1.0 + 1.0 / m))


def assess(error: FloatArray, residual: FloatArray, mask: NDArray[np.bool_], dt: float,
           n_periods: int, line_cross: float) -> Stationarity | None:
    """The period-to-period test of the error's power (module notes); ``None`` when the
    record is too short for ``MIN_SEGMENTS`` segments of 32 samples.

    Over ``n_periods ≥ MIN_SEGMENTS`` whole periods the segments are the periods and the
    series is the error ε itself: a linear instrument's error then has the same lines in each
    period, and a gain that changes shows in them; its mean square varies by the noise's and
    by the cross term of lines and noise, ``line_cross`` (``Σ_k P_k s_k``, line units) times
    ``2J``. Otherwise the series is the lines' residual (the lines' power varies from one
    segment to the next by the motion's own envelope)."""
    n = len(residual)
    segments = n_periods
    if n_periods < MIN_SEGMENTS or n < 32 * segments:
        return None
    r = _demeaned(error, mask)
    d = dct(r, type=2, norm="ortho")
    d[: 4 * segments] = 0.0  # below two cycles per segment: the drift's, see low_part
    hp = np.where(mask, idct(d, type=2, norm="ortho"), 0.0)
    edges = np.linspace(0, n, segments + 1).round().astype(int)
    counts = np.add.reduceat(mask.astype(np.float64), edges[:-1])
    if np.any(counts < 16):
        return None
    ms = np.add.reduceat(hp * hp, edges[:-1]) / counts
    rd = _demeaned(residual, mask)
    rd = np.where(mask, idct(np.where(np.arange(n) < 4 * segments, 0.0,
                                      dct(rd, type=2, norm="ortho")), type=2, norm="ortho"), 0.0)
    c2 = _sum_c2(rd) * n / max(int(mask.sum()), 1)
    # var(m_j) of a stationary Gaussian noise, and the lines' cross term with it
    var = 2.0 * c2 / counts + 2.0 * segments * max(line_cross, 0.0)
    w = 1.0 / var
    mean = float(np.sum(w * ms) / np.sum(w))
    stat = float(np.sum(w * (ms - mean) ** 2))
    p = float(chdtrc(segments - 1, stat))
    stationary = p >= FALSE_ALARM
    extra, extra_dof = 0.0, math.inf
    if not stationary:
        e = dct(ms - mean, type=2, norm="ortho")[1 : ENVELOPE_TERMS + 1]
        level = float(np.mean(e * e)) - float(np.mean(var))
        extra = max(level, 0.0) / segments
        extra_dof = float(len(e))
    return Stationarity(
        segments=segments, segment_s=n * dt / segments, mean_squares=ms,
        expected_sd=float(np.sqrt(np.mean(var))), statistic=stat, p_value=p,
        stationary=stationary, extra_variance=extra, extra_dof=extra_dof)


__all__ = ["ENVELOPE_TERMS", "FALSE_ALARM", "MIN_SEGMENTS", "Stationarity", "assess",
           "low_part"]
