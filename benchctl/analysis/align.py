"""Put the two streams on the instrument's own sample instants, and find the gaps.

What is done, in order:

1. Both time series are checked: finite, strictly increasing (no duplicates), enough samples.
2. Each device sample gets a slot ``k`` on a uniform grid. First guess from the median step
   ``dt₀``: ``k_i = k_{i−1} + 1 + drops``, where a drop is a lasting jump of
   ``t_i − i·dt₀``: the medians over ``h`` samples after and before a boundary differ by
   about ``dt₀`` (``h`` ≥ 7, larger for larger jitter; jitter and short bursts of late
   receipts do not move a median). Then, until it settles: fit ``t_i ≈ t₀ + k_i·dt`` by
   least squares, take the slow wander of the instants about that grid (circular means of
   their phase over blocks of 500 samples, so that samples in wrong slots do not bias it,
   unwrapped and interpolated), and re-slot every sample by
   ``k_i = round((t_i − t₀ − wander_i)/dt)``, kept strictly increasing by moving samples
   that collide back into the free slots before them. So jitter about the device's clock
   (and bursts of late receipts) does not move samples to other slots or fake drops, and a
   clock off its nominal rate, or slowly wandering, is followed.
3. The reference is evaluated at each device instant (minus any compensated delay) by a cubic
   interpolating spline through the reference samples (``scipy.interpolate.make_interp_spline``,
   k = 3): the reference is smooth and oversampled, its interpolation error is negligible.
   The device's output is never interpolated: the error ``ε_i = y_i − x(t_i)`` is formed at
   the device's own instants.
4. Device samples outside the span of the reference, or inside a long gap of the reference
   (a step longer than 4.5× its median step), are excluded. Shorter reference gaps (up to
   three missing samples, e.g. a slipped Modbus cycle) are bridged by the spline: for a
   motion below 1 Hz sampled at 100 Hz its error across 40 ms is below 10⁻⁴ of the
   amplitude. All reference gaps are reported.
5. Slots without a sample (dropped device samples, excluded ones) are masked; the correlation
   estimator uses only the pairs that exist (see ``correlation``), so gaps bias nothing and the
   variance stays that of the analysed samples.

With ``timebase="fitted"`` the device instants are replaced by the fitted grid instants
``t₀ + k_i·dt`` (for an instrument that samples on its own clock but whose samples carry
jittery receipt times); the default ``"given"`` takes the given times as the sample instants.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import median_filter

from benchctl.errors import DataError

FloatArray = NDArray[np.float64]

BRIDGE_STEPS = 4.5  # a reference gap up to 4 median steps long (3 missing samples) is bridged
HALF_WINDOW = 7  # at least this many samples each side of a boundary when seeking a drop
MIN_SAMPLES = 64
# Input ranges (README, "Inputs and alignment"): beyond them a stream is refused, not analysed
MAX_GRID_FACTOR = 100  # a stream's grid (span / median step): at most 100× its samples …
MAX_GRID_SLOTS = 10_000_000  # … and at most 10 million slots
MIN_STEP_S = 1e-6  # median step at least 1 µs …
MAX_STEP_S = 1e6  # … and at most 10⁶ s
MAX_ABS_TIME_S = 1e12  # |time| at most 10¹² s
MAX_ABS_ANGLE_DEG = 1e6  # |angle| at most 10⁶ deg


@dataclass(frozen=True)
class StreamTiming:
    """Timing of one stream: nominal step (s), rms jitter about its grid (s), gaps."""

    dt: float
    jitter_rms: float
    gap_count: int
    missing_samples: int
    longest_gap_s: float


@dataclass(frozen=True)
class Aligned:
    """Both streams on the device's grid.

    ``x``, ``y``: reference and device (deg) per slot, meaningful where ``mask``; ``t``: the
    instants used (s; NaN in empty slots); ``dt``: grid step (s); ``excluded``: device samples
    dropped for lack of reference; ``shift``: the delay subtracted from the device instants
    before the reference was evaluated (s).
    """

    t: FloatArray
    x: FloatArray
    y: FloatArray
    mask: NDArray[np.bool_]
    dt: float
    device: StreamTiming
    reference: StreamTiming
    excluded: int
    shift: float

    @property
    def n_valid(self) -> int:
        return int(self.mask.sum())


def check_times(t: FloatArray, name: str) -> None:
    """Raise ``DataError`` unless ``t`` is finite and strictly increasing."""
    if len(t) < MIN_SAMPLES:
        raise DataError(f"{name}: {len(t)} samples, at least {MIN_SAMPLES} are needed")
    bad = ~np.isfinite(t)
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(f"{name}: time at sample {i} is {t[i]}, expected a finite number")
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0)) + 1
        what = "duplicate" if d[i - 1] == 0 else "decreasing"
        raise DataError(
            f"{name}: {what} timestamp at sample {i}: {t[i]!r} after {t[i - 1]!r}; "
            "times must be strictly increasing"
        )


def check_grid(t: FloatArray, name: str, where: Callable[[int], str] | None = None) -> None:
    """Raise ``DataError`` unless the instants ``t`` (finite, increasing) are within the input
    ranges: ``|t| ≤ MAX_ABS_TIME_S``, a median step within ``MIN_STEP_S … MAX_STEP_S``, and a
    grid (span / median step) of at most ``MAX_GRID_FACTOR`` × the samples and
    ``MAX_GRID_SLOTS`` slots (a wild time or a huge gap would make an astronomically long
    grid). ``where(i)`` names sample ``i`` in messages (default ``sample i``)."""
    at = where or (lambda i: f"sample {i}")
    big = np.abs(t) > MAX_ABS_TIME_S
    if big.any():
        i = int(np.argmax(big))
        raise DataError(
            f"{name}: {at(i)}: time {float(t[i])!r}; expected |time| ≤ {MAX_ABS_TIME_S:g} s"
        )
    d = np.diff(t)
    step = float(np.median(d))
    if not MIN_STEP_S <= step <= MAX_STEP_S:
        raise DataError(
            f"{name}: median time step {step!r} s; expected {MIN_STEP_S:g} … {MAX_STEP_S:g} s"
        )
    slots = float(t[-1] - t[0]) / step + 1.0
    limit = min(MAX_GRID_FACTOR * len(t), MAX_GRID_SLOTS)
    if slots > limit:
        i = int(np.argmax(d)) + 1
        raise DataError(
            f"{name}: {at(i)}: time {float(t[i])!r} after {float(t[i - 1])!r}, a gap of "
            f"{d[i - 1] / step:.4g} "
            f"median steps ({step:.6g} s): the record would span {slots:.4g} steps for "
            f"{len(t)} samples; expected at most {limit} ({MAX_GRID_FACTOR}× the samples, "
            f"never more than {MAX_GRID_SLOTS})"
        )


def check_values(v: FloatArray, name: str) -> None:
    """Raise ``DataError`` on NaN/inf, ``|angle| > MAX_ABS_ANGLE_DEG`` or a constant signal."""
    bad = ~np.isfinite(v) | (np.abs(v) > MAX_ABS_ANGLE_DEG)
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(
            f"{name}: value at sample {i} is {v[i]}, expected a finite angle, "
            f"|angle| ≤ {MAX_ABS_ANGLE_DEG:g} deg"
        )
    if float(np.ptp(v)) == 0.0:
        raise DataError(f"{name}: the signal is constant ({v[0]!r} deg); nothing to analyse")


def _line(k: NDArray[np.int64], t: FloatArray) -> tuple[float, float]:
    kc = k - k.mean()
    dt = float(np.dot(kc, t - t.mean()) / np.dot(kc, kc))
    return dt, float(t.mean() - dt * k.mean())


def _wander(u: FloatArray, dt: float, block: int = 500) -> FloatArray:
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


def _first_steps(t: FloatArray, dt0: float) -> NDArray[np.int64]:
    """Slots advanced between consecutive samples: 1, plus the drops found between them.

    A drop shifts every later sample by ``dt₀``: it is found as a jump between the median of
    ``t_i − i·dt₀`` over the ``h`` samples after and the ``h`` samples before a boundary (a
    burst of late receipts, fewer than ``h/2`` samples, does not move a median), placed at
    the boundary where that jump is largest.
    """
    n = len(t)
    d = np.diff(t)
    jitter = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / np.sqrt(2.0)
    h = int(np.clip(np.ceil((14.2 * jitter / dt0) ** 2), HALF_WINDOW, 101)) | 1
    if n < 4 * h:
        return np.maximum(1, np.rint(d / dt0)).astype(np.int64)
    med = median_filter(t - dt0 * np.arange(n), size=h, mode="nearest")  # centred, width h
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
            total = (med[min(e + c, n - 1)] - med[max(a - c, 0)]) / dt0
            m = max(1, round(total))
            order = a + np.argsort(d[a:e])[::-1]
            q, r = divmod(m, len(order))  # m drops over the run's largest steps, in turn
            steps[order] += q
            steps[order[:r]] += 1
    return steps


def slot_indices(t: FloatArray) -> tuple[NDArray[np.int64], float, float]:
    """Grid slots of the instants ``t``, with the fitted step and origin (see module notes)."""
    dt0 = float(np.median(np.diff(t)))
    idx = np.arange(len(t))
    k = np.concatenate(([0], np.cumsum(_first_steps(t, dt0))))
    for _ in range(5):
        dt, t0 = _line(k, t)
        wander = _wander(t - t0, dt)
        k_new = np.rint((t - t0 - wander) / dt).astype(np.int64)
        # strictly increasing: a sample that shares a slot with a later one moves back into
        # the free slots before it (a burst of late receipts), never pushes later ones on
        k_new = idx + np.minimum.accumulate((k_new - idx)[::-1])[::-1]
        k_new -= k_new[0]
        if np.array_equal(k_new, k):
            break
        k = k_new
    dt, t0 = _line(k, t)
    return k, dt, t0


def _timing(t: FloatArray, k: NDArray[np.int64], dt: float, t0: float) -> StreamTiming:
    steps = np.diff(k)
    gaps = steps > 1
    jitter = t - (t0 + k * dt)
    return StreamTiming(
        dt=dt,
        jitter_rms=float(np.sqrt(np.mean((jitter - jitter.mean()) ** 2))),
        gap_count=int(gaps.sum()),
        missing_samples=int((steps[gaps] - 1).sum()),
        longest_gap_s=float(np.max(np.diff(t)[gaps])) if gaps.any() else 0.0,
    )


def align(
    t_ref: FloatArray,
    x_ref: FloatArray,
    t_dev: FloatArray,
    y_dev: FloatArray,
    *,
    shift_s: float = 0.0,
    timebase: Literal["given", "fitted"] = "given",
) -> Aligned:
    """Evaluate the reference at the device's instants and lay both on the device's grid.

    Parameters
    ----------
    t_ref, x_ref : ndarray
        Reference (stand) instants, s, and angles, deg.
    t_dev, y_dev : ndarray
        Device instants, s, and angles, deg.
    shift_s : float
        Delay to compensate, s: the reference is evaluated at ``t_dev − shift_s``.
    timebase : {"given", "fitted"}
        Use the given device instants, or the least-squares grid fitted through them.

    Returns
    -------
    Aligned
    """
    for t, v, name in ((t_ref, x_ref, "reference"), (t_dev, y_dev, "device")):
        if len(t) != len(v):
            raise DataError(f"{name}: {len(t)} times but {len(v)} angles")
        check_times(t, f"{name} time")
        check_grid(t, f"{name} time")
        check_values(v, f"{name} angle")
    k, dt, t0 = slot_indices(t_dev)
    dev_timing = _timing(t_dev, k, dt, t0)
    kr, dtr, t0r = slot_indices(t_ref)
    ref_timing = _timing(t_ref, kr, dtr, t0r)
    t_use = t0 + k * dt if timebase == "fitted" else t_dev
    same = shift_s == 0.0 and len(t_ref) == len(t_dev) and np.array_equal(t_ref, t_use)
    t_eval = t_use - shift_s
    ok = (t_eval >= t_ref[0]) & (t_eval <= t_ref[-1])
    if not ok.any():
        raise DataError(
            f"the streams do not overlap in time: reference {t_ref[0]:.6g} … {t_ref[-1]:.6g} s, "
            f"device {t_dev[0]:.6g} … {t_dev[-1]:.6g} s"
            + (f" (shifted by {shift_s:.6g} s)" if shift_s else "")
        )
    d_ref = np.diff(t_ref)
    gap_ref = d_ref > BRIDGE_STEPS * float(np.median(d_ref))
    if gap_ref.any():
        seg = np.clip(np.searchsorted(t_ref, t_eval, side="right") - 1, 0, len(d_ref) - 1)
        ok &= ~(gap_ref[seg] & (t_eval > t_ref[seg]) & (t_eval < t_ref[seg + 1]))
    if same:
        x_at = np.asarray(x_ref, dtype=float)
    else:
        from scipy.interpolate import make_interp_spline  # slow import, needed only here

        spline = make_interp_spline(t_ref, x_ref, k=3)
        x_at = np.full(len(t_eval), np.nan)
        x_at[ok] = spline(t_eval[ok])
    first, last = int(np.argmax(ok)), len(ok) - int(np.argmax(ok[::-1])) - 1
    k_rel = k[first : last + 1] - k[first]
    n = int(k_rel[-1]) + 1
    sel = ok[first : last + 1]
    mask = np.zeros(n, dtype=bool)
    mask[k_rel[sel]] = True
    x = np.zeros(n)
    y = np.zeros(n)
    t = np.full(n, np.nan)
    x[k_rel[sel]] = x_at[first : last + 1][sel]
    y[k_rel[sel]] = y_dev[first : last + 1][sel]
    t[k_rel[sel]] = t_use[first : last + 1][sel]
    return Aligned(
        t=t,
        x=x,
        y=y,
        mask=mask,
        dt=dt,
        device=dev_timing,
        reference=ref_timing,
        excluded=int(len(ok) - sel.sum()),
        shift=shift_s,
    )
