"""Put the two streams on the instrument's own sample instants, and find the gaps.

What is done, in order:

1. Both time series are checked: finite, strictly increasing (no duplicates), enough samples,
   within the input ranges (``ranges``).
2. Each device sample gets a slot ``k`` on a uniform grid (``clockfit.fit_slots``). First
   guess from the median step ``dt₀``: ``k_i = k_{i−1} + 1 + drops``, where a drop is a
   lasting jump of the level of ``t_i − i·dt₀`` (its median over ``h`` ≥ 7 samples, larger
   for larger jitter, then the lowest such median within 4 s ahead: a burst of late receipts
   raises the level only until it is read, a drop for good). Then the circular-phase grid
   (phase means over blocks of 500 samples, so samples in wrong slots do not bias it), and
   finally, until it settles, the robust clock of the stamps on time (``robust_clock``: a
   line and a slow wander fitted to the stamps, late ones left out) with every sample
   re-slotted to the slot nearest its stamp on it, kept strictly increasing by moving
   samples that collide back into the free slots before them. So jitter about the device's
   clock and bursts of late receipts (a stalled host reading k samples late after a silence
   of k slots) do not move samples to other slots or fake drops, and a clock off its nominal
   rate, or slowly wandering, is followed.
3. The reference is evaluated at each device instant (minus any compensated delay) by a cubic
   interpolating spline through the reference samples (``scipy.interpolate.make_interp_spline``,
   k = 3): the reference is smooth and oversampled, its interpolation error is negligible.
   The device's output is never interpolated: the error ``ε_i = y_i − x(t_i)`` is formed at
   the device's own instants.
4. Device samples outside the span of the reference (by more than ``EDGE_STEPS`` of its
   median step: a corrected clock can move the last stamp a hair past it, and the spline's
   end extends that far exactly enough), or inside a long gap of the reference
   (a step longer than 4.5× its median step), are excluded. Shorter reference gaps (up to
   three missing samples, e.g. a slipped Modbus cycle) are bridged by the spline: for a
   motion below 1 Hz sampled at 100 Hz its error across 40 ms is below 10⁻⁴ of the
   amplitude. All reference gaps are reported.
5. Slots without a sample (dropped device samples, excluded ones) are masked; the correlation
   estimator uses only the pairs that exist (see ``correlation``), so gaps bias nothing and the
   variance stays that of the analysed samples.

With ``timebase="fitted"`` the device instants are replaced by the instants of the robust
clock at their slots, ``t₀ + k_i·dt + w(k_i)`` (for an instrument that samples on its own
clock but whose samples carry jittery receipt times); ``"given"`` takes the given times as the
sample instants; the default ``"auto"`` lays the record on the stamps, measures which share
``β`` of each stream's scatter about its clock is the stamps' own error
(``timing.stamp_shares``: the error formed at the stamps follows ``ẋ·scatter`` with slope β) and
takes the fitted clock when ``β ≥ 0.5``, the stamps otherwise. Stamps used as given count
``β`` of their scatter as their residual error (all of it when it cannot be measured).
``reference_timebase`` does the same for the reference (a stream sampled on a uniform clock
whose stamps jitter). Instants labelled by their time base
(``timebase.Instants``, as a recording's ``pair`` gives them) are used as given and carry their
own label and residual error.

Timing contribution: an error ``δ`` in an instant adds ``ẋ·δ`` to ε, so the instants' residual
errors add about ``σ_ẋ²·(δ_dev² + δ_ref²)`` to the variance (``Aligned.timing_variance``), with
``σ_ẋ`` the rms rate of the reference at the device instants and ``δ`` the rms residual of each
time base: for given stamps their rms jitter about their robust clock (all of it counted: the
analysis cannot tell a stamp's error from a sample taken off the grid), for fitted ones the
clock's own error, for labelled ones their label's.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis.clockfit import WANDER_BLOCK, Clock, fit_slots, fit_slots_scatter
from benchctl.analysis.ranges import check_grid, check_times, check_values
from benchctl.analysis.sums import dot
from benchctl.analysis.timing import AUTO_SHARE, NOT_MEASURED, StampShare, stamp_shares
from benchctl.errors import DataError

FloatArray = NDArray[np.float64]

#: a device instant this share of the reference's median step beyond its first or last
#: sample is still read (the spline's end, extended): a skew correction of a few tenths of a
#: millisecond must not cost a record its last sample and with it its whole periods
EDGE_STEPS = 0.01
BRIDGE_STEPS = 4.5  # a reference gap up to 4 median steps long (3 missing samples) is bridged
BRIDGE_MAX_S = 2.0  # a longer one up to this long is bridged when the motion is smooth enough:
BRIDGE_TOL = 1e-2  # … the spline's rms error across such a gap, tried where the reference is
BRIDGE_TRIALS = 24  # whole (this many places), is below this × the reference's rms
BRIDGE_SIDE = 8  # samples each side of a trial gap for its local spline
SMOOTH_SCATTER = 0.5  # lag-1 correlation of a scatter above which it is a wander, not jitter
GRID_SCATTER = 1e-6  # stamps within this share of a step of their clock: a grid, no test
Mode = Literal["auto", "given", "fitted"]
MODES = ("auto", "given", "fitted")
#: time bases whose error is a random scatter per sample (not an offset of the record)
RANDOM_STAMPS = ("given", "receipt", "midpoint", "request_end")
FITTED_CLOCKS = ("fitted", "device", "adapter")  # clocks fitted through stamps (wander blocks)


@dataclass(frozen=True)
class StreamTiming:
    """Timing of one stream: nominal step (s), rms jitter about its grid (s), gaps, and the
    stamps left out of its clock's fit as late (bursts)."""

    dt: float
    jitter_rms: float
    gap_count: int
    missing_samples: int
    longest_gap_s: float
    late: int = 0


@dataclass(frozen=True)
class Aligned:
    """Both streams on the device's grid.

    ``x``, ``y``: reference and device (deg) per slot, meaningful where ``mask``; ``t``: the
    instants used (s; NaN in empty slots); ``dt``: grid step (s); ``excluded``: device samples
    dropped for lack of reference; ``shift``: the delay subtracted from the device instants
    before the reference was evaluated (s). ``device_timebase``/``reference_timebase``: where
    the instants come from; ``*_residual_s``: their estimated rms error (s); ``rate_rms``: the
    reference's rms rate at the device instants (deg/s).
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
    device_timebase: str = "given"
    reference_timebase: str = "given"
    device_residual_s: float = 0.0
    reference_residual_s: float = 0.0
    rate_rms: float = 0.0
    bridged: int = 0
    bridge_variance: float = 0.0
    xdot: FloatArray | None = None  # the reference's rate at the device instants (deg/s)
    modes: tuple[Mode, Mode] = ("given", "given")  # the modes used (device, reference)
    choice: dict[str, Any] | None = None  # how they were chosen (``align``)
    # a bench timing calibration applied to the device's instants: its standard uncertainty
    # (s; None: none applied), and the share of the reference's residual error that is the
    # stand clock's anchor in the exchanges' windows (s; what the calibration measured too)
    calibration_u_s: float | None = None
    anchor_u_s: float = 0.0

    @property
    def n_valid(self) -> int:
        return int(self.mask.sum())

    @property
    def timing_variance(self) -> float:
        """Estimated variance the instants' residual errors add to ε, σ_ẋ²·(δ_dev² + δ_ref²),
        plus that of the reference bridged across longer gaps (``bridge_variance``)."""
        d = np.nan_to_num(self.device_residual_s)
        r = np.nan_to_num(self.reference_residual_s)
        return float(self.rate_rms**2 * (d**2 + r**2) + self.bridge_variance)

    def rate(self) -> FloatArray:
        """The reference's rate at every slot (deg/s): the spline's where the reference was
        interpolated, else differences on the grid (``_rate``)."""
        return self.xdot if self.xdot is not None else _rate(self.x, self.mask, self.dt)

    @property
    def offset_u_s(self) -> float:
        """Standard uncertainty (s) of an offset common to the record between the streams'
        instants, from the residual error of each time base that is a clock: a clock fitted
        through stamps (fitted, device, adapter) errs independently from block to block of
        ``WANDER_BLOCK`` samples (at its knots by √(3/2) × its rms error, which is averaged
        along the interpolation), so over the record by that / √(blocks); another
        (the stand's) by its error. Stamps used as they are scatter at random: their error is
        in ``timing_variance`` and ``random_residual_s``, not an offset.

        A bench timing calibration applied (``calibration_u_s``) adds its own uncertainty, and
        takes the place of the stand clock's anchor (``anchor_u_s``: where in the exchanges'
        windows the stand took its samples): the calibration measured the delay between the
        streams as this bench dates them, that anchor included; the stand clock's rate error
        stays."""
        span = len(self.mask) * self.dt
        parts = []
        if self.calibration_u_s is not None:
            parts.append(self.calibration_u_s)
        for base, r, step in ((self.device_timebase, self.device_residual_s, self.dt),
                              (self.reference_timebase, self.reference_residual_s,
                               self.reference.dt)):
            if base in RANDOM_STAMPS:
                continue
            r = float(np.nan_to_num(r))
            if base == "stand" and self.calibration_u_s is not None:
                r = math.sqrt(max(r * r - self.anchor_u_s**2, 0.0))
            if base in FITTED_CLOCKS and step > 0:  # its knots err by √(3/2) of its rms error
                r *= math.sqrt(1.5 / max(1.0, span / step / WANDER_BLOCK))
            parts.append(r)
        return math.hypot(*parts) if parts else 0.0

    @property
    def random_residual_s(self) -> float:
        """rms error (s) of the instants that scatter at random (stamps used as they are)."""
        parts = [float(np.nan_to_num(r)) for base, r in (
            (self.device_timebase, self.device_residual_s),
            (self.reference_timebase, self.reference_residual_s)) if base in RANDOM_STAMPS]
        return math.hypot(*parts) if parts else 0.0

    def timing_warning(self, variance: float, cross: float = 0.0,
                       offset_s: float | None = None) -> str:
        """The warning when timing moves σ's interval noticeably: the variance the instants'
        residual errors add, and (``cross``, deg²) the standard uncertainty of σ² from an
        offset of ``offset_s`` (default ``offset_u_s``) between the streams
        (``timing.timing_budget``)."""
        offset = self.offset_u_s if offset_s is None else offset_s
        text = (
            f"timing: the instants' residual errors (device {1e3 * self.device_residual_s:.3g} "
            f"ms {self.device_timebase}, reference {1e3 * self.reference_residual_s:.3g} ms "
            f"{self.reference_timebase}) at an rms rate of {self.rate_rms:.3g}°/s"
        )
        if self.bridged:
            text += f" and {self.bridged} samples on a reference bridged across its gaps"
        share = (f"about {100 * self.timing_variance / variance:.3g} % to σ²" if variance > 0
                 else f"{self.timing_variance:.3g} deg² to a σ² of 0")
        text += f" add {share} (σ_ẋ²·jitter²)"
        if cross > 0.0 and variance > 0:
            text += (f"; an offset of ±{1e3 * offset:.3g} ms between the streams moves "
                     f"σ² by ±{100 * cross / variance:.3g} % (2·|cov(ε, ẋ)|·offset: first-order "
                     "for a lagging instrument)")
        text += "; σ's interval includes them"
        given = [name for name, base, entry in (
            ("--timebase", self.device_timebase, "device"),
            ("--reference-timebase", self.reference_timebase, "reference"))
            if base == "given" and (self.choice or {}).get(entry, {}).get("stamp_share") is not None
            and (self.choice or {})[entry]["stamp_share"] >= AUTO_SHARE]
        if given:
            text += (": the stamps jitter about a uniform clock, a fitted time base would take "
                     "it out (" + ", ".join(f"{o} fitted" for o in given) + ")")
        return text

    def timing_fields(self) -> dict[str, Any]:
        """The time bases and the timing contribution, for the result's ``timing``."""
        return {
            "device_timebase": self.device_timebase,
            "reference_timebase": self.reference_timebase,
            "device_time_residual_s": self.device_residual_s,
            "reference_time_residual_s": self.reference_residual_s,
            "device_late_stamps": self.device.late,
            "reference_bridged_samples": self.bridged,
            "bridge_variance": self.bridge_variance,
            "reference_rate_rms": self.rate_rms,
            "timing_variance": self.timing_variance,
            "timebase_choice": self.choice,
        }


def slot_indices(t: FloatArray) -> tuple[NDArray[np.int64], float, float]:
    """Grid slots of the instants ``t``, with the fitted step and origin (see module notes)."""
    k, clk = fit_slots(t)
    return k, clk.dt, float(clk.at(0.0))


def _timing(t: FloatArray, k: NDArray[np.int64], clk: Clock,
            jitter: FloatArray | None = None) -> StreamTiming:
    """The stream's timing; ``jitter``: ``t − clk.at(k)``, if made already."""
    steps = np.diff(k)
    gaps = steps > 1
    if jitter is None:
        jitter = t - clk.at(k)
    return StreamTiming(
        dt=clk.dt,
        jitter_rms=float(np.sqrt(np.mean((jitter - jitter.mean()) ** 2))),
        gap_count=int(gaps.sum()),
        missing_samples=int((steps[gaps] - 1).sum()),
        longest_gap_s=float(np.max(np.diff(t)[gaps])) if gaps.any() else 0.0,
        late=clk.late,
    )


def _bridgeable(
    t: FloatArray, x: FloatArray, d: FloatArray, gap: NDArray[np.bool_]
) -> FloatArray:
    """The spline's rms error across each reference gap it may bridge (NaN: not bridged).

    Gaps (``gap``: steps ``d`` over ``BRIDGE_STEPS`` median steps) up to ``BRIDGE_MAX_S`` are
    tried: a cubic spline through the ``BRIDGE_SIDE`` samples present each side of the same
    span left out at ``BRIDGE_TRIALS`` places over the record (at least half of them with a
    sample inside); bridged when the rms of its misses there is below ``BRIDGE_TOL`` of the
    reference's rms (a host stall leaves such gaps in a slow motion polled fast), with that
    rms as its error."""
    from scipy.interpolate import make_interp_spline  # about 0.5 s to import: a spline only

    out = np.full(len(d), np.nan)
    tol = BRIDGE_TOL * float(np.std(x))
    n = len(t)
    if n < 2 * BRIDGE_SIDE + 2:
        return out
    side = BRIDGE_SIDE
    for j in np.flatnonzero(gap & (d <= BRIDGE_MAX_S)):
        if j < side or j + 1 + side > n:
            continue
        # trial spans as long as this gap, left out where the samples are: the spline through
        # the BRIDGE_SIDE samples present each side against the samples present inside (a
        # reference with other gaps of its own — scattered replies left out — is tried too)
        lo, hi = float(t[side]), float(t[n - 1 - side]) - float(d[j])
        if hi <= lo:
            continue
        sq = []
        for ts in np.linspace(lo, hi, BRIDGE_TRIALS):
            a = int(np.searchsorted(t, ts, side="right"))
            b = int(np.searchsorted(t, ts + float(d[j]), side="left"))
            if b - a < 1 or a < side or b + side > n:
                continue
            outer = np.r_[a - side : a, b : b + side]
            e = make_interp_spline(t[outer], x[outer], k=3)(t[a:b]) - x[a:b]
            sq.append(float(np.mean(e**2)))
        if len(sq) < BRIDGE_TRIALS // 2:
            continue
        rms = float(np.sqrt(np.mean(sq)))
        if rms <= tol:
            out[j] = rms
    return out


def _rate(x: FloatArray, mask: NDArray[np.bool_], dt: float) -> FloatArray:
    """The reference's rate (deg/s) in each valid slot from its neighbours: central
    differences where both are there, one-sided where one is, 0 where none."""
    if bool(mask.all()):  # no gap: numpy's own (one array, not five)
        return np.asarray(np.gradient(x, dt), dtype=float)
    d = np.diff(x) / dt
    d[~(mask[1:] & mask[:-1])] = np.nan
    back = np.concatenate(([np.nan], d))
    fwd = np.concatenate((d, [np.nan]))
    with np.errstate(invalid="ignore"):
        out = np.where(np.isnan(back), fwd, np.where(np.isnan(fwd), back, 0.5 * (back + fwd)))
    return np.nan_to_num(out, copy=False)


def _rate_rms(x: FloatArray, mask: NDArray[np.bool_], dt: float) -> float:
    """rms rate of the reference (deg/s) from differences over consecutive valid slots."""
    pair = mask[1:] & mask[:-1]
    if not pair.any():
        return 0.0
    v = np.diff(x)
    if not pair.all():
        v = v[pair]
    v /= dt
    v -= v.mean()  # in place: the same numbers as (v − v̄)², without two more arrays
    return float(np.sqrt(np.mean(np.square(v, out=v))))


Label = tuple[str, float, dict[str, Any]] | None


@dataclass(frozen=True)
class _Stream:
    """One stream's stamps, slots, fitted clock and timing."""

    t: FloatArray
    k: NDArray[np.int64]
    clk: Clock
    timing: StreamTiming
    label: Label

    @classmethod
    def of(cls, t: FloatArray, label: Label) -> _Stream:
        k, clk, scatter = fit_slots_scatter(t)
        return cls(t, k, clk, _timing(t, k, clk, scatter), label)

    @property
    def scatter(self) -> FloatArray:
        """The stamps' scatter about their fitted clock, s."""
        return np.asarray(self.t - self.clk.at(self.k), dtype=float)

    def testable(self, mode: str) -> bool:
        """Unlabelled stamps used (or maybe used) as given that scatter about their clock by
        more than ``GRID_SCATTER`` of a step (a grid written with its rounding is a grid), and
        at random: a scatter that follows itself from sample to sample (lag-1 correlation over
        ``SMOOTH_SCATTER``) is a clock's slow wander the fitted clock follows anyway — a
        skewed clock's curve, say —, not jitter to test."""
        return (self.label is None and mode != "fitted"
                and self.timing.jitter_rms > GRID_SCATTER * self.timing.dt
                and self.random_scatter)

    @functools.cached_property
    def random_scatter(self) -> bool:
        """The scatter's lag-1 correlation is under ``SMOOTH_SCATTER``."""
        d = self.scatter - float(np.mean(self.scatter))
        den = dot(d, d)
        return den > 0.0 and dot(d[1:], d[:-1]) / den < SMOOTH_SCATTER

    def instants(self, mode: str, share: StampShare) -> tuple[FloatArray, StreamTiming, str,
                                                                 float]:
        """(instants used, timing, time base, residual error) in ``mode`` (given or fitted).
        Stamps used as given: their residual error is the share ``β`` of their scatter that
        the data show to be the stamps' own (all of it when not measured)."""
        if mode == "fitted":
            return self.clk.at(self.k), self.timing, "fitted", self.clk.error_rms
        if self.label is not None:  # its own fit's late stamps, not those of a re-fit
            late = self.label[2].get("late")
            timing = self.timing
            if isinstance(late, int):
                timing = dataclasses.replace(timing, late=late)
            return self.t, timing, self.label[0], self.label[1]
        res = self.timing.jitter_rms
        if share.measured:
            res *= math.sqrt(min(max(share.beta, 0.0), 1.0))
        return self.t, self.timing, "given", res


def _calibration_u(label: Label) -> float | None:
    """The standard uncertainty (s) of a bench timing calibration applied to instants
    labelled ``label`` (the recording's ``info["timing_offset_u_s"]``), None when none was."""
    if label is None or "timing_offset_s" not in label[2]:
        return None
    u = label[2].get("timing_offset_u_s", 0.0)
    return float(u) if isinstance(u, (int, float)) and math.isfinite(u) and u >= 0 else 0.0


def _anchor_u(label: Label) -> float:
    """The share (s) of a stand clock's residual error that is its anchor in the exchanges'
    windows: a uniform offset in the interval they leave (``timebase.stand_clock``)."""
    room = label[2].get("offset_interval_s", 0.0) if label is not None else 0.0
    return float(room) / math.sqrt(12.0) if isinstance(room, (int, float)) else 0.0


def _check_mode(mode: str, name: str) -> None:
    if mode not in MODES:
        raise DataError(f"{name}: expected one of {', '.join(MODES)}, got {mode!r}")


def align(
    t_ref: FloatArray,
    x_ref: FloatArray,
    t_dev: FloatArray,
    y_dev: FloatArray,
    *,
    shift_s: float = 0.0,
    timebase: Mode = "auto",
    reference_timebase: Mode = "auto",
    labels: tuple[Label, Label] = (None, None),
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
    timebase, reference_timebase : {"auto", "given", "fitted"}
        Use the given device (reference) instants, those of the robust clock fitted through
        them, or (``auto``) the one the data call for: the fitted clock when the stamps'
        scatter about it is mostly the stamps' own error (``timing.stamp_shares``).
    labels : (label, label)
        ``timebase.label_of`` of the reference's and the device's instants as the caller
        had them (a recording's time bases), else None.

    Returns
    -------
    Aligned
    """
    _check_mode(timebase, "timebase")
    _check_mode(reference_timebase, "reference timebase")
    one_column = len(t_ref) == len(t_dev) and np.array_equal(t_ref, t_dev)  # one CSV's rows
    for t, v, name in ((t_ref, x_ref, "reference"), (t_dev, y_dev, "device")):
        if len(t) != len(v):
            raise DataError(f"{name}: {len(t)} times but {len(v)} angles")
        if not (one_column and name == "device"):  # one column of times is checked once
            check_times(t, f"{name} time")
            check_grid(t, f"{name} time")
        check_values(v, f"{name} angle")
    dev = _Stream.of(np.asarray(t_dev, dtype=float), labels[1])
    # one column of times with one label: one clock fitted through it serves both streams
    ref = (dev if one_column and labels[0] == labels[1]
           else _Stream.of(np.asarray(t_ref, dtype=float), labels[0]))
    modes: list[Mode] = ["given" if m == "auto" else m for m in (timebase, reference_timebase)]
    shares = (NOT_MEASURED, NOT_MEASURED)
    if not one_column and (dev.testable(timebase) or ref.testable(reference_timebase)):
        first = _lay(ref, x_ref, dev, y_dev, shift_s, modes, shares)
        shares = _stamp_test(first, ref, dev, (dev.testable(timebase),
                                               ref.testable(reference_timebase)))
        for i, (mode, stream) in enumerate(((timebase, dev), (reference_timebase, ref))):
            if mode == "auto" and stream.testable(mode) and shares[i].measured:
                modes[i] = "fitted" if shares[i].beta >= AUTO_SHARE else "given"
    out = _lay(ref, x_ref, dev, y_dev, shift_s, modes, shares)
    choice = {
        "device": {"asked": timebase, "used": modes[0], **shares[0].to_dict()},
        "reference": {"asked": reference_timebase, "used": modes[1], **shares[1].to_dict()},
    }
    return dataclasses.replace(out, modes=(modes[0], modes[1]), choice=choice)


def _stamp_test(al: Aligned, ref: _Stream, dev: _Stream, on_stamps: tuple[bool, bool]
                ) -> tuple[StampShare, StampShare]:
    """``β`` of the device's and the reference's scatter, from the record laid on their stamps
    (``timing.stamp_shares``); a stream not on its stamps (``on_stamps``) is not tested."""
    from scipy.interpolate import make_interp_spline  # about 0.5 s to import: a spline only

    m = al.mask
    ts = al.t[m]
    zero = np.zeros(len(ts))
    d_dev = zero
    if on_stamps[0]:  # the slots' instants are the device's own stamps, in order
        i = np.clip(np.searchsorted(dev.t, ts), 0, len(dev.t) - 1)
        d_dev = np.where(dev.t[i] == ts, dev.scatter[i], 0.0)
    d_ref = make_interp_spline(ref.t, ref.scatter, k=3)(ts - al.shift) if on_stamps[1] else zero
    eps = (al.y - al.x)[m]
    return stamp_shares(eps, al.x[m], al.rate()[m], d_dev, d_ref)


def _lay(
    ref: _Stream,
    x_ref: FloatArray,
    dev: _Stream,
    y_dev: FloatArray,
    shift_s: float,
    modes: Sequence[str],
    shares: tuple[StampShare, StampShare],
) -> Aligned:
    """Both streams on the device's grid, each on the instants of its mode."""
    t_use, dev_timing, dev_base, dev_res = dev.instants(modes[0], shares[0])
    t_ref, ref_timing, ref_base, ref_res = ref.instants(modes[1], shares[1])
    k, t_dev = dev.k, dev.t
    same = shift_s == 0.0 and len(t_ref) == len(t_dev) and np.array_equal(t_ref, t_use)
    t_eval = t_use - shift_s
    d_ref = np.diff(t_ref)
    step = float(np.median(d_ref))
    edge = EDGE_STEPS * step  # the spline's ends reach a hair further
    ok = (t_eval >= t_ref[0] - edge) & (t_eval <= t_ref[-1] + edge)
    if not ok.any():
        raise DataError(
            f"the streams do not overlap in time: reference {t_ref[0]:.6g} … {t_ref[-1]:.6g} s, "
            f"device {t_dev[0]:.6g} … {t_dev[-1]:.6g} s"
            + (f" (shifted by {shift_s:.6g} s)" if shift_s else "")
        )
    gap_ref = d_ref > BRIDGE_STEPS * step
    bridge_sq = None  # the spline's estimated squared error across bridged gaps (deg²)
    if gap_ref.any():  # each instant's reference step (a search of every instant: 0.1 s)
        seg = np.clip(np.searchsorted(t_ref, t_eval, side="right") - 1, 0, len(d_ref) - 1)
        inside = (t_eval > t_ref[seg]) & (t_eval < t_ref[seg + 1])
        bridge_sq = np.zeros(len(t_eval))
        bridge_err = _bridgeable(t_ref, x_ref, d_ref, gap_ref)
        bridged = gap_ref & np.isfinite(bridge_err)
        gap_ref &= ~bridged
        in_bridge = bridged[seg] & inside
        bridge_sq[in_bridge] = bridge_err[seg[in_bridge]] ** 2
        ok &= ~(gap_ref[seg] & inside)
    rate_at = None
    if same:
        x_at = np.asarray(x_ref, dtype=float)
    else:
        from scipy.interpolate import make_interp_spline  # slow import, needed only here

        spline = make_interp_spline(t_ref, x_ref, k=3)
        x_at = np.full(len(t_eval), np.nan)
        x_at[ok] = spline(t_eval[ok])
        rate_at = np.zeros(len(t_eval))
        rate_at[ok] = spline.derivative()(t_eval[ok])
    first, last = int(np.argmax(ok)), len(ok) - int(np.argmax(ok[::-1])) - 1
    k_rel = k[first : last + 1] - k[first]
    n = int(k_rel[-1]) + 1
    sel = ok[first : last + 1]
    whole = bool(sel.all())  # every sample between the first and the last is read (most)
    rows: slice | NDArray[np.bool_] = slice(None) if whole else sel
    if whole and n == len(k_rel):  # … and no slot is empty: the grid is the samples in order
        slots: slice | NDArray[np.int64] = slice(None)
        mask = np.ones(n, dtype=bool)
    else:
        slots = k_rel[rows]
        mask = np.zeros(n, dtype=bool)
        mask[slots] = True

    def laid(v: FloatArray, fill: float = 0.0) -> FloatArray:
        if isinstance(slots, slice):
            return np.array(v[first : last + 1], dtype=float)
        out = np.full(n, fill)
        out[slots] = v[first : last + 1][rows]
        return out

    x = laid(x_at)
    y = laid(y_dev)
    t = laid(t_use, np.nan)
    # one time column: the rate from the grid when asked (Aligned.rate)
    xdot = None if rate_at is None else laid(rate_at)
    return Aligned(
        t=t,
        x=x,
        y=y,
        mask=mask,
        dt=dev_timing.dt,
        device=dev_timing,
        reference=ref_timing,
        excluded=int(len(ok) - sel.sum()),
        shift=shift_s,
        device_timebase=dev_base,
        reference_timebase=ref_base,
        device_residual_s=float(dev_res),
        reference_residual_s=float(ref_res),
        rate_rms=_rate_rms(x, mask, dev_timing.dt),
        bridged=0 if bridge_sq is None else int(np.count_nonzero(bridge_sq[ok])),
        bridge_variance=(0.0 if bridge_sq is None
                         else float(bridge_sq[ok].sum() / max(1, int(ok.sum())))),
        xdot=xdot,
        calibration_u_s=_calibration_u(dev.label),
        anchor_u_s=_anchor_u(ref.label) if ref_base == "stand" else 0.0,
    )
