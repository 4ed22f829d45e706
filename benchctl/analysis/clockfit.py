"""A uniform clock through a stream's stamps: each sample's slot ``k`` on the clock, and the
clock ``t₀ + k·Δt + w(k)`` (a line and a slow wander) fitted robustly to the stamps on time.

Slots (:func:`fit_slots`) are counted from the stamps: a burst of late samples after a silence
of as many slots is a delay, not drops (a sample that would share a slot with a later one moves
back into the free slots before it); stamps that step evenly are a grid, their own order.
The clock (:func:`robust_clock`) is a line and a slow wander through the stamps of the
samples that arrived on time. "On time" is decided by the stamps' own scatter: a stamp more
than ``REJECT_LATE`` robust scales after the clock is late and left out of the fit
(``REJECT_EARLY`` before it: an outlier), so bursts, batches and stalls do not pull the clock.
For receipts (only ever late, ``one_sided``) the clock is set at the lower envelope of the
receipts on time (per block their 5 % quantile, finally their 2 % quantile): the least latency
a receipt had.

The residual error of such instants (``Clock.error_rms``) is the uncertainty of the fitted
wander (block medians of ``WANDER_BLOCK`` samples), far below the stamps' own jitter. The
time bases that use it: :mod:`benchctl.analysis.timebase`; the analysis grid:
:mod:`benchctl.analysis.align`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from benchctl.analysis.sums import dot

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
        out = np.subtract(xa, self.x0)  # t0 + dt·(x − x0) + w(x), in one array
        out *= self.dt
        out += self.t0
        if self.knots.size:
            out += _interp(xa, self.knots, self.wander).reshape(xa.shape)
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


def fit_line(x: FloatArray, t: FloatArray) -> tuple[float, float]:
    """Least squares ``t ≈ a + b·(x − x̄)``: (a, b)."""
    xc = x - x.mean()
    # np.dot, not sums.dot: the clock of stamps on a grid is this fit to their last bits,
    # and their scatter about it (rounding, 1e-14 s) is reported as it always was
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


def _block_means(x: FloatArray, nb: int) -> FloatArray:
    """Mean ``x`` of each of ``nb`` consecutive blocks (the last ones short, or empty: NaN)."""
    n = len(x)
    size = -(-n // nb)
    held = -(-n // size)  # the blocks that hold a sample
    out = np.full(nb, np.nan)
    if held * size == n and not np.isnan(x).any():  # whole blocks (no copy): their means
        out[:held] = x.reshape(held, size).sum(axis=1) / size
        return out
    out[:held] = np.nanmean(np.concatenate((x, np.full(held * size - n, np.nan)))
                            .reshape(held, size), axis=1)
    return out


def _block_levels(
    x: FloatArray, r: FloatArray, keep: NDArray[np.bool_], nb: int, q: float,
    x_means: FloatArray | None = None, *, own: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """Mean ``x`` and ``q``-quantile of the kept ``r`` of ``nb`` consecutive blocks (blocks
    with fewer than max(8, a tenth) kept samples are skipped). ``x_means``: the blocks' mean
    ``x`` (:func:`_block_means`), if made already (the clock's passes share them). ``own``:
    ``r`` may be reordered in place (the caller's scratch)."""
    n = len(x)
    size = -(-n // nb)
    if own and nb * size == n and bool(keep.all()):  # every sample kept, whole blocks: no copy
        rr = r.reshape(nb, size)
        cnt = size - np.count_nonzero(np.isnan(rr), axis=1)
    else:
        flat = np.full(nb * size, np.nan)
        np.copyto(flat[:n], r, where=keep)
        rr = flat.reshape(nb, size)
        cnt = np.sum(~np.isnan(rr), axis=1)
    pos = q * np.maximum(cnt - 1, 0)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, np.maximum(cnt - 1, 0))
    level = np.empty(nb)
    # a block whose samples are all kept (most): its two order statistics by a partition, the
    # same values a sort puts there (a sort of every block cost a long record ≈ 50 ms a pass)
    full = cnt == size
    if full.all():  # every block: partitioned in place, no copy of them
        level = _interpolated(rr, pos, lo, hi, whole=True, own=True)
    else:
        for rows in (full, ~full):
            if rows.any():
                level[rows] = _interpolated(rr[rows], pos[rows], lo[rows], hi[rows],
                                            whole=rows is full, own=True)
    good = cnt >= max(8, size // 10)
    if x_means is None:
        x_means = _block_means(x, nb)
    return x_means[good], level[good]


def _interpolated(b: FloatArray, pos: FloatArray, lo: NDArray[np.int64], hi: NDArray[np.int64],
                  *, whole: bool, own: bool = False) -> FloatArray:
    """Each row's order statistics ``lo`` and ``hi`` (NaN last), interpolated at ``pos``.
    ``whole``: no row holds a NaN, and every row has the same ``lo`` and ``hi`` (a partition
    puts them in place; otherwise a sort). ``own``: ``b`` may be reordered in place."""
    if whole and own:
        b.partition(sorted({int(lo[0]), int(hi[0])}), axis=1)
    else:
        b = (np.partition(b, sorted({int(lo[0]), int(hi[0])}), axis=1) if whole
             else np.sort(b, axis=1))
    i = np.arange(b.shape[0])
    return np.asarray(b[i, lo] + (pos - lo) * (b[i, hi] - b[i, lo]), dtype=np.float64)


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
    owned = xa is not x and xa.base is None  # converted here (slots): made relative in place
    xr = np.subtract(xa, x0, out=xa if owned else None)
    del xa
    tref = float(ta[0]) if n else 0.0
    tr = ta - tref  # small numbers: the fit keeps its precision on a large monotonic clock
    inl = np.ones(n, dtype=bool)
    w = np.zeros(n)
    knots = np.empty(0)
    wv = np.empty(0)
    nb = n // block if n >= 2 * block else 0
    x_means = _block_means(xr, nb) if nb else None  # the same blocks in every pass
    a0, b = fit_line(xr, tr)
    a = a0 - b * float(xr.mean())  # t ≈ a + b·xr
    r = np.empty(n)  # each pass's residuals (the last pass's are kept) …
    scratch = np.empty(n)  # … and the levels' and the rejection's, in place
    new = np.empty(n, dtype=bool)
    early = np.empty(n, dtype=bool)

    def line_residual(out: FloatArray) -> FloatArray:
        """``tr − (a + b·xr)`` into ``out``."""
        np.multiply(xr, b, out=out)
        out += a
        return np.subtract(tr, out, out=out)

    for it in range(10):
        # receipts (only ever late): each block's level is its lower envelope — the least
        # latency holds still when the host gets busy, a median of the stamps "on time" rises
        # with the load and would tilt the clock (a busy second half: a rate error of 10⁻⁴)
        q = (ONE_SIDED_QUANTILE if it == 0 else ONE_SIDED_BLOCK) if one_sided else 0.5
        kx, kl = (_block_levels(xr, line_residual(scratch), inl, nb, q, x_means, own=True)
                  if nb else (np.empty(0), np.empty(0)))
        if kx.size >= 2:
            c0, c1 = fit_line(kx, kl)
            a, b = a + c0 - c1 * float(kx.mean()), b + c1
            knots, wv = kx, kl - (c0 + c1 * (kx - kx.mean()))
            w = _interp(xr, knots, wv)
        else:
            if it > 0:
                a0, b = fit_line(xr[inl], tr[inl])
                a = a0 - b * float(xr[inl].mean())
            a += float(np.quantile((tr - (a + b * xr))[inl], q))
            knots, wv, w = np.empty(0), np.empty(0), np.zeros(n)
        line_residual(r)
        r -= w
        floor = floor_s if floor_s is not None else 1e-6 * abs(b) + 1e-12
        c, sc = _centre_scale(r, one_sided, floor)
        rc = np.subtract(r, c, out=scratch)
        np.less_equal(rc, REJECT_LATE * sc, out=new)
        new &= np.greater_equal(rc, -REJECT_EARLY * sc, out=early)
        del rc
        if np.count_nonzero(new) < max(2, n // 4):  # never fewer than a quarter: keep the
            np.less_equal(r, np.quantile(r, 0.25), out=new)  # earliest
        if it > 0 and np.array_equal(new, inl):
            break
        inl, new = new, inl
    # r: the last pass's residuals, of the a, b and w the loop ends with
    if one_sided and inl.any():  # receipts: the clock at their lower envelope, the earliest
        a += float(np.quantile(r[inl], ONE_SIDED_FLOOR))  # on time (their least latency)
        line_residual(r)
        r -= w
    r_in = r if inl.all() else r[inl]
    if r_in.size:
        dev = np.subtract(r_in, r_in.mean(), out=scratch[: r_in.size])
        jit = float(np.sqrt(np.mean(np.square(dev, out=dev))))
    else:
        jit = 0.0
    del r_in
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
        den = dot(kc, kc)
        dt = dot(kc, tt - tt.mean()) / den if den > 0 else 0.0
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
    # imported here: scipy.ndimage costs 0.1–0.2 s, and stamps on a grid (a CSV's times, a
    # fitted clock) never come here
    from scipy.ndimage import median_filter, minimum_filter1d

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
    k, clk, _ = _slots(np.asarray(t, dtype=float), one_sided)
    return k, clk


def fit_slots_scatter(t: FloatArray) -> tuple[NDArray[np.int64], Clock, FloatArray]:
    """:func:`fit_slots` and the stamps' scatter about their clock, ``t − clock(k)`` (s)."""
    k, clk, scatter = _slots(t, False)
    return k, clk, (t - clk.at(k) if scatter is None else scatter)


def _slots(ta: FloatArray, one_sided: bool
           ) -> tuple[NDArray[np.int64], Clock, FloatArray | None]:
    """:func:`fit_slots`, with the scatter when it was made on the way (stamps on a grid)."""
    if _uniform(ta):  # a grid already (a CSV's times, a fitted clock): one slot per stamp
        k = np.arange(len(ta), dtype=np.int64)
        clk = robust_clock(k, ta, one_sided=one_sided)
        scatter = clk.at(k)
        np.subtract(ta, scatter, out=scatter)
        moves = np.rint(scatter / clk.dt)  # the slots nearest the stamps, relative to k
        # none moves (the usual grid): k as it is, strictly increasing
        if not moves.any() or np.array_equal(_increasing(k + moves.astype(np.int64)), k):
            return k, clk, scatter
    k, clk = refine_slots(ta, first_slots(ta), one_sided=one_sided)
    return k, clk, None


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
