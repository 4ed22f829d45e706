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
3. the delays ``τ_s`` (cumulated) against the segments' mid-times: a least-squares line, its
   slope the skew ``b`` (s per s) with its standard error from the line's residuals.

The skew is corrected when it is significant (``|b| > SIGNIFICANT``·its standard error), at
least ``MIN_PPM``, measured on ``MIN_SEGMENTS`` segments or more, and the line explains
``MIN_R2`` of the delays' spread — a steady drift, not the steps that bursts of late receipts
make, nor the beating of lines that leak (a 600 s record of three 200 s periods cut in 37.5 s
segments read −29 ppm of it). The device's instants then become ``t − b·(t − t₀)``, anchored
at the record's first device instant — the instrument's clock taken as right when the record
began (a logger started with the test); the delay there stays, as the instrument's own. Above
``WARN_PPM`` the result warns.

Pure computation on arrays: :func:`estimate_skew`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.fft import rfft

FloatArray = NDArray[np.float64]

SEGMENTS_MAX = 16  # segments of the record (fewer when a segment would be too short) …
SEGMENT_MIN_S = 20.0  # … at least this long …
SEGMENT_MIN_SAMPLES = 256  # … and holding this many slots
POWER_SHARE = 0.99  # the reference's strongest bins holding this share of its power
SIGNIFICANT = 4.0  # standard errors a skew must exceed to be corrected …
MIN_PPM = 5.0  # … and at least this (a smaller one moves nothing measurable)
WARN_PPM = 20.0  # a skew above this is a warning (the clocks should be fixed)
MIN_PERIODS = 4  # a known period: segments of whole periods when the record holds this many
MIN_R2 = 0.98  # the line must explain this share of the delays' spread …
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
    r2: float = 1.0  # the share of the delays' spread the line explains
    whole_periods: bool = False  # segments of whole periods of the motion

    @property
    def significant(self) -> bool:
        """Worth correcting: beyond its noise, at least ``MIN_PPM``, measured on at least
        ``MIN_SEGMENTS`` segments, and a line that explains ``MIN_R2`` of the delays' spread
        (a steady drift, not the steps of bursts of late stamps, nor — cut where the motion's
        lines leak — their beating)."""
        return (abs(self.ppm) > SIGNIFICANT * self.se_ppm and abs(self.ppm) >= MIN_PPM
                and self.segments >= MIN_SEGMENTS and self.r2 >= MIN_R2)

    def plus(self, rest: Skew) -> Skew:
        """This skew with ``rest`` (what a record corrected by this one still shows) added:
        ``(1 + b)(1 + b') − 1``; the standard error is ``rest``'s (the last measurement)."""
        b = (1.0 + self.ppm * 1e-6) * (1.0 + rest.ppm * 1e-6) - 1.0
        return Skew(ppm=b * 1e6, se_ppm=rest.se_ppm, segments=rest.segments,
                    drift_s=self.drift_s + rest.drift_s, delays_s=rest.delays_s,
                    mids_s=rest.mids_s, r2=self.r2, whole_periods=self.whole_periods)

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
                  period_s: float | None = None) -> Skew | None:
    """The skew of ``y``'s instants against ``x``'s (both on one grid of step ``dt``, meaningful
    where ``mask``), or None when the record is too short to cut into three segments.
    ``period_s``: the motion's period, when known — segments of whole periods then hold its
    lines exactly (no window, no leakage)."""
    n = len(mask)
    span = n * dt
    count, m, whole = _segments(n, dt, period_s)
    if count < 3:
        return None
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
    mc = mids - mids.mean()
    b = float(np.dot(mc, tau - tau.mean()) / np.dot(mc, mc))
    resid = tau - tau.mean() - b * mc
    dof = count - 2
    s2 = float(np.dot(resid, resid)) / dof if dof > 0 else 0.0
    se = math.sqrt(s2 / float(np.dot(mc, mc)))
    spread = float(np.dot(tau - tau.mean(), tau - tau.mean()))
    r2 = 1.0 - float(np.dot(resid, resid)) / spread if spread > 0.0 else 0.0
    return Skew(ppm=1e6 * b, se_ppm=1e6 * se, segments=count, drift_s=b * span,
                delays_s=tau, mids_s=mids, r2=r2, whole_periods=whole)


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
    """The device's instants with the skew taken out, anchored at its first instant: the
    slope ``b`` is measured against the device's own instants, so ``t − b·(t − t₀)`` is exact
    (stamps ``s = t₀ + (t − t₀)(1 + ε)``: ``b = ε/(1 + ε)``)."""
    b = skew.ppm * 1e-6
    return np.asarray(t_dev - b * (t_dev - t_dev[0]), dtype=float)


__all__ = ["Skew", "deskewed", "estimate_skew"]
