"""Is the error stationary? Its power segment by segment, against what a stationary error's
spectrum predicts; and the slow parts of σ's interval that a spectrum alone gets wrong.

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
interval: value ``Σ d_k²``; its pivot ``Σ d_k²/Σ θ_k`` a weighted sum of χ²₁ whose weights are
a power law fitted to the coefficients (:func:`fit_drift`), its quantiles exact
(``uncertainty.weighted_chi2_factors``). A drift that rises without bound towards zero
frequency has no level there: the mean removal then adds back only the noise floor's
``var(ε̄)``, not half the first bin's (the record's mean is the drift's own).

**A changing power** (a slowly modulated gain, a noise that grows): the error's mean square
differs from period to period by more than chance. :func:`assess` tests it over at least
``MIN_SEGMENTS`` whole periods: the error, its slow part (below two cycles a period: the
drift above) taken out, is cut into its periods, and each one's mean square ``m_j`` compared
with its variance under stationarity, ``var(m_j) = (2/n_j) Σ_τ c(τ)²`` (``c`` the residual's
autocovariance, from its smoothed periodogram; white noise: ``2σ⁴/n_j``) plus the lines'
cross term with the noise: ``X = Σ (m_j − m̄)²/var(m_j)`` is a χ² with J − 1 degrees of
freedom for a stationary error. On a one-period record (every line's noise from the local
polynomial method) the series is the error, less its smooth linear part's mean square, in
``ONE_PERIOD_SEGMENTS`` equal parts; a record of two to five periods is not assessed. Above
its ``1 − FALSE_ALARM`` quantile the record is flagged *non-stationary*.

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

from benchctl.analysis.uncertainty import weighted_chi2_factors

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

MIN_SEGMENTS = 6  # segments of the stationarity test (whole periods when there are as many)
ONE_PERIOD_SEGMENTS = 8  # … and of a one-period record's
FALSE_ALARM = 1e-3  # the test's false-alarm rate on a stationary error
SMOOTH_BINS = 16  # periodogram bins averaged for the autocovariance's Σ c²
#: the drift term's shape where a drift is flagged: of the power laws whose log-likelihood is
#: within this of the best, the one with the fewest degrees of freedom (without a flag: the
#: best fit). Chosen on the Monte Carlo of benchmarks/sigma_coverage.py: 0 (the best fit
#: everywhere) covers a random walk 89 % of the time, 3.0 (the 95 % region of two parameters)
#: a stationary low-pass noise 99 %; 0.75 for every record gave 94.4 % and 97.9 %, 0.75 where
#: a drift is flagged gives 93.9 % and 96.6 % (1000 records each)
SHAPE_DROP = 0.75
ENVELOPE_TERMS = 3  # DCT coefficients of the segment mean squares for the level at zero
#: a drift is flagged when its steep fit's coefficients hold more than 1 + this times the noise
#: floor's power. Chosen on benchmarks/sigma_coverage.py's records (300 of each kind): a random
#: walk of 0.1° over 900 s beside 0.1° of white noise is flagged in 97 % of them; white,
#: in-band and linear-dominated errors and a modulated gain in none (their median excess is
#: about 0); a stationary low-pass noise with its corner at 0.005 Hz (on 900 s records: the
#: power rises over the record's lowest coefficients there too) in 31 %
DRIFT_EXCESS = 1.0
Z975 = 1.959963984540054


@dataclass(frozen=True)
class Stationarity:
    """The segment-to-segment test of the error's power (deg², per segment)."""

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
    if mask.all():  # no gap: the same numbers, without the masked copies
        return np.subtract(r, r.mean()) if len(r) else np.array(r, dtype=float)
    out = np.where(mask, r, 0.0)
    if mask.any():  # in place: one record's length of memory, not two
        out -= out[mask].mean()
        out[~mask] = 0.0
    return out


#: at most this many of a record's lowest cosine coefficients are taken by projection on
#: their basis vectors (:class:`LowCosines`), more by the record's cosine transform (its cost
#: does not grow with them: 900 000 samples, 32 coefficients and their part taken out by
#: projection 16 ms, 60 of them 37 ms, by the transform and its inverse 32 ms)
PROJECTED_COSINES = 40
COSINE_BLOCK = 500  # samples per block of the projection
#: the projections' matrix products are made in row chunks of at most this many multiply-adds:
#: OpenBLAS makes a product that small on the calling thread, a larger one wakes its worker
#: threads, and on a busy machine they wait for a core longer than the product takes (32
#: coefficients of 900 000 samples and their part taken out, 2 cores busy: about 50 ms in
#: whole products, 15 ms in chunks)
SERIAL_PRODUCT = 1 << 18


def _cos_sin(j: NDArray[np.int64], n: int) -> tuple[FloatArray, FloatArray]:
    """cos and sin of ``π·j/(2n)``, the integers ``j`` first reduced modulo ``4n`` (exact):
    the angle's rounding is then that of a number below 2π."""
    a = (np.pi / (2 * n)) * (j % (4 * n)).astype(np.float64)
    return np.cos(a), np.sin(a)


class LowCosines:
    """The lowest ``count`` coefficients of a series' orthonormal cosine transform (DCT-II,
    ``d_k = c_k Σ_s v_s cos(πk(2s + 1)/(2n))``, ``c_0 = √(1/n)``, else ``√(2/n)``), and the
    series less their part, without a transform of the whole record.

    The record is cut into blocks of ``COSINE_BLOCK`` samples, ``s = m·q + p``; the angle is
    a block's ``α_k·m`` plus a position's ``β_kp``, so the projections are a matrix product of
    the blocks with ``[cos β, sin β]`` (``q × 2·count``), combined by ``cos α`` and ``sin α``
    (``blocks × count``), and the low part is the product of those back; the samples after the
    last whole block are projected directly. The same numbers as
    ``scipy.fft.dct(v, norm="ortho")[:count]`` (and the inverse transform of the rest) to the
    rounding of the sums, at a fraction of a transform's cost for a few dozen coefficients."""

    def __init__(self, n: int, count: int) -> None:
        self.n, self.count = n, count
        k = np.arange(count, dtype=np.int64)
        q = COSINE_BLOCK if n >= 2 * COSINE_BLOCK else max(n, 1)
        self.q, self.blocks = q, n // q
        self.head = self.blocks * q
        #: block rows per matrix product (SERIAL_PRODUCT multiply-adds at most)
        self.rows = max(1, SERIAL_PRODUCT // max(1, q * 2 * count))
        self.scale = np.full(count, math.sqrt(2.0 / n) if n else 0.0)
        if count:
            self.scale[0] = math.sqrt(1.0 / n) if n else 0.0
        cb, sb = _cos_sin(np.outer(2 * np.arange(q, dtype=np.int64) + 1, k), n)
        self.cs_b = np.hstack((cb, sb))  # q × 2·count
        self.cos_a, self.sin_a = _cos_sin(
            np.outer(2 * q * np.arange(self.blocks, dtype=np.int64), k), n)
        self.cos_tail, _ = _cos_sin(
            np.outer(2 * np.arange(self.head, n, dtype=np.int64) + 1, k), n)

    def coefficients(self, v: FloatArray) -> FloatArray:
        """``d_0 … d_{count−1}`` of ``v`` (length ``n``)."""
        vb = v[: self.head].reshape(self.blocks, self.q)
        uv = np.empty((self.blocks, 2 * self.count))
        rows = self.rows
        for i in range(0, self.blocks, rows):
            np.matmul(vb[i : i + rows], self.cs_b, out=uv[i : i + rows])
        d = (np.einsum("mk,mk->k", self.cos_a, uv[:, : self.count])
             - np.einsum("mk,mk->k", self.sin_a, uv[:, self.count :]))
        if self.head < self.n:
            d += v[self.head :] @ self.cos_tail
        return np.asarray(d * self.scale, dtype=float)

    def remove(self, v: FloatArray, d: FloatArray) -> FloatArray:
        """``v − Σ_k d_k·(basis vector k)``, in place in ``v``."""
        ds = d * self.scale
        a = np.hstack((self.cos_a * ds, -self.sin_a * ds))  # blocks × 2·count
        head = v[: self.head].reshape(self.blocks, self.q)
        cs_t = self.cs_b.T
        rows = self.rows
        low = np.empty((min(rows, self.blocks), self.q))
        for i in range(0, self.blocks, rows):
            part = low[: min(rows, self.blocks - i)]
            np.matmul(a[i : i + rows], cs_t, out=part)
            head[i : i + rows] -= part
        if self.head < self.n:
            v[self.head :] -= self.cos_tail @ ds
        return v


def _low_coefficients(v: FloatArray, count: int) -> FloatArray:
    """The lowest ``count`` orthonormal DCT-II coefficients of ``v`` (at most its length)."""
    count = min(count, len(v))
    if count <= PROJECTED_COSINES:
        return LowCosines(len(v), count).coefficients(v)
    return np.asarray(dct(v, type=2, norm="ortho")[:count], dtype=float)


@dataclass(frozen=True)
class Drift:
    """The residual's lowest cosine coefficients (variance units) and their fitted shape."""

    values: FloatArray  # d_k²/n, k = 1 … 2·low_bins
    shape: FloatArray  # θ_k of the interval: the fewest degrees of freedom in the 95 % region
    floor: float  # c: one coefficient's noise level just above them
    steep: bool  # the best fit falls as k^(−b), b ≥ 1: no finite level at zero frequency
    exponent: float = 0.0  # b of the best fit (0 with no drift part: a = 0)

    @property
    def excess(self) -> float:
        """The coefficients' power over what the noise floor alone gives them, as a ratio less
        one (0: the floor's; a random walk of the bias reads about 15 in the Monte Carlo)."""
        return _excess(self.values, self.floor)

    @property
    def flagged(self) -> bool:
        """A drift (:func:`_is_drift`)."""
        return _is_drift(self.steep, self.values, self.floor)

    def to_dict(self) -> dict[str, Any]:
        excess = self.excess
        return {
            "flagged": self.flagged,
            "exponent": self.exponent,
            "excess": excess if math.isfinite(excess) else None,
            "threshold": DRIFT_EXCESS,
            "coefficients": len(self.values),
            "variance": float(self.values.sum()),
            "floor": self.floor,
        }


def _excess(values: FloatArray, floor: float) -> float:
    expected = floor * len(values)
    if expected <= 0.0:
        return math.inf if float(values.sum()) > 0.0 else 0.0
    return float(values.sum()) / expected - 1.0


def _is_drift(steep: bool, values: FloatArray, floor: float) -> bool:
    """A drift: the best fit rises without bound towards zero frequency (``steep``) and the
    lowest coefficients hold more than ``1 + DRIFT_EXCESS`` times the floor's power."""
    return steep and _excess(values, floor) > DRIFT_EXCESS


def fit_drift(residual: FloatArray, mask: NDArray[np.bool_], low_bins: int,
              floor: float) -> Drift:
    """The expected values ``θ_k = c + a·k^(−b)`` of the residual's lowest ``2·low_bins``
    cosine coefficients (χ²₁-scaled), fitted by maximum likelihood over a grid of ``a ≥ 0`` and
    ``0 ≤ b ≤ 4``, the floor ``c`` given: a drift's shape, smooth where the values themselves
    scatter by a factor of ten (one degree of freedom each). Where a drift is flagged
    (``Drift.flagged``) the interval takes, of the shapes whose log-likelihood is within
    ``SHAPE_DROP`` of the best, the one with the fewest degrees of freedom: a drift whose first
    coefficients happen to be small looks flatter than it is, and would otherwise get a narrow
    interval just when it reads low. Where none is flagged it takes the best fit."""
    r = _demeaned(residual, mask)
    n_valid = max(int(mask.sum()), 1)
    d = _low_coefficients(r, 2 * low_bins + 1)[1:]
    v = d * d / n_valid
    c = max(floor, 0.0)
    k = np.arange(1, len(v) + 1, dtype=float)
    top = max(float(v.max()), c, 1e-300)
    a = np.concatenate(([0.0], top * np.geomspace(1e-4, 4.0, 80)))
    b = np.linspace(0.0, 4.0, 17)
    theta = np.maximum(c + a[:, None, None] * k[None, None, :] ** -b[None, :, None], 1e-300)
    loglik = -0.5 * np.sum(np.log(theta) + v / theta, axis=-1)
    best = np.unravel_index(int(np.argmax(loglik)), loglik.shape)
    steep = bool(a[best[0]] > 0.0 and b[best[1]] >= 1.0)
    exponent = float(b[best[1]]) if a[best[0]] > 0.0 else 0.0
    i, j = best[0], best[1]
    if _is_drift(steep, v, c):  # its safe shape
        nu = theta.sum(axis=-1) ** 2 / np.sum(theta * theta, axis=-1)
        nu = np.where(loglik >= loglik.max() - SHAPE_DROP, nu, np.inf)
        i, j = np.unravel_index(int(np.argmin(nu)), nu.shape)
    return Drift(values=v, shape=np.asarray(theta[i, j], dtype=float), floor=c, steep=steep,
                 exponent=exponent)


def low_part(drift: Drift, mean_removal: float) -> tuple[float, float, float, float, float]:
    """The interval's low term (module notes) with the mean removal's share, in variance
    units: ``(value, variance, ν, G, H)``; ν that of the drift's shape (:func:`fit_drift`), G
    and H the interval factors of its pivot (``weighted_chi2_factors``)."""
    total = float(drift.values.sum())
    if total <= 0.0:
        return 0.0, 0.0, math.inf, 0.0, 0.0
    value = total + mean_removal
    theta = drift.shape
    nu = float(theta.sum() ** 2 / np.sum(theta * theta))
    g, h = weighted_chi2_factors(theta)
    return value, 2.0 * value * value / nu, nu, g, h


def _sum_c2(spectrum: ComplexArray, n: int, cut: int) -> float:
    """``Σ_τ c(τ)²`` of a stationary series of length ``n`` from its rfft, the bins below
    ``cut`` left out (the drift's): the periodogram ``S_j = |X_j|²/n`` smoothed over
    ``SMOOTH_BINS`` bins and corrected for the smoothing's bias (``E Ī² = S²(1 + 1/m)``),
    ``(1/n) Σ_j S_j²`` over the two-sided bins."""
    s = (spectrum.real**2 + spectrum.imag**2) / n
    s[:cut] = 0.0
    m = min(SMOOTH_BINS, len(s))
    sm = np.convolve(s, np.ones(m) / m, "same")
    sq = sm * sm
    total = 2.0 * float(sq.sum()) - float(sq[0]) - (float(sq[-1]) if n % 2 == 0 else 0.0)
    return total / n / (1.0 + 1.0 / m)


def assess(series: FloatArray, noise_spectrum: ComplexArray, mask: NDArray[np.bool_],
           dt: float, segments: int, line_cross: float, baseline: FloatArray | None = None,
           lowest_line_bin: int | None = None) -> Stationarity | None:
    """The segment-to-segment test of the error's power (module notes); ``None`` when the
    record is too short for ``segments`` segments of 32 samples.

    ``series``, its slow part below two cycles a segment taken out by its cosine transform
    (a drift's, :func:`fit_drift`; or below ``lowest_line_bin``, DFT bins of the record, if
    lower), is cut into ``segments`` equal parts; ``noise_spectrum`` (the rfft of the
    zero-filled noise) gives a segment mean square's variance under stationarity, from its
    bins above the same cut.

    Over whole periods the series is the error ε itself: a linear instrument's error has the
    same lines in each period, and a gain that changes shows in them. Its mean square varies
    by the noise's and by the cross term of lines and noise, ``line_cross`` (``Σ_k P_k s_k``,
    line units) times ``2J``; the noise is the lines' residual. On one period the motion's
    own envelope makes the lines' power differ from segment to segment: each segment's mean
    square of the smooth linear part, ``baseline``, is taken off (what is left is the
    noise's and its cross term with the lines), and the noise is the error less that linear
    part (:func:`benchctl.analysis.linewise.noise_spectrum`)."""
    n = len(series)
    if segments < MIN_SEGMENTS or n < 32 * segments:
        return None
    edges = np.linspace(0, n, segments + 1).round().astype(np.int64)
    counts = np.add.reduceat(mask.astype(np.float64), edges[:-1])
    if np.any(counts < 16):
        return None
    cut = 2 * segments if lowest_line_bin is None else min(2 * segments, lowest_line_bin)

    low = LowCosines(n, 2 * cut) if 2 * cut <= PROJECTED_COSINES else None

    def high_pass_power(v: FloatArray) -> FloatArray:
        """Each segment's mean square of ``v`` high-passed: its cosine coefficients below
        ``2·cut`` taken out (DCT index k is frequency k/(2T): DFT bin k/2), by projection
        or by the transform and its inverse (arrays reused in place: a long record's analysis
        peaks here)."""
        if low is not None:
            hp = _demeaned(v, mask)
            low.remove(hp, low.coefficients(hp))
        else:
            d = dct(_demeaned(v, mask), type=2, norm="ortho", overwrite_x=True)
            d[: 2 * cut] = 0.0
            hp = idct(d, type=2, norm="ortho", overwrite_x=True)
            del d
        if not mask.all():
            hp[~mask] = 0.0
        np.square(hp, out=hp)
        return np.asarray(np.add.reduceat(hp, edges[:-1]) / counts, dtype=float)

    ms = high_pass_power(series)
    if baseline is not None:  # the same filter: a line near the cut loses the same to it
        ms = ms - high_pass_power(baseline)
    n_valid = max(float(mask.sum()), 1.0)
    c2 = _sum_c2(noise_spectrum, n, cut) * (n / n_valid) ** 2
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


__all__ = ["ENVELOPE_TERMS", "FALSE_ALARM", "MIN_SEGMENTS", "ONE_PERIOD_SEGMENTS", "Drift",
           "LowCosines", "Stationarity", "assess", "fit_drift", "low_part"]
