"""The host's scheduling latency in figures, and its verdict against the stand: pure functions
(no clock, no thread, no I/O — ``benchctl.run.fitness`` measures; this judges).

- ``lateness_stats``: a wake's *lateness* is when it woke less when it asked to; over a window
  the maximum, the median, p99 and p99.9 (nearest rank: the smallest lateness at or above which
  lie no more than 1 %, 0.1 % of the wakes), the count, and how many wakes were later than each
  of ``THRESHOLDS_S``.
- ``stand_bounds``: what the stand tolerates of a late host, each a ``Bound``: its buffer
  (``buffered``: the queue plays on while the host sleeps), the stand loop's send window
  (``stream``: a setpoint later than ``send_window`` × its period is a missed slot), and the
  slack its heartbeat watchdog leaves beyond the longest exchange and the heartbeat period.
  ``table``: the stand plays its table itself, only the watchdog bounds the host.
- ``judge``: the worst lateness × the margin asked for must fit inside the tightest bound.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

#: a wake later than each of these is counted (0.1 ms, 1 ms, 10 ms, 100 ms)
THRESHOLDS_S: tuple[float, ...] = (1e-4, 1e-3, 1e-2, 1e-1)


@dataclass(frozen=True)
class LatencyStats:
    """The lateness of ``count`` wakes asked for every ``period_s`` over ``window_s``."""

    period_s: float
    window_s: float
    count: int
    max_s: float  # nan when nothing was measured (count 0)
    p999_s: float
    p99_s: float
    median_s: float
    over: tuple[tuple[float, int], ...]  # (threshold s, wakes later than it)

    def to_dict(self) -> dict[str, Any]:
        return {
            "period_s": self.period_s,
            "window_s": self.window_s,
            "count": self.count,
            "max_s": self.max_s,
            "p999_s": self.p999_s,
            "p99_s": self.p99_s,
            "median_s": self.median_s,
            "over": {f"{t:g}": n for t, n in self.over},
        }


def quantile(ordered: Sequence[float], p: float) -> float:
    """The nearest-rank ``p``-quantile of ``ordered`` (ascending): its ⌈p·n⌉-th value (the
    first for p = 0); nan when empty."""
    n = len(ordered)
    if n == 0:
        return math.nan
    rank = max(1, math.ceil(p * n - 1e-9))  # 1e-9: p·n exact in decimal, not in binary
    return float(ordered[min(rank, n) - 1])


def lateness_stats(
    lateness_s: Sequence[float],
    period_s: float,
    window_s: float,
    thresholds_s: Sequence[float] = THRESHOLDS_S,
) -> LatencyStats:
    """The figures of the wakes' lateness (seconds each, as measured)."""
    ordered = sorted(float(x) for x in lateness_s)
    return LatencyStats(
        period_s=period_s,
        window_s=window_s,
        count=len(ordered),
        max_s=ordered[-1] if ordered else math.nan,
        p999_s=quantile(ordered, 0.999),
        p99_s=quantile(ordered, 0.99),
        median_s=quantile(ordered, 0.5),
        over=tuple((t, sum(1 for x in ordered if x > t)) for t in thresholds_s),
    )


@dataclass(frozen=True)
class Bound:
    """One thing of the stand's that a late host eats into: ``seconds`` of lateness it
    tolerates, and how the verdict names it."""

    name: str  # "buffer", "send window", "watchdog"
    seconds: float
    text: str  # "the stand's 1 s buffer"

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "seconds": self.seconds, "text": self.text}


def stand_bounds(
    *,
    mode: str,
    buffer_s: float,
    setpoint_rate_hz: float,
    send_window: float,
    watchdog_s: float | None,
    exchange_s: float,
) -> list[Bound]:
    """What the stand tolerates of a late host (``exchange_s``: the longest exchange plus the
    heartbeat period, ``benchctl.config.exchange_bound_s``; ``watchdog_s`` None: unknown, not
    a bound)."""
    out: list[Bound] = []
    if mode == "buffered":
        out.append(Bound("buffer", buffer_s, f"the stand's {buffer_s:g} s buffer"))
    elif mode == "stream":
        period = 1.0 / setpoint_rate_hz
        w = send_window * period
        out.append(Bound(
            "send window", w,
            f"the stand loop's {w * 1e3:g} ms send window ({send_window:g} of its "
            f"{period * 1e3:g} ms period: a later setpoint is a missed slot)",
        ))
    if watchdog_s is not None:
        slack = max(0.0, watchdog_s - exchange_s)
        out.append(Bound(
            "watchdog", slack,
            f"the {slack:g} s left of the stand's {watchdog_s:g} s watchdog after its longest "
            f"exchange ({exchange_s:g} s)",
        ))
    return out


@dataclass(frozen=True)
class Verdict:
    """The worst lateness against the tightest bound."""

    ok: bool
    worst_s: float
    margin: float  # bound / worst: inf for a worst of 0 or no bound, nan when nothing measured
    required: float  # the margin asked for (run.host_check.margin)
    bound: Bound | None  # the tightest; None: nothing to judge against

    def to_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "worst_s": self.worst_s,
            "margin": self.margin,
            "required_margin": self.required,
            "bound": None if self.bound is None else self.bound.to_dict(),
        }


def judge(worst_s: float, bounds: Sequence[Bound], required: float) -> Verdict:
    """``ok`` when ``worst_s × required`` fits inside the tightest bound (or there is none);
    a worst that is not a number (nothing measured) is never ok."""
    bound = min(bounds, key=lambda b: b.seconds) if bounds else None
    if not math.isfinite(worst_s) or worst_s < 0:
        return Verdict(False, worst_s, math.nan, required, bound)
    if bound is None:
        return Verdict(True, worst_s, math.inf, required, None)
    margin = bound.seconds / worst_s if worst_s > 0 else math.inf
    return Verdict(worst_s * required <= bound.seconds, worst_s, margin, required, bound)


def _ms(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "–"
    return f"{seconds * 1e3:.2f} ms" if seconds < 1.0 else f"{seconds:.2f} s"


def margin_text(margin: float) -> str:
    """×1190, ×12, ×3.8, ×0.21; ×∞ (a worst of 0)."""
    if math.isnan(margin):
        return "×?"
    if math.isinf(margin):
        return "×∞"
    return f"×{margin:.0f}" if margin >= 10 else f"×{margin:.2g}"


def summary(stats: LatencyStats, verdict: Verdict, on_poor: str) -> str:
    """The figures and the verdict in one line (without the leading ``host latency:``), e.g.
    ``max 0.84 ms, p99.9 0.31 ms over 2 s (margin ×1190 against the stand's 1 s buffer) —
    ok``."""
    if stats.count == 0:
        return (f"no wake measured over {stats.window_s:g} s — poor: nothing to judge "
                f"(run.host_check.on_poor: {on_poor})")
    head = (f"max {_ms(stats.max_s)}, p99.9 {_ms(stats.p999_s)} over {stats.window_s:g} s, "
            f"{stats.count} wakes")
    b = verdict.bound
    if b is None:
        return f"{head} (no buffer or watchdog of the stand's to judge it against) — ok"
    against = f"margin {margin_text(verdict.margin)} against {b.text}"
    if verdict.ok:
        return f"{head} ({against}) — ok"
    return (f"{head} ({against}) — poor: run.host_check.margin asks ×{verdict.required:g}, "
            f"a worst lateness of at most {_ms(b.seconds / verdict.required)} "
            f"(run.host_check.on_poor: {on_poor})")
