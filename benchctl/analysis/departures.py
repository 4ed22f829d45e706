"""Where the stand's motion was not the profile's: underruns and rejoins, as intervals the
analysis leaves out (as it leaves out gaps).

When the host falls behind, the stand does not play the profile for a while: in buffered mode
its queue runs dry (an **underrun**: it goes on from its last point, brakes, holds), in stream
mode it holds its last setpoint over the missed slots; then the loop **rejoins** the profile
along a path within the limits. Over that time the instrument is shaken by another motion —
braking, holding, a path back — and its error there is not the error under the profile. Both
are events in the recording (``events.jsonl``); the commanded points are in ``setpoints.csv``
(``t_send``, ``t_slot``: sent when, due when).

The rule (one interval per departure, on the host clock):

- **start**: the last point the stand played as commanded. For an ``underrun`` event: the
  latest point queued before the stand reported the underrun (the ``t_slot`` of the last
  setpoint with ``t_send`` ≤ the event's ``t_host``; all of them were played before the
  queue ran dry). For a ``rejoin`` event: the last setpoint commanded before the rejoin's path
  (the one the stand held, ``t_slot`` before the path's first point). A rejoin that follows an
  underrun shares its interval.
- **back on the profile**: the rejoin's path played to its end: its first point (the first
  setpoint sent after the event, with ``t_slot`` ≥ the event's ``t_slot``) plus its
  ``duration_s``. An underrun that no rejoin follows (the run ended there) lasts to the end of
  the record.
- **settling**: a stated margin more after that, the bench config's
  ``run.analysis.departure_settle_s`` (the one recorded with the run; default ``SETTLE_S`` =
  3 s), for the stand's servo and the instrument's own response to the departure to die
  away. 3 s is several time constants of either: the simulated 8 Hz, ζ = 0.8 servo's
  ``1/(ζ·2π·f_n)`` is 25 ms, a resonant 0.8 Hz, ζ = 0.3 one's 0.66 s (3 s: e⁻⁴·⁵); an
  instrument's lag of τ = 0.3 s decays by e⁻¹⁰; it is the margin the equalisation pre-test
  leaves for the stand's transient too. A bench whose servo and instrument settle faster may
  state less.

Intervals that overlap (or touch) are merged. Pure computation on the events and the setpoint
columns; :func:`departures_of` reads them from a loaded recording.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

SETTLE_S = 3.0  # default settling after the stand is back on the profile (servo, instrument)
MIN_KEPT_SHARE = 0.5  # the analysis judges σ only when at least this share of the samples is kept
REASON = "the stand's motion was not the profile's (a queue underrun or a rejoin of the profile)"
RULE = (
    "from the last point the stand played as commanded to {settle:g} s after it was back on "
    "the profile (the rejoin's path played to its end)"
)


@dataclass(frozen=True)
class Departure:
    """One interval where the motion was not the profile's (host clock, s): ``start_s`` the
    last point played as commanded, ``back_s`` back on the profile (inf: never, in the
    record), ``end_s`` = ``back_s`` + the settling; ``kinds`` the events behind it."""

    start_s: float
    back_s: float
    end_s: float
    kinds: tuple[str, ...]

    def count(self, kind: str) -> int:
        return self.kinds.count(kind)


@dataclass(frozen=True)
class Departures:
    """The departures of a record, merged and in order, with the settling used."""

    items: tuple[Departure, ...]
    settle_s: float = SETTLE_S

    def __bool__(self) -> bool:
        return bool(self.items)

    def __len__(self) -> int:
        return len(self.items)

    @property
    def rule(self) -> str:
        return RULE.format(settle=self.settle_s)

    def within(self, lo: float, hi: float) -> Departures:
        """Those that touch ``[lo, hi]``."""
        return Departures(tuple(d for d in self.items if d.start_s <= hi and d.end_s >= lo),
                          self.settle_s)

    def inside(self, t: FloatArray) -> NDArray[np.bool_]:
        """True where an instant of ``t`` lies in a departure (ends included)."""
        t = np.asarray(t, dtype=float)
        if not self.items:
            return np.zeros(t.shape, dtype=bool)
        starts = np.array([d.start_s for d in self.items])
        ends = np.array([d.end_s for d in self.items])
        i = np.searchsorted(starts, t, side="right") - 1
        ok = i >= 0
        out = np.zeros(t.shape, dtype=bool)
        out[ok] = t[ok] <= ends[i[ok]]
        return out


def _float(v: Any) -> float | None:
    if isinstance(v, bool) or not isinstance(v, int | float):
        return None
    f = float(v)
    return f if math.isfinite(f) else None


def find_departures(
    events: Iterable[Mapping[str, Any]],
    t_send: FloatArray,
    t_slot: FloatArray,
    settle_s: float = SETTLE_S,
) -> Departures:
    """The departures (module notes) from a recording's events and its setpoints' ``t_send``
    and ``t_slot`` columns (rows without a slot time, such as the cleanup ramp's, ignored).

    Examples
    --------
    A buffered run whose queue (points every 0.02 s, sent 1 s ahead) ran dry after the point
    due at 10.0 s; the host saw it at 10.5 s, and the path back, 0.4 s long, started at 11.0 s:

    >>> import numpy as np
    >>> slot = np.r_[np.arange(0.0, 10.01, 0.02), np.arange(11.0, 20.0, 0.02)]
    >>> send = np.where(slot < 10.5, slot - 1.0, 10.9)
    >>> ev = [{"kind": "underrun", "t_host": 10.5},
    ...       {"kind": "rejoin", "t_host": 10.8, "t_slot": 10.8, "duration_s": 0.4}]
    >>> d = find_departures(ev, send, slot).items[0]
    >>> round(d.start_s, 6), round(d.back_s, 6), round(d.end_s, 6), d.kinds
    (10.0, 11.4, 14.4, ('underrun', 'rejoin'))
    """
    if not (math.isfinite(settle_s) and settle_s >= 0):
        raise ValueError(f"settle_s: expected a non-negative number of seconds, got {settle_s!r}")
    send = np.asarray(t_send, dtype=float)
    slot = np.asarray(t_slot, dtype=float)
    ok = np.isfinite(send) & np.isfinite(slot)
    send, slot = send[ok], slot[ok]
    raw: list[tuple[float, float, tuple[str, ...]]] = []
    pending: float | None = None  # an underrun's start, waiting for its rejoin
    for e in events:
        kind = e.get("kind")
        if kind == "underrun":
            t = _float(e.get("t_host"))
            if t is None:
                continue
            before = slot[send <= t]
            start = min(float(before.max()), t) if before.size else t
            pending = start if pending is None else min(pending, start)
        elif kind == "rejoin":
            t = _float(e.get("t_slot"))
            if t is None:
                continue
            dur = _float(e.get("duration_s")) or 0.0
            t_ev = _float(e.get("t_host"))
            after = slot >= t - 1e-9
            if t_ev is not None:
                after &= send >= t_ev
            first = float(slot[after].min()) if after.any() else t
            held = slot[slot < first - 1e-9]
            start = float(held.max()) if held.size else first
            kinds: tuple[str, ...] = ("rejoin",)
            if pending is not None:
                start, kinds = min(start, pending), ("underrun", "rejoin")
                pending = None
            raw.append((start, first + max(dur, 0.0), kinds))
    if pending is not None:
        raw.append((pending, math.inf, ("underrun",)))
    return Departures(_merge(raw, settle_s), settle_s)


def _merge(raw: list[tuple[float, float, tuple[str, ...]]], settle_s: float
           ) -> tuple[Departure, ...]:
    out: list[Departure] = []
    for start, back, kinds in sorted(raw, key=lambda r: r[0]):
        end = back + settle_s
        if out and start <= out[-1].end_s:
            prev = out[-1]
            b = max(prev.back_s, back)
            out[-1] = Departure(prev.start_s, b, b + settle_s, prev.kinds + kinds)
        else:
            out.append(Departure(start, back, end, kinds))
    return tuple(out)


def settle_of(meta: Mapping[str, Any] | None) -> float:
    """The settling a recording's bench config states (``run.analysis.departure_settle_s``),
    else ``SETTLE_S``."""
    try:
        v = meta["config"]["run"]["analysis"]["departure_settle_s"]  # type: ignore[index]
    except (KeyError, TypeError):
        return SETTLE_S
    f = _float(v)
    return f if f is not None and f >= 0 else SETTLE_S


def departures_of(rec: Any, settle_s: float | None = None) -> Departures:
    """The departures of a loaded recording (``benchctl.recording.Recording``): its events and
    its setpoints stream (none without one), with ``settle_s`` or else the settling its bench
    config states (:func:`settle_of`)."""
    sp = (getattr(rec, "streams", None) or {}).get("setpoints") or {}
    t_send = sp.get("t_send", np.empty(0))
    t_slot = sp.get("t_slot", np.empty(0))
    if len(t_send) != len(t_slot):
        t_send = t_slot = np.empty(0)
    settle = settle_of(getattr(rec, "meta", None)) if settle_s is None else settle_s
    return find_departures(getattr(rec, "events", None) or [], t_send, t_slot, settle)


def sigma_inconclusive(departures: Any) -> str | None:
    """Why σ is not to be judged, from an analysis's ``departures`` (None: it is)."""
    if not isinstance(departures, dict) or not departures.get("too_little"):
        return None
    return ("the stand's motion was not the profile's for too much of the window: "
            f"{departures.get('too_little_reason') or 'too little left'} "
            f"({departures.get('count')} departure(s), {departures.get('excluded_s', 0):.3g} s); "
            "run the test again, or longer, on a host that keeps up")


def departure_text(dep: Mapping[str, Any]) -> str:
    """One line on the departures from the profile an analysis left out."""
    per = dep.get("line_periods") or {}
    on = {
        "whole_periods": f"σ on the {per.get('used')} of {per.get('of')} whole period(s) no "
                         "departure touches",
        "all": "σ over the whole record, departures included (for information only)",
    }.get(str(dep.get("sigma_over")), "σ on the samples outside them")
    return (f"motion not the profile's: {dep.get('count')} interval(s) ({dep.get('underruns')} "
            f"underrun(s), {dep.get('rejoins')} rejoin(s)), {dep.get('excluded_s', 0):.3g} s "
            f"left out with {dep.get('settle_s', 0):g} s settling; {on}; "
            f"{100 * dep.get('kept_share', 0):.3g} % of the samples kept")


__all__ = [
    "MIN_KEPT_SHARE",
    "SETTLE_S",
    "Departure",
    "Departures",
    "departure_text",
    "departures_of",
    "find_departures",
    "settle_of",
    "sigma_inconclusive",
]
