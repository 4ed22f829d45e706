"""Clock skew between the two streams: a delay that grows (or shrinks) steadily over the record.

An instrument that stamps its samples with its own clock — a logger's CSV, a device clock never
fitted to the host's — runs a little fast or slow: at 200 ppm its stamps drift 0.18 s from the
reference's over 15 minutes, and the error ``y − x`` read at the drifting instants is mostly the
drift (σ +143 … +485 %). The instrument's own response does not change over the record, so a
*change* of the cross-spectrum's phase from one stretch of the record to the next is the drift:

1. the record (on the device's grid, gaps masked) is cut into ``S`` equal segments — of whole
   periods of the motion when its period is known and the record holds at least
   ``MIN_PERIODS``; in each the cross-spectrum ``C_s(f) = Y_s(f)·X_s*(f)`` at the frequencies
   where the reference is strong (the bins holding ``POWER_SHARE`` of its power). Segments that
   are not whole periods are Hann-windowed: the motion's lines leak into each other's bins
   and, beating, turn the phases in a pattern of their own;
2. between consecutive segments the delay changed by the phase turn of ``C_s·C_{s−1}*``,
   ``Δτ_s = −Σ w_f ω_f Δφ_s(f) / Σ w_f ω_f²`` (weights ``w_f = |C_s||C_{s−1}|``); consecutive
   segments differ by little, so the phases never wrap, whatever the drift over the record;
3. cumulated, these turns give a first delay per segment, each then read again against the
   record's mean cross-spectrum ``C̄ = Σ_s C_s e^{jωτ_s}`` (``_against_mean``): cumulating
   the consecutive turns carries each step's error into every later segment (a random walk a
   line reads as a skew of a few ppm); against the mean each segment has only its own;
4. the delays ``τ_s`` against the segments: a least-squares line, its slope the skew ``b``
   (s per s) with its standard error from the line's residuals; and, for a delay that changes
   *slowly* rather than steadily (a clock whose rate drifts as it warms), a polynomial in time
   of the highest degree up to ``MAX_DEGREE`` whose top term is beyond ``CURVE_SIGNIFICANT``
   standard errors, its terms beyond the line passing an F test at ``CURVE_P`` together, with
   ``MIN_DOF`` segments to spare. A segment's phase turns with the mean
   delay over it (weighted by the windows' product), not the delay at its middle, so the
   model is fitted to its columns averaged over each segment (``_design``). A curve found on
   few whole periods is sought again on ``SEGMENTS_MAX`` windowed segments, which can hold a
   higher degree.

The skew is corrected when it is significant (``|b| > SIGNIFICANT``·its standard error, at
least ``MIN_PPM``) or a curve is, measured on ``MIN_SEGMENTS`` segments or more, and the model
explains ``MIN_R2`` of the delays' spread — a steady or slowly changing drift, not the steps
that bursts of late receipts make, nor the beating of lines that leak. A lagging instrument's σ
moves with the delay left on average over the record (``b·T/2``: 3 ppm over 15 minutes,
1.35 ms, against an 80 ms lag: σ +1.5 %), so there is no floor beyond significance. The
device's instants then become ``t − b·(t − t₀)`` (a curve: ``t − (τ(t) − τ(t₀))``), anchored
at the record's first device instant — the instrument's clock taken as right when the record
began (a logger started with the test); the delay there stays, as the instrument's own. What
the correction leaves uncertain (``anchor_se_s``: the model's mean over the record less its
start), or a slope beyond ``UNEXPLAINED`` standard errors left uncorrected
(``unexplained_s``), goes into σ's interval (``timing.timing_budget``). Above ``WARN_PPM``, or
with a curve, the result warns.

Pure computation on arrays: :func:`estimate_skew`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.fft import rfft
from scipy.special import fdtri

FloatArray = NDArray[np.float64]

SEGMENTS_MAX = 16  # segments of the record (fewer when a segment would be too short) …
SEGMENT_MIN_S = 20.0  # … at least this long …
SEGMENT_MIN_SAMPLES = 256  # … and holding this many slots
POWER_SHARE = 0.99  # the reference's strongest bins holding this share of its power
SIGNIFICANT = 4.0  # standard errors a skew (or a curve's term) must exceed to be corrected …
MIN_PPM = 0.1  # … and at least this (noise-free data: not a rounding). A lagging instrument's
# σ moves by about b·T/τ: 5 ppm over 15 minutes against a 90 ms lag, +2.5 % (once the floor)
UNEXPLAINED = 2.0  # a slope beyond this many standard errors, not corrected: in σ's interval
MAX_DEGREE = 8  # a delay that changes slowly: a polynomial of degree up to this …
MIN_DOF = 6  # … leaving this many segments beyond its terms, its top term beyond
CURVE_SIGNIFICANT = 5.0  # this many standard errors, and the curve as a whole beyond the line
CURVE_P = 1e-4  # at this level (F test): several degrees are tried, so a stricter test than a
# line's, or segments' noise reads as a curve (a 300 s record's 15 windowed segments: degree 8;
# at 1e-3 one perfect clock in a thousand, nine periods of white error, read a curve of
# degree 2 and had its stamps moved; the slowest curves of the tests pass at 1e-4, not 1e-5)
WARN_PPM = 20.0  # a skew above this is a warning (the clocks should be fixed)
MIN_PERIODS = 4  # a known period: segments of whole periods when the record holds this many
MIN_R2 = 0.9  # the model must explain this share of the delays' spread …
MIN_SEGMENTS = 6  # … over at least this many segments


@dataclass(frozen=True)
class Skew:
    """The drift of the device's instants against the reference's: ``ppm`` (its stamps fast by
    this many parts per million: ``b·10⁶``), its standard error, the delays per segment."""

    ppm: float
    se_ppm: float
    segments: int
    drift_s: float  # over the record: b × its span
    delays_s: FloatArray  # τ_s − τ_0 per segment
    mids_s: FloatArray  # the segments' mid-times from the record's start
    r2: float = 1.0  # the share of the delays' spread the model explains
    whole_periods: bool = False  # segments of whole periods of the motion
    degree: int = 1  # the delay's model: a line (1), or a curve (a rate that changes)
    coef: tuple[float, ...] = ()  # the model's delay (s) in s from the record's start, c₀ + c₁u …
    t0_s: float = 0.0  # the record's start on the device's clock (its first grid instant)
    half_s: float = 0.0  # half the record's span (the curve's time scale)
    wander_s: float = 0.0  # the curve's largest departure from the line over the record
    anchor_se_s: float = 0.0  # se of the model's mean delay over the record less its start's

    @property
    def significant(self) -> bool:
        """Worth correcting: a line beyond its noise and at least ``MIN_PPM``, or a curve
        whose terms beyond the line are (each beyond ``CURVE_SIGNIFICANT`` standard errors);
        measured on at least ``MIN_SEGMENTS`` segments, and a model that explains ``MIN_R2``
        of the delays' spread (a steady or slowly changing drift, not the steps of bursts of
        late stamps, nor — cut where the motion's lines leak — their beating)."""
        line = abs(self.ppm) > SIGNIFICANT * self.se_ppm and abs(self.ppm) >= MIN_PPM
        return ((line or self.degree > 1) and self.segments >= MIN_SEGMENTS
                and self.r2 >= MIN_R2)

    @property
    def unexplained_s(self) -> float:
        """A slope beyond ``UNEXPLAINED`` standard errors that is not corrected (under
        ``SIGNIFICANT`` of them, or a model that explains too little of the delays, or too
        few segments): the delay it may leave on average over the record, ``|b|·T/2`` (s),
        for σ's interval; 0 otherwise."""
        if self.significant or not abs(self.ppm) > UNEXPLAINED * self.se_ppm:
            return 0.0
        return abs(self.drift_s) / 2.0

    @property
    def left(self) -> bool:
        """What a corrected record still shows is worth another pass: a slope beyond one
        standard error, or a curve."""
        return abs(self.ppm) > self.se_ppm or self.degree > 1

    def plus(self, rest: Skew) -> Skew:
        """This skew with ``rest`` (what a record corrected by this one still shows) added:
        ``(1 + b)(1 + b') − 1``; the standard errors are ``rest``'s (the last measurement)."""
        b = (1.0 + self.ppm * 1e-6) * (1.0 + rest.ppm * 1e-6) - 1.0
        return dataclasses.replace(
            self, ppm=b * 1e6, se_ppm=rest.se_ppm, segments=rest.segments,
            drift_s=self.drift_s + rest.drift_s, delays_s=rest.delays_s, mids_s=rest.mids_s,
            degree=max(self.degree, rest.degree), wander_s=self.wander_s + rest.wander_s,
            anchor_se_s=rest.anchor_se_s)

    @property
    def ci95_ppm(self) -> tuple[float, float]:
        return self.ppm - 1.96 * self.se_ppm, self.ppm + 1.96 * self.se_ppm


def _segments(n: int, dt: float, period_s: float | None) -> tuple[int, int, bool]:
    """(count, slots per segment, whole periods?) of the record's cut (module notes)."""
    span = n * dt
    if period_s is not None and period_s > 0:
        per = period_s / dt
        periods = int(span / period_s + 1e-9)
        if abs(per - round(per)) < 1e-6 * per and periods >= MIN_PERIODS:
            k = -(-periods // SEGMENTS_MAX)  # periods per segment
            return periods // k, round(k * per), True
    count = min(SEGMENTS_MAX, int(span // SEGMENT_MIN_S), n // SEGMENT_MIN_SAMPLES)
    return count, (n // count if count else 0), False


def estimate_skew(x: FloatArray, y: FloatArray, mask: NDArray[np.bool_], dt: float,
                  period_s: float | None = None, t0_s: float = 0.0) -> Skew | None:
    """The skew of ``y``'s instants against ``x``'s (both on one grid of step ``dt``, meaningful
    where ``mask``), or None when the record is too short to cut into three segments.
    ``period_s``: the motion's period, when known — segments of whole periods then hold its
    lines exactly (no window, no leakage). ``t0_s``: the grid's first instant on the device's
    clock (where a curve's time starts)."""
    n = len(mask)
    span = n * dt
    count, m, whole = _segments(n, dt, period_s)
    if count < 3:
        return None
    found = _delays(x, y, mask, dt, count, m, whole)
    if found is None:
        return None
    sk = _fit(*found, span, whole, t0_s)
    if sk.degree > 1 and whole and count < SEGMENTS_MAX:
        # a curve on few whole periods: the windowed segments, more of them, may follow it
        # further (a rate wandering over the record wants a degree its periods cannot hold)
        c2, m2, _ = _segments(n, dt, None)
        more = _delays(x, y, mask, dt, c2, m2, False) if c2 > count else None
        if more is not None:
            alt = _fit(*more, span, False, t0_s)
            if alt.degree > sk.degree and alt.r2 >= MIN_R2:
                return alt
    return sk


def _delays(x: FloatArray, y: FloatArray, mask: NDArray[np.bool_], dt: float, count: int,
            m: int, whole: bool) -> tuple[FloatArray, FloatArray] | None:
    """Each segment's delay (less the first's) and its mid-time (module notes, steps 1–2)."""
    xs = np.where(mask, x, 0.0)[: m * count].reshape(count, m)
    ys = np.where(mask, y, 0.0)[: m * count].reshape(count, m)
    ms = mask[: m * count].reshape(count, m)
    # each segment about its own mean (a drift or an offset is not a line of the motion)
    cnt = np.maximum(ms.sum(axis=1, keepdims=True), 1)
    xs = np.where(ms, xs - xs.sum(axis=1, keepdims=True) / cnt, 0.0)
    ys = np.where(ms, ys - ys.sum(axis=1, keepdims=True) / cnt, 0.0)
    # segments of whole periods hold the lines on their bins; otherwise a window keeps the
    # leakage between lines (which turns the phases too) small
    win = np.ones(m) if whole else np.hanning(m)
    fx = rfft(xs * win, axis=1)
    fy = rfft(ys * win, axis=1)
    px = np.sum(np.abs(fx) ** 2, axis=0)
    px[0] = 0.0
    total = float(px.sum())
    if not total > 0.0:
        return None
    order = np.argsort(px)[::-1]
    keep = order[: int(np.searchsorted(np.cumsum(px[order]), POWER_SHARE * total)) + 1]
    keep = keep[keep > 0]
    omega = 2.0 * np.pi * keep / (m * dt)
    c = fy[:, keep] * np.conj(fx[:, keep])  # (segments, bins)
    turn = c[1:] * np.conj(c[:-1])
    w = np.abs(turn)
    dphi = np.angle(turn)
    den = np.sum(w * omega**2, axis=1)
    if not np.all(den > 0.0):
        return None
    step = -np.sum(w * omega * dphi, axis=1) / den  # τ_s − τ_{s−1}
    tau = _against_mean(c, np.asarray(omega, dtype=float),
                        np.asarray(np.concatenate(([0.0], np.cumsum(step))), dtype=float))
    mids = np.asarray((np.arange(count) + 0.5) * m * dt, dtype=float)
    return tau, mids


def _design(mids: FloatArray, seg_s: float, half: float, degree: int,
            whole: bool) -> FloatArray:
    """Columns ``u^j`` (``u = (t − half)/half``, j ≤ ``degree``) averaged over each segment as
    its delay is: a segment's cross-spectrum turns with the mean delay over it, weighted by the
    product of the windows (uniform for whole periods, Hann² otherwise). The mid-point value
    is not that mean where the delay curves (by ``τ''·L²/24``: 6 ms for a rate wandering by
    200 ppm over 900 s read in 100 s segments)."""
    k = 65
    frac = (np.arange(k) + 0.5) / k
    w = np.ones(k) if whole else np.sin(np.pi * frac) ** 4
    w = w / w.sum()
    t = mids[:, None] + (frac[None, :] - 0.5) * seg_s
    u = (t - half) / half
    return np.stack([(u**j) @ w for j in range(degree + 1)], axis=1)


def _poly(tau: FloatArray, a: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    """Least squares ``τ ≈ a·c``: the coefficients, their covariance, the residual sum of
    squares."""
    coef, *_ = np.linalg.lstsq(a, tau, rcond=None)
    resid = tau - a @ coef
    rss = float(np.dot(resid, resid))
    dof = len(tau) - a.shape[1]
    cov = (rss / dof if dof > 0 else 0.0) * np.linalg.inv(a.T @ a)
    return np.asarray(coef, dtype=float), np.asarray(cov, dtype=float), rss


def _fit(tau: FloatArray, mids: FloatArray, span: float, whole: bool, t0_s: float) -> Skew:
    """The line through the delays (the skew and its standard error), and the degree of the
    curve they follow: the highest up to ``MAX_DEGREE`` whose top term is beyond
    ``CURVE_SIGNIFICANT`` standard errors and whose terms beyond the line, together, pass an
    F test at ``CURVE_P`` (``MIN_DOF`` segments left beyond its terms)."""
    count = len(tau)
    half = 0.5 * span
    seg = float(mids[1] - mids[0]) if count > 1 else span
    coef1, cov1, rss1 = _poly(tau, _design(mids, seg, half, 1, whole))
    b, se = coef1[1] / half, math.sqrt(max(cov1[1, 1], 0.0)) / half
    degree, coef, cov, rss = 1, coef1, cov1, rss1
    for d in range(2, MAX_DEGREE + 1):  # the highest whose top term is significant (a bump,
        if count - (d + 1) < MIN_DOF:  # even, has no odd term: degree 3 alone would miss it)
            break
        c, v, r = _poly(tau, _design(mids, seg, half, d, whole))
        dof = count - d - 1
        f_stat = (rss1 - r) / (d - 1) / (r / dof) if r > 0.0 else math.inf
        if (abs(c[-1]) > CURVE_SIGNIFICANT * math.sqrt(max(v[-1, -1], 0.0))
                and f_stat > float(fdtri(d - 1, dof, 1.0 - CURVE_P))):
            degree, coef, cov, rss = d, c, v, r
    spread = float(np.dot(tau - tau.mean(), tau - tau.mean()))
    r2 = 1.0 - rss / spread if spread > 0.0 else 0.0
    # the model in seconds from the record's start: τ(t) = Σ c_j ((t − half)/half)^j
    grid = np.linspace(-1.0, 1.0, 201)
    curve = np.polynomial.polynomial.polyval(grid, coef)
    line = coef1[0] + coef1[1] * grid
    wander = float(np.max(np.abs(curve - line - np.mean(curve - line)))) if degree > 1 else 0.0
    # the model's mean delay over the record less its value at the start (the anchor): a
    # correction off by this leaves an offset between the streams (timing.timing_budget)
    g = np.array([np.mean(grid**j) - (-1.0) ** j for j in range(degree + 1)])
    anchor_se = math.sqrt(max(float(g @ cov @ g), 0.0))
    return Skew(ppm=1e6 * b, se_ppm=1e6 * se, segments=count, drift_s=b * span,
                delays_s=tau, mids_s=mids, r2=r2, whole_periods=whole, degree=degree,
                coef=tuple(float(c) for c in coef), t0_s=t0_s, half_s=half, wander_s=wander,
                anchor_se_s=anchor_se)


def _against_mean(c: NDArray[np.complex128], omega: FloatArray, tau: FloatArray,
                  rounds: int = 3) -> FloatArray:
    """Each segment's delay against the record's mean cross-spectrum, starting from ``tau``
    (the consecutive turns cumulated, which never wrap): ``C̄ = Σ_s C_s e^{jωτ_s}``, then
    ``τ_s += −Σ w ω ∠(C_s e^{jωτ_s} C̄*) / Σ w ω²`` (``w = |C_s||C̄|``), ``rounds`` times.
    Cumulated turns carry each step's error into every later segment (a random walk that a
    line through them reads as a skew of a few ppm); against the mean each segment's error
    is its own."""
    for _ in range(rounds):
        rot = c * np.exp(1j * omega[None, :] * tau[:, None])
        mean = rot.sum(axis=0)
        z = rot * np.conj(mean)[None, :]
        w = np.abs(z)
        den = np.sum(w * omega**2, axis=1)
        if not np.all(den > 0.0):
            break
        tau = tau - np.sum(w * omega * np.angle(z), axis=1) / den
    return np.asarray(tau - tau[0], dtype=float)


def deskewed(t_dev: FloatArray, skew: Skew) -> FloatArray:
    """The device's instants with the skew taken out, anchored at its first instant.

    A line: the slope ``b`` is measured against the device's own instants, so
    ``t − b·(t − t₀)`` is exact (stamps ``s = t₀ + (t − t₀)(1 + ε)``: ``b = ε/(1 + ε)``). A
    curve (a rate that changes): the delay it gives at each instant on the device's clock,
    less the delay at the first, ``t − (τ(t) − τ(t₀))``."""
    if skew.degree <= 1 or not skew.coef or not skew.half_s > 0.0:
        b = skew.ppm * 1e-6
        return np.asarray(t_dev - b * (t_dev - t_dev[0]), dtype=float)
    half = skew.half_s
    u = (t_dev - skew.t0_s - half) / half
    tau = np.polynomial.polynomial.polyval(u, np.asarray(skew.coef))
    return np.asarray(t_dev - (tau - tau[0]), dtype=float)


__all__ = ["Skew", "deskewed", "estimate_skew"]
