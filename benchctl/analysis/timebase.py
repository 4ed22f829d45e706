"""Time bases: when each sample was taken, on the host's monotonic clock.

A stamp taken by the host at receipt is the sample's instant plus a delay that is only ever
positive: usually small, sometimes large — a loaded or stalled host reads a burst of frames
late, all stamped late. The instants used by the analysis come from the best source a stream
has (see ``instrument_timebase``):

``device``
    the instrument's own time (NMEA 0183 ``$PASHR``) or sample counter (NMEA 2000 SID);
``adapter``
    the CAN adapter's receive timestamp of each frame (slcan ``Z1``, 1 ms, unwrapped by the
    driver into ``adapter_time_s``);
``fitted``
    the host's receipt stamps alone;
``receipt``
    the receipt stamps as they are (batches told apart, nothing fitted).

For the first three the instrument is taken to sample on its own uniform clock (as the
analysis grid assumes): each sample gets a slot ``k`` on that clock — from the counter, from
its device or adapter time, or from the receipt stamps by counting (a burst of late samples
after a silence of as many slots is a delay, not drops: a sample that would share a slot with
a later one moves back into the free slots before it) — and its instant is
``t₀ + k·Δt + w(k)``, a line and a slow wander (``robust_clock``) fitted to the receipt stamps
of the samples that arrived on time. "On time" is decided by the stamps' own scatter: a stamp
more than ``REJECT_LATE`` robust scales after the clock is late and left out of the fit
(``REJECT_EARLY`` before it: an outlier), so bursts, batches and stalls do not pull the clock.
The clock is set at the lower envelope of the receipts on time (per block their 5 %
quantile, finally their 2 % quantile):
the least latency a receipt had. What remains of the transmission latency stays part of the
instrument's measured delay, as with receipt stamps (a device clock's offset from the host
clock cannot be observed from the data).

The residual error of such instants (``Clock.error_rms``) is the uncertainty of the fitted
wander (block medians of ``WANDER_BLOCK`` samples), far below the stamps' own jitter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import median_filter, minimum_filter1d

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

REJECT_LATE = 3.5  # a stamp this many robust sd after its clock arrived late (left out)
REJECT_EARLY = 8.0  # … this many before it is an outlier (receipts are never early)
WANDER_BLOCK = 500  # samples per block of the clock's slow wander
HALF_WINDOW = 7  # at least this many samples each side of a boundary when seeking a drop
MAX_REFINE = 12  # re-slotting rounds
BURST_HORIZON_S = 4.0  # a burst of late stamps ends within this (a host stall's catch-up;
# overlapping stalls hold up to a few seconds: at 2 s a 2.9 s hold's first samples were drops)
ONE_SIDED_QUANTILE = 0.1  # first level of receipts (only ever late): their 10 % quantile
ONE_SIDED_FLOOR = 0.02  # receipts' clock: the 2 % quantile of those on time (lower envelope)
ONE_SIDED_BLOCK = 0.05  # … and each block's level: the 5 % quantile of its stamps on time
SCALE_SAMPLES = 65_536  # the robust scale of a longer record from a subsample this long
BURST_LEVEL = 1.5  # steps above the lowest level ahead: a burst, not drops

#: the time bases, best first
TIMEBASES = ("device", "adapter", "fitted", "receipt")


# ---------------------------------------------------------------------------------- labels
class Instants(np.ndarray):
    """Sample instants (s, host monotonic clock) labelled with the time base they come from.

    ``timebase`` is one of ``TIMEBASES`` (or ``"given"``); ``residual_s`` the estimated rms
    error of the instants (s); ``info`` further facts (dict). The labels survive slicing and
    boolean indexing (``t[mask]``), so a recording's ``pair`` can hand them to ``analyze``
    through any caller that crops the arrays; ``np.asarray`` drops them.
    """

    timebase: str
    residual_s: float
    info: dict[str, Any]

    def __new__(
        cls,
        t: ArrayLike,
        timebase: str,
        residual_s: float = math.nan,
        info: dict[str, Any] | None = None,
    ) -> Instants:
        obj = np.asarray(t, dtype=float).view(cls)
        obj.timebase = timebase
        obj.residual_s = float(residual_s)
        obj.info = dict(info or {})
        return obj

    def __array_finalize__(self, obj: Any) -> None:
        self.timebase = getattr(obj, "timebase", "given")
        self.residual_s = getattr(obj, "residual_s", math.nan)
        self.info = getattr(obj, "info", {})


def label_of(t: object) -> tuple[str, float, dict[str, Any]] | None:
    """(time base, residual error s, info) of labelled instants, else None."""
    if isinstance(t, Instants):
        return t.timebase, t.residual_s, t.info
    return None


# ---------------------------------------------------------------------------------- clocks
@dataclass(frozen=True)
class Clock:
    """``t ≈ t₀ + Δt·x + w(x)``: a line and a slow wander through stamps, late ones left out.

    ``knots``/``wander``: the wander at block centres (interpolated linearly, extended along
    the end segments; empty = none); ``inliers``: the stamps on time; ``jitter_rms``: their
    rms scatter about the clock (s); ``error_rms``: the estimated rms error of the clock's
    instants (s).
    """

    t0: float
    dt: float
    x0: float
    knots: FloatArray
    wander: FloatArray
    inliers: NDArray[np.bool_]
    jitter_rms: float
    error_rms: float

    def at(self, x: ArrayLike) -> FloatArray:
        """The clock's instants at ``x`` (slots or another clock's seconds)."""
        xa = np.asarray(x, dtype=float)
        out = self.t0 + self.dt * (xa - self.x0)
        if self.knots.size:
            out = out + _interp(xa, self.knots, self.wander).reshape(xa.shape)
        return np.asarray(out, dtype=float)

    @property
    def late(self) -> int:
        """Stamps left out of the fit."""
        return int((~self.inliers).sum())


def _interp(x: FloatArray, kx: FloatArray, kv: FloatArray) -> FloatArray:
    """Piecewise-linear through the knots, extended along the end segments beyond them."""
    x = np.atleast_1d(np.asarray(x, dtype=float))
    out = np.interp(x, kx, kv)
    if kx.size >= 2:
        lo, hi = x < kx[0], x > kx[-1]
        out[lo] = kv[0] + (x[lo] - kx[0]) * (kv[1] - kv[0]) / (kx[1] - kx[0])
        out[hi] = kv[-1] + (x[hi] - kx[-1]) * (kv[-1] - kv[-2]) / (kx[-1] - kx[-2])
    return np.asarray(out, dtype=float)


def _fit_line(x: FloatArray, t: FloatArray) -> tuple[float, float]:
    """Least squares ``t ≈ a + b·(x − x̄)``: (a, b)."""
    xc = x - x.mean()
    den = float(np.dot(xc, xc))
    b = float(np.dot(xc, t - t.mean()) / den) if den > 0 else 0.0
    return float(t.mean()), b


def _row_medians(a: FloatArray) -> tuple[FloatArray, NDArray[np.int64]]:
    """Median of each row's non-NaN values (NaN where none), and their count."""
    srt = np.sort(a, axis=1)  # NaN last
    cnt = np.sum(~np.isnan(a), axis=1)
    rows = np.arange(a.shape[0])
    lo = srt[rows, np.maximum(cnt - 1, 0) // 2]
    hi = srt[rows, np.maximum(cnt, 1) // 2]
    return np.where(cnt > 0, 0.5 * (lo + hi), np.nan), cnt


def _block_levels(
    x: FloatArray, r: FloatArray, keep: NDArray[np.bool_], nb: int, q: float
) -> tuple[FloatArray, FloatArray]:
    """Mean ``x`` and ``q``-quantile of the kept ``r`` of ``nb`` consecutive blocks (blocks
    with fewer than max(8, a tenth) kept samples are skipped)."""
    n = len(x)
    size = -(-n // nb)
    pad = np.full(nb * size - n, np.nan)
    rr = np.concatenate((np.where(keep, r, np.nan), pad)).reshape(nb, size)
    xx = np.concatenate((x, pad)).reshape(nb, size)
    srt = np.sort(rr, axis=1)  # NaN last
    cnt = np.sum(~np.isnan(rr), axis=1)
    pos = q * np.maximum(cnt - 1, 0)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, np.maximum(cnt - 1, 0))
    rows = np.arange(nb)
    level = srt[rows, lo] + (pos - lo) * (srt[rows, hi] - srt[rows, lo])
    good = cnt >= max(8, size // 10)
    return np.nanmean(xx[good], axis=1), level[good]


def _centre_scale(r: FloatArray, one_sided: bool, floor: float) -> tuple[float, float]:
    """Centre and scale of the stamps on time among residuals ``r``.

    Symmetric: median and 1.4826·MAD (up to half the stamps may be outliers). One-sided
    (receipts, only ever late): from the earliest 30 % — scale ``(Q₀.₃ − Q₀.₀₂)/1.53``,
    centre ``Q₀.₃ + 0.524·scale`` (a Gaussian's), so up to 70 % may arrive late.
    """
    r = r[:: max(1, len(r) // SCALE_SAMPLES)]  # a long record: a subsample
    if one_sided:
        q02, q30 = np.quantile(r, [0.02, 0.30])
        sc = max(float(q30 - q02) / 1.53, floor)
        return float(q30) + 0.524 * sc, sc
    med = float(np.median(r))
    return med, max(1.4826 * float(np.median(np.abs(r - med))), floor)


def robust_clock(
    x: ArrayLike,
    t: ArrayLike,
    *,
    one_sided: bool = False,
    block: int = WANDER_BLOCK,
    floor_s: float | None = None,
) -> Clock:
    """Fit ``t ≈ t₀ + Δt·x + w(x)`` to the stamps ``t`` taken on time.

    ``x``: slots (integers) or another clock's readings (s), increasing; ``t``: stamps (s).
    The record is cut into blocks of ``block`` samples; each block's level is a quantile of
    the residuals about the current line (first the median — or for ``one_sided`` stamps,
    receipts that are only ever late, the 10 % quantile — then the median of the stamps on
    time, or for ``one_sided`` their ``ONE_SIDED_BLOCK`` quantile, the block's lower envelope,
    which a busy host does not move); the line is fitted through the levels and the wander
    ``w`` is their residual, interpolated (a record shorter than two blocks: a least-squares
    line, no wander). "On time" is re-decided from the residuals' centre and scale
    (``_centre_scale``): more than ``REJECT_LATE`` scales after it is late, more than
    ``REJECT_EARLY`` before it an outlier.
    ``one_sided``: the clock is finally set at the lower envelope of the stamps on time (their
    ``ONE_SIDED_FLOOR`` quantile), the least latency a receipt had.
    ``floor_s`` is the smallest scale taken (default 10⁻⁶ of a step).
    """
    xa = np.asarray(x, dtype=float)
    ta = np.asarray(t, dtype=float)
    n = len(xa)
    x0 = float(xa[0]) if n else 0.0
    xr = xa - x0
    tref = float(ta[0]) if n else 0.0
    tr = ta - tref  # small numbers: the fit keeps its precision on a large monotonic clock
    inl = np.ones(n, dtype=bool)
    w = np.zeros(n)
    knots = np.empty(0)
    wv = np.empty(0)
    nb = n // block if n >= 2 * block else 0
    a0, b = _fit_line(xr, tr)
    a = a0 - b * float(xr.mean())  # t ≈ a + b·xr
    for it in range(10):
        # receipts (only ever late): each block's level is its lower envelope — the least
        # latency holds still when the host gets busy, a median of the stamps "on time" rises
        # with the load and would tilt the clock (a busy second half: a rate error of 10⁻⁴)
        q = (ONE_SIDED_QUANTILE if it == 0 else ONE_SIDED_BLOCK) if one_sided else 0.5
        resid = tr - (a + b * xr)
        kx, kl = (_block_levels(xr, resid, inl, nb, q) if nb
                  else (np.empty(0), np.empty(0)))
        if kx.size >= 2:
            c0, c1 = _fit_line(kx, kl)
            a, b = a + c0 - c1 * float(kx.mean()), b + c1
            knots, wv = kx, kl - (c0 + c1 * (kx - kx.mean()))
            w = _interp(xr, knots, wv)
        else:
            if it > 0:
                a0, b = _fit_line(xr[inl], tr[inl])
                a = a0 - b * float(xr[inl].mean())
            a += float(np.quantile((tr - (a + b * xr))[inl], q))
            knots, wv, w = np.empty(0), np.empty(0), np.zeros(n)
        r = tr - (a + b * xr) - w
        floor = floor_s if floor_s is not None else 1e-6 * abs(b) + 1e-12
        c, sc = _centre_scale(r, one_sided, floor)
        new = (r - c <= REJECT_LATE * sc) & (r - c >= -REJECT_EARLY * sc)
        if new.sum() < max(2, n // 4):  # never fewer than a quarter: keep the earliest
            new = r <= np.quantile(r, 0.25)
        if it > 0 and np.array_equal(new, inl):
            break
        inl = new
    r = tr - (a + b * xr) - w
    if one_sided and inl.any():  # receipts: the clock at their lower envelope, the earliest
        a += float(np.quantile(r[inl], ONE_SIDED_FLOOR))  # on time (their least latency)
        r = tr - (a + b * xr) - w
    jit = float(np.sqrt(np.mean((r[inl] - r[inl].mean()) ** 2))) if inl.any() else 0.0
    n_in = max(1, int(inl.sum()))
    if knots.size:
        per_block = max(1.0, n_in / knots.size)
        err = 1.2533 * jit / math.sqrt(per_block) * math.sqrt(2.0 / 3.0)
    else:
        err = jit * math.sqrt(2.0 / n_in)
    return Clock(
        t0=a + tref,
        dt=b,
        x0=x0,
        knots=knots + x0 if knots.size else knots,
        wander=wv,
        inliers=inl,
        jitter_rms=jit,
        error_rms=err,
    )


# ---------------------------------------------------------------------------------- slots
def _line(k: NDArray[np.int64], t: FloatArray) -> tuple[float, float]:
    """``t ≈ t₀ + Δt·k`` through the stamps on time: (Δt, t₀).

    Least squares, refitted without the stamps more than ``REJECT_LATE`` robust scales
    (1.4826·MAD) from it until they settle. A burst's stamps are late by up to its hold (a
    1.1 s hold of 108 samples early in a minute tilted a plain least-squares line by 9·10⁻⁴ of
    a step: 0.45 of a step over a ``WANDER_BLOCK``, beyond what the circular wander can
    unwrap, and the slots counted 33 too many).
    """
    keep = np.ones(len(k), dtype=bool)
    dt = t0 = 0.0
    for _ in range(8):
        kk, tt = k[keep], t[keep]
        kc = kk - kk.mean()
        den = float(np.dot(kc, kc))
        dt = float(np.dot(kc, tt - tt.mean()) / den) if den > 0 else 0.0
        t0 = float(tt.mean() - dt * kk.mean())
        r = t - (t0 + dt * k)
        med = float(np.median(r[keep]))
        sc = 1.4826 * float(np.median(np.abs(r[keep] - med)))
        new = np.abs(r - med) <= REJECT_LATE * max(sc, 1e-6 * abs(dt) + 1e-12)
        if new.sum() < max(2, len(k) // 2) or np.array_equal(new, keep):
            break
        keep = new
    return dt, t0


def _circular_wander(u: FloatArray, dt: float, block: int = WANDER_BLOCK) -> FloatArray:
    """Slow offset of the instants ``u`` from the grid ``k·dt``, whatever their slots.

    Circular means of the phase ``2π u/dt`` over blocks of samples (a sample in a wrong slot
    has the same phase), unwrapped across blocks and interpolated to every sample.
    """
    n = len(u)
    nb = max(1, n // block)
    z = np.exp(2j * np.pi * (u - u[0]) / dt)
    size = n // nb
    means = z[: nb * size].reshape(nb, size).mean(axis=1)
    offset = np.unwrap(np.angle(means)) * dt / (2.0 * np.pi) + u[0]
    if nb == 1:
        return np.full(n, offset[0])
    centres = np.arange(nb) * size + (size - 1) / 2.0
    return np.interp(np.arange(n), centres, offset)


def step_estimate(t: FloatArray) -> float:
    """The stream's step, robust to drops, jitter and bursts of late stamps.

    The median step over 4 samples (a scheduler that sends on 4 ms ticks makes the single steps
    bimodal), then refined over longer and longer spans (8, 64, 512, 4096 samples and a
    quarter of the record): each span's slots counted with the current step, the step the
    median of span / slots — its error shrinks with the span, so the level ``t_i − i·Δt``
    stays flat over a burst's horizon.
    """
    n = len(t)
    m0 = min(4, max(1, n // 4))
    dt = float(np.median((t[m0:] - t[:-m0]) / m0))  # spans of 4: a timer's bimodal steps average
    spans = [m for m in (8, 64, 512, 4096) if m < n // 4] + [n // 4]
    for m in spans:
        if m < 2:
            break
        span = t[m:] - t[:-m]
        cnt = np.rint(span / dt)
        ok = cnt >= 1
        if not ok.any():
            break
        dt = float(np.median(span[ok] / cnt[ok]))
    return dt


def _first_steps(t: FloatArray, dt0: float) -> NDArray[np.int64]:
    """Slots advanced between consecutive samples: 1, plus the drops found between them.

    A drop shifts every later sample by ``dt₀``: it is found as a jump of the level of
    ``t_i − i·dt₀`` — its median over ``h`` samples (jitter does not move it), replaced by the
    lowest such median within ``BURST_HORIZON_S`` ahead where it stands more than
    ``BURST_LEVEL`` steps above it (a burst of late receipts raises the level only until it
    is read, a drop for good) — placed at the boundary where that jump is largest.
    """
    n = len(t)
    d = np.diff(t)
    jitter = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / np.sqrt(2.0)
    h = int(np.clip(np.ceil((14.2 * jitter / dt0) ** 2), HALF_WINDOW, 101)) | 1
    if n < 4 * h:
        return np.maximum(1, np.rint(d / dt0)).astype(np.int64)
    med = median_filter(t - dt0 * np.arange(n), size=h, mode="nearest")  # centred, width h
    # a burst of late stamps raises the level only until it is read, a drop for good: where
    # the level stands well above the lowest level ahead, that lowest level is the clock's
    ahead = int(max(4 * h, min(n, round(BURST_HORIZON_S / dt0))))
    env = minimum_filter1d(med, size=ahead, origin=-(ahead // 2), mode="nearest")
    med = np.where(med - env > BURST_LEVEL * dt0, env, med)
    c = h // 2
    b = np.arange(1, n)  # boundary between samples b−1 and b
    jump = (med[np.clip(b + c, 0, n - 1)] - med[np.clip(b - 1 - c, 0, n - 1)]) / dt0
    steps = np.ones(n - 1, dtype=np.int64)
    cand = jump >= 0.5
    if cand.any():
        edges = np.flatnonzero(np.diff(np.concatenate(([0], cand.view(np.int8), [0]))))
        for a, e in zip(edges[::2], edges[1::2], strict=True):
            # boundaries a … e−1 (boundary j between samples j and j+1): the level change
            # across the whole run counts the drops; they sit at its largest raw steps
            # (the lowest levels ahead: a burst that falls back is no drop)
            total = (env[min(e + c, n - 1)] - env[max(a - c, 0)]) / dt0
            m = round(total)
            if m < 1:
                continue  # a burst of late samples that returned to the level: no drop
            order = a + np.argsort(d[a:e])[::-1]
            q, r = divmod(m, len(order))  # m drops over the run's largest steps, in turn
            steps[order] += q
            steps[order[:r]] += 1
    return steps


def _increasing(k: NDArray[np.int64]) -> NDArray[np.int64]:
    """Strictly increasing slots: a sample that shares a slot with a later one moves back into
    the free slots before it (a burst of late receipts), never pushes later ones on."""
    idx = np.arange(len(k))
    out = idx + np.minimum.accumulate((k - idx)[::-1])[::-1]
    return np.asarray(out - out[0], dtype=np.int64)


def first_slots(t: FloatArray) -> NDArray[np.int64]:
    """A first slot assignment of the stamps ``t`` (drops counted, jitter and bursts ignored):
    median-level drops, then the circular-phase grid and wander until it settles."""
    k = np.concatenate(([0], np.cumsum(_first_steps(t, step_estimate(t)))))
    for _ in range(5):
        dt, t0 = _line(k, t)
        wander = _circular_wander(t - t0, dt)
        k_new = _increasing(np.rint((t - t0 - wander) / dt).astype(np.int64))
        if np.array_equal(k_new, k):
            break
        k = k_new
    return k


def refine_slots(
    t: FloatArray, k: NDArray[np.int64], *, one_sided: bool = False
) -> tuple[NDArray[np.int64], Clock]:
    """Slots re-decided against the robust clock of the stamps on time, until they settle.

    Each sample moves to the slot nearest its stamp on that clock; a late one (a burst) that
    would share a slot with a later sample moves back into the free slots before it.
    """
    clk = robust_clock(k, t, one_sided=one_sided)
    for _ in range(MAX_REFINE):
        k_new = _increasing(k + np.rint((t - clk.at(k)) / clk.dt).astype(np.int64))
        if np.array_equal(k_new, k):
            break
        k = k_new
        clk = robust_clock(k, t, one_sided=one_sided)
    return k, clk


def fit_slots(t: ArrayLike, *, one_sided: bool = False) -> tuple[NDArray[np.int64], Clock]:
    """Slots and the robust clock of stamps ``t`` (finite, increasing) of a stream sampled on
    a uniform clock: jitter, bursts of late stamps and a slowly wandering clock do not move
    samples to other slots; a lasting jump of about one step is a dropped sample.
    ``one_sided``: the stamps are receipts, only ever late (see ``robust_clock``)."""
    ta = np.asarray(t, dtype=float)
    if _uniform(ta):  # a grid already (a CSV's times, a fitted clock): one slot per stamp
        k = np.arange(len(ta), dtype=np.int64)
        clk = robust_clock(k, ta, one_sided=one_sided)
        if np.array_equal(_increasing(k + np.rint((ta - clk.at(k)) / clk.dt).astype(np.int64)),
                          k):
            return k, clk
    return refine_slots(ta, first_slots(ta), one_sided=one_sided)


UNIFORM_TOL = 1e-4  # stamps whose steps all lie within this share of their mean step: a grid


def _uniform(t: FloatArray) -> bool:
    """The stamps step evenly (within ``UNIFORM_TOL`` of a step): no drop, burst or jitter to
    find — the slots are the stamps' own order (what :func:`first_slots` and
    :func:`refine_slots` would find, without their passes over the record)."""
    if len(t) < 3:
        return False
    d = np.diff(t)
    mean = (t[-1] - t[0]) / (len(t) - 1)
    return bool(mean > 0 and np.max(np.abs(d - mean)) <= UNIFORM_TOL * mean)


# ---------------------------------------------------------------------------------- device clocks
#: one-sided unwrapping (``unwrap``): how far, in periods, the host's elapsed time may fall
#: short of the true one (receipt jitter); it may exceed it by up to 1 − this (a host stall)
EARLY_WRAP_SLACK = 0.25


def unwrap(values: ArrayLike, period: float, t_host: ArrayLike, scale: float = 1.0,
           *, one_sided: bool = False) -> FloatArray:
    """A wrapping clock or counter made continuous, counting the wraps by the host's clock.

    ``values`` wrap at ``period`` (e.g. 60 000 ms, 253 SIDs, 86 400 s); one unit is ``scale``
    host seconds (for a counter: its sample period). Between consecutive samples the number of
    wraps is the one that brings the elapsed value nearest to the elapsed host time, so gaps
    and host stalls shorter than half a period are counted right.

    ``one_sided``: ``t_host`` are receipt stamps, which a stalled host makes late by the
    stall's length but never early by more than their jitter: the wraps are then the most
    that do not put the elapsed value beyond the elapsed host time by more than
    ``EARLY_WRAP_SLACK`` of a period, so stalls up to three quarters of a period are counted
    right (a 100 Hz NMEA 2000 SID: 1.9 s, not 1.26 s).
    """
    v = np.asarray(values, dtype=float)
    h = np.asarray(t_host, dtype=float)
    if v.size < 2:
        return v.copy()
    dv = np.diff(v)
    dh = np.diff(h) / scale
    if one_sided:
        wraps = np.floor((dh - dv) / period + EARLY_WRAP_SLACK)
    else:
        wraps = np.rint((dh - dv) / period)
    return np.concatenate(([v[0]], v[0] + np.cumsum(dv + wraps * period)))


@dataclass(frozen=True)
class TimeBase:
    """A stream's instants on the host clock and how they were found."""

    t: FloatArray
    kind: str
    residual_s: float
    jitter_s: float  # rms jitter of the receipt stamps on time about the clock
    late: int  # receipt stamps left out of the fit (bursts, batches)
    slots: NDArray[np.int64] | None = None
    dt: float = math.nan

    def instants(self) -> Instants:
        return Instants(self.t, self.kind, self.residual_s,
                        {"late": self.late, "receipt_jitter_s": self.jitter_s, "dt": self.dt})


def clock_timebase(t_receipt: ArrayLike, kind: str, slots: ArrayLike | None = None) -> TimeBase:
    """Instants on the robust clock of the receipt stamps, at ``slots`` (from a counter or a
    device/adapter clock) or at slots counted from the stamps themselves."""
    tr = np.asarray(t_receipt, dtype=float)
    if slots is None:
        k, clk = fit_slots(tr, one_sided=True)
    else:
        k = np.asarray(slots, dtype=np.int64)
        k = k - k[0]
        clk = robust_clock(k, tr, one_sided=True)
    return TimeBase(clk.at(k), kind, clk.error_rms, clk.jitter_rms, clk.late, k, clk.dt)


def clock_slots(c: ArrayLike) -> NDArray[np.int64]:
    """Slots of samples from their own clock's readings ``c`` (s; device or adapter time)."""
    return fit_slots(np.asarray(c, dtype=float))[0]


def counter_slots(counter: ArrayLike, period: int, t_receipt: ArrayLike,
                  adapter_time: ArrayLike | None = None) -> NDArray[np.int64]:
    """Slots from a sample counter wrapping at ``period`` (NMEA 2000 SID: 253). Its wraps are
    counted by the CAN adapter's timestamps where every sample has one (taken as the frames
    arrive: a host stall does not delay them), else by the receipt stamps, one-sided (see
    ``unwrap``); the step between samples is the median of those one count apart."""
    c = np.asarray(counter, dtype=float)
    av = adapter_clock(adapter_time)
    if av is not None and av.shape == c.shape:
        witness, one_sided = av, False
    else:
        witness, one_sided = np.asarray(t_receipt, dtype=float), True
    dc = np.mod(np.diff(c), period)
    one = dc == 1
    dh = np.diff(witness)
    step = float(np.median(dh[one])) if one.any() else float(np.median(dh / np.maximum(dc, 1)))
    k = unwrap(c, period, witness, scale=step, one_sided=one_sided)
    return np.asarray(np.rint(k - k[0]), dtype=np.int64)


def adapter_clock(adapter_time: ArrayLike | None) -> FloatArray | None:
    """The CAN adapter's timestamps as a clock, or None when a sample lacks one or they run
    backwards or stand still throughout (at 1 ms they may repeat from frame to frame)."""
    if adapter_time is None:
        return None
    av = np.asarray(adapter_time, dtype=float)
    if av.size < 2 or not np.isfinite(av).all() or np.any(np.diff(av) < 0) or av[-1] <= av[0]:
        return None
    return av


def valid_clock(c: FloatArray | None) -> bool:
    """True when ``c`` (a device or adapter time column) is there for every sample and
    strictly increasing (a clock to count slots with)."""
    if c is None or c.size < 2 or not np.isfinite(c).all():
        return False
    return bool(np.all(np.diff(c) > 0))


# ---------------------------------------------------------------------------------- reference
STAND_WINDOW_QUANTILE = 0.01  # the stand clock's offset: between the 99 % quantile of the
# windows' earliest ends and the 1 % quantile of their latest (a few glitches do not move it)


def stand_clock(
    t_stand: ArrayLike, wrap_s: float, t_lo: ArrayLike, t_hi: ArrayLike, anchor: str = "window"
) -> tuple[FloatArray, float, dict[str, Any]]:
    """Host instants of the stand's samples from the stand's own clock.

    ``t_stand``: the stand's clock when it took each state (s, wrapping every ``wrap_s``);
    ``[t_lo, t_hi]``: the host times it can have been taken between (each exchange's window).
    The stand's clock runs at its own rate and offset. Its wraps are counted, and its rate
    found (the least-squares line of the windows' centres against the unwrapped clock), on the
    *narrow* windows only (up to twice the median width and under half a wrap): their centres
    are within a few milliseconds of the states, so a gap of any length between them is counted
    right. Every other sample gets the wrap that puts it inside its own window; a window so
    wide (a host stalled mid-exchange for about a wrap or more) that more than one wrap fits,
    or none does, cannot date its sample: that sample is left out (NaN in the instants,
    ``info["dropped"]``) — a gap the analysis handles, never a sample a wrap off its time.
    The offset is set where every window allows it: midway between the latest of the windows'
    earliest ends and the earliest of their latest ends (their 99 % and 1 % quantiles) — the
    fastest exchanges bound it, so a busy host or a slow turnaround does not move it;
    ``anchor="earliest"`` sets it at the earliest end instead (RTU: a stand answers with the
    state it has as the request is complete). Returns (instants, residual rms error, info):
    the error is that of a uniform offset within the interval the windows leave (its
    width/√12), plus the rate's.
    """
    lo = np.asarray(t_lo, dtype=float)
    hi = np.asarray(t_hi, dtype=float)
    raw = np.asarray(t_stand, dtype=float)
    mid = 0.5 * (lo + hi)
    width = hi - lo
    # a stalled exchange's centre says little: neither its wraps nor the rate come from it
    tight = (width <= 2.0 * float(np.median(width))) & (width < 0.5 * wrap_s)
    if int(tight.sum()) < 2:
        tight = np.ones(len(raw), dtype=bool)
    c_t = unwrap(raw[tight], wrap_s, mid[tight])
    c0 = float(c_t[0])
    a0, b = _fit_line(c_t - c0, mid[tight] - float(mid[tight][0]))
    a_ls = a0 - b * float((c_t - c0).mean()) + float(mid[tight][0])
    # every sample's wrap: the one that puts its instant nearest its window's centre, kept when
    # that instant is inside the window (with the fit's own scatter as margin) and no other
    # wrap's is
    scatter = float(np.std(mid[tight] - (a_ls + b * (c_t - c0))))
    margin = max(4.0 * scatter, 1e-3)
    base = raw - c0
    n_wrap = np.rint(((mid - a_ls) / b - base) / wrap_s) if b > 0 else np.zeros(len(raw))
    x = base + n_wrap * wrap_s
    pred = a_ls + b * x
    step = b * wrap_s
    fits = (pred >= lo - margin) & (pred <= hi + margin)
    other = ((pred - step >= lo - margin) | (pred + step <= hi + margin))
    keep = tight | (fits & ~other)
    q = STAND_WINDOW_QUANTILE
    low = float(np.quantile((lo - (a_ls + b * x))[keep], 1.0 - q))
    high = float(np.quantile((hi - (a_ls + b * x))[keep], q))
    consistent = low <= high
    off = (0.5 * (low + high) if anchor == "window" else low) if consistent else 0.0
    t = np.where(keep, a_ls + off + b * x, np.nan)
    room = max(high - low, 0.0)
    n = int(tight.sum())
    rate_err = scatter * math.sqrt(2.0 / n) if n > 2 else 0.0  # the fitted line's own error
    err = math.hypot(room / math.sqrt(12.0), rate_err) if consistent else scatter
    info = {"rate": b, "offset_interval_s": room, "consistent": consistent,
            "dropped": int((~keep).sum())}
    return t, err, info


def stamp_error(rtt: ArrayLike, stamp: str = "midpoint") -> float:
    """Estimated rms error of stand stamps (s) from the round trips ``rtt`` of the samples
    kept: half the rms variation of the round trip about its median (``midpoint``: the stand
    may have taken its state anywhere in the variable part of the exchange, on either leg), or
    a tenth of it (``request_end``: stamped from the send time and the request's byte time,
    only the send's own scheduling remains). NaN without round trips."""
    r = np.asarray(rtt, dtype=float)
    r = r[np.isfinite(r)]
    if r.size == 0:
        return math.nan
    rms = float(np.sqrt(np.mean((r - np.median(r)) ** 2)))
    return 0.5 * rms if stamp == "midpoint" else 0.1 * rms


# ---------------------------------------------------------------------------------- streams
#: protocols whose samples carry the device's own clock: device_time_s (s, wrapping at the
#: period given) or a counter (wrapping at the period given); CANopen CiA 410 carries neither,
#: J1939 PGN 61459's latency byte is a delay (its device_time_s is receipt minus latency, on
#: the host's clock), not a clock
DEVICE_CLOCKS: dict[str, tuple[str, float]] = {
    "nmea0183": ("time", 86_400.0),  # $PASHR UTC time of day (a leap second reads 86 400)
    "nmea2000": ("counter", 253.0),  # PGN 127257 SID 0…252
}
# a device or adapter clock is not used when more than this share of the receipts came before
# the instants it gives (by more than EARLY_MARGIN_S + 8 × the receipts' jitter): a receipt
# can be late by any amount on a busy host, never early — early ones are a clock that is not
# the samples' own (slots counted wrong, a time that is not the sampling instant)
MAX_EARLY = 0.01
EARLY_MARGIN_S = 1e-3


def _receipt(t: FloatArray) -> TimeBase:
    k, clk = fit_slots(t, one_sided=True)
    r = t - clk.at(k)
    jit = float(np.sqrt(np.mean((r - r.mean()) ** 2)))
    return TimeBase(t, "receipt", jit, clk.jitter_rms, clk.late, k, clk.dt)


def instrument_timebase(
    t_receipt: ArrayLike,
    *,
    device_time: ArrayLike | None = None,
    counter: ArrayLike | None = None,
    adapter_time: ArrayLike | None = None,
    driver: str | None = None,
    prefer: str = "best",
) -> TimeBase:
    """The instants of an instrument's samples from the best time base they have.

    ``t_receipt``: receipt stamps (host monotonic s, strictly increasing: batches told apart);
    ``device_time``/``counter``: the protocol's own time or counter (NaN where absent; used
    for the drivers in ``DEVICE_CLOCKS``); ``adapter_time``: the CAN adapter's timestamps (s,
    unwrapped; NaN where absent). ``prefer``: ``best`` (device, adapter, fitted, in that order:
    the first the samples all have and that no more than ``MAX_EARLY`` of the receipts
    precede),
    or one of ``TIMEBASES`` (``ValueError`` if the samples do not have it).
    """
    tr = np.asarray(t_receipt, dtype=float)
    if prefer not in ("best", *TIMEBASES):
        raise ValueError(f"time base {prefer!r}: expected best or one of {', '.join(TIMEBASES)}")
    if prefer == "receipt":
        return _receipt(tr)

    def slots_from(kind: str) -> NDArray[np.int64] | None:
        if kind == "device":
            what, period = DEVICE_CLOCKS.get(driver or "", ("", 0.0))
            if what == "time" and device_time is not None:
                dv = np.asarray(device_time, dtype=float)
                if np.isfinite(dv).all():
                    c = unwrap(dv, period, tr)
                    return clock_slots(c) if valid_clock(c) else None
            if what == "counter" and counter is not None:
                cv = np.asarray(counter, dtype=float)
                if np.isfinite(cv).all():
                    return counter_slots(cv, int(period), tr, adapter_time)
            return None
        if kind == "adapter":
            av = adapter_clock(adapter_time)
            return None if av is None else clock_slots(av)
        return None

    order = ("device", "adapter", "fitted") if prefer == "best" else (prefer,)
    for kind in order:
        if kind == "fitted":
            return clock_timebase(tr, "fitted")
        k = slots_from(kind)
        if k is None or np.any(np.diff(k) <= 0):
            if prefer != "best":
                raise ValueError(f"the samples have no usable {kind} time base")
            continue
        tb = clock_timebase(tr, kind, k)
        early = tr - tb.t < -(EARLY_MARGIN_S + 8.0 * tb.jitter_s)
        if np.mean(early) <= MAX_EARLY or prefer != "best":
            return tb
    return clock_timebase(tr, "fitted")  # not reached
