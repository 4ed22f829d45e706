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
``t₀ + k·Δt + w(k)``, a line and a slow wander fitted to the receipt stamps of the samples
that arrived on time (:mod:`benchctl.analysis.clockfit`: the slots and the clock).
The clock is set at the least latency a receipt had: what remains of the transmission
latency stays part of the instrument's measured delay, as with receipt stamps (a device
clock's offset from the host clock cannot be observed from the data).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from benchctl.analysis.clockfit import fit_line, fit_slots, robust_clock

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

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
    a0, b = fit_line(c_t - c0, mid[tight] - float(mid[tight][0]))
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
