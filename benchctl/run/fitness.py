"""The host fitness check: the host's scheduling latency measured before the motion and
judged against what the stand tolerates (``run.host_check``; ``docs/howto/host-check.md``).

For ``window_s`` (2 s) one thread per period — ``run.host_check.period_s`` (1 ms, cyclictest's)
and the stand loop's own (``1/setpoint_rate_hz`` streaming, else ``1/sample_rate_hz``) — asks
to wake on absolute deadlines ``t0 + k·period`` and waits as the stand loop waits (an event's
timed wait on the run's clock); each wake's lateness is when it woke less its deadline. A wake
so late that later deadlines have passed skips them (one lateness per stall, as the loop skips
slots). With ``run.realtime_priority`` the threads ask for it first, so the figures are those
of a loop at that priority. The figures and the verdict are ``benchctl.run.latency``'s.

On simulated time nothing is measured (``SKIP_VIRTUAL``): a simulated run's host latency means
nothing, and its recording must not depend on the host.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

from benchctl.clock import Clock, EventLike, ThreadLike
from benchctl.config import BenchConfig, exchange_bound_s
from benchctl.run.latency import (
    Bound,
    LatencyStats,
    Verdict,
    judge,
    lateness_stats,
    stand_bounds,
    summary,
)
from benchctl.run.prechecks import CheckResult
from benchctl.run.realtime import PrioritySetter, RealtimeResult, request_realtime
from benchctl.run.stand_loop import SEND_WINDOW

NAME = "host latency"  # the precheck's name
SKIP_VIRTUAL = "simulated time: host latency not measured"
SKIP_DISABLED = "host latency not measured: run.host_check.enabled is false"
JOIN_SLACK_S = 5.0  # a measuring thread ends this long after its window at the latest


def measure_lateness(clock: Clock, period_s: float, window_s: float,
                     stop: EventLike) -> list[float]:
    """In the calling thread: wake every ``period_s`` on absolute deadlines for ``window_s``
    and return each wake's lateness (s, ≥ 0); fewer when ``stop`` is set."""
    out: list[float] = []
    t0 = clock.monotonic()
    end = t0 + window_s
    k = 1
    while (deadline := t0 + k * period_s) <= end:
        now = clock.monotonic()
        while now < deadline:
            if stop.wait(deadline - now):
                return out
            now = clock.monotonic()
        out.append(now - deadline)
        k = max(k + 1, math.floor((now - t0) / period_s) + 1)
    return out


@dataclass
class HostLatency:
    """What was measured: each period's wakes' lateness over ``window_s``; ``realtime``: the
    priority the measuring threads asked for and got (None: not asked)."""

    window_s: float
    series: dict[float, list[float]]
    realtime: RealtimeResult | None = None


#: measures the host: (clock, periods, window_s, stop, realtime priority) → HostLatency
Probe = Callable[[Clock, Sequence[float], float, EventLike, int | None], HostLatency]


def measure_host(clock: Clock, periods: Sequence[float], window_s: float, stop: EventLike,
                 priority: int | None = None, setter: PrioritySetter | None = None) -> HostLatency:
    """One measuring thread per period, side by side, for ``window_s`` (``stop`` set: they end
    at once). With ``priority`` each thread asks for SCHED_FIFO first (``setter``: the OS's)."""
    series: dict[float, list[float]] = {}
    granted: list[RealtimeResult] = []
    errors: list[BaseException] = []

    def work(period: float) -> None:
        try:
            if priority is not None:
                granted.append(request_realtime(priority, setter))
            series[period] = measure_lateness(clock, period, window_s, stop)
        except BaseException as e:  # handed to the caller
            errors.append(e)

    threads: list[ThreadLike] = [
        clock.thread(work, name=f"host-check {p * 1e3:g} ms", args=(p,)) for p in periods
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join(window_s + JOIN_SLACK_S)
    if errors:
        raise errors[0]
    return HostLatency(window_s, {p: series.get(p, []) for p in periods},
                       granted[0] if granted else None)


def loop_period_s(cfg: BenchConfig) -> float:
    """The stand loop's period: a setpoint period streaming, else a poll period."""
    st = cfg.stand
    return 1.0 / (st.setpoint_rate_hz if st.mode == "stream" else st.sample_rate_hz)


def periods_s(cfg: BenchConfig) -> list[float]:
    """The periods measured: ``run.host_check.period_s`` and the stand loop's own."""
    return sorted({cfg.run.host_check.period_s, loop_period_s(cfg)})


def watchdog_s(cfg: BenchConfig) -> float | None:
    """The stand's heartbeat watchdog: ``stand.watchdog_s``, the simulated stand's with a
    ``sim:`` section (as ``benchctl.config`` checks it); None when not known."""
    return cfg.sim.stand.watchdog_s if cfg.sim is not None else cfg.stand.watchdog_s


def bounds(cfg: BenchConfig) -> list[Bound]:

    st = cfg.stand
    return stand_bounds(mode=st.mode, buffer_s=st.buffer_s, setpoint_rate_hz=st.setpoint_rate_hz,
                        send_window=SEND_WINDOW, watchdog_s=watchdog_s(cfg),
                        exchange_s=exchange_bound_s(st))


@dataclass
class HostCheck:
    """The measurement's figures and verdict against a bench config."""

    stats: LatencyStats  # every wake of every period
    per_period: list[LatencyStats]
    verdict: Verdict
    bounds: list[Bound]
    on_poor: str  # run.host_check.on_poor
    realtime: RealtimeResult | None = None
    detail: str = field(init=False)

    def __post_init__(self) -> None:
        self.detail = summary(self.stats, self.verdict, self.on_poor)
        if self.realtime is not None:
            self.detail += f"; measured at {self.realtime.detail}"

    @property
    def ok(self) -> bool:
        return self.verdict.ok

    @property
    def line(self) -> str:
        """The operator's line: ``host latency: max 0.84 ms, … — ok``."""
        return f"{NAME}: {self.detail}"

    def values(self) -> dict[str, Any]:
        return {
            "window_s": self.stats.window_s,
            "all": self.stats.to_dict(),
            "periods": [s.to_dict() for s in self.per_period],
            "bounds": [b.to_dict() for b in self.bounds],
            "verdict": self.verdict.to_dict(),
            "on_poor": self.on_poor,
            "realtime": None if self.realtime is None else self.realtime.to_dict(),
        }

    def check_result(self) -> CheckResult:
        """The precheck: failed only when poor under ``on_poor: refuse``."""
        return CheckResult(NAME, self.ok or self.on_poor != "refuse", self.detail,
                           self.values())

    def warning(self) -> str | None:
        """The record's warning when poor under ``on_poor: warn``."""
        if self.ok or self.on_poor == "refuse":
            return None
        return f"{NAME}: {self.detail}"


def assess(cfg: BenchConfig, measured: HostLatency) -> HostCheck:
    """The measured lateness judged against ``cfg``'s stand and ``run.host_check``."""
    hc = cfg.run.host_check
    everything = [x for s in measured.series.values() for x in s]
    per = [lateness_stats(s, p, measured.window_s) for p, s in sorted(measured.series.items())]
    stats = lateness_stats(everything, min(measured.series, default=hc.period_s),
                           measured.window_s)
    bs = bounds(cfg)
    return HostCheck(stats, per, judge(stats.max_s, bs, hc.margin), bs, hc.on_poor,
                     measured.realtime)


def host_check(cfg: BenchConfig, clock: Clock, stop: EventLike, *, window_s: float | None = None,
               probe: Probe | None = None, setter: PrioritySetter | None = None) -> HostCheck:
    """Measure the host (``probe``: ``measure_host`` by default, its threads asking for
    ``run.realtime_priority`` through ``setter``, the OS's by default) and judge it against
    ``cfg``; ``window_s`` overrides ``run.host_check.window_s``."""
    window = cfg.run.host_check.window_s if window_s is None else window_s
    measure: Probe = probe if probe is not None else partial(measure_host, setter=setter)
    return assess(cfg, measure(clock, periods_s(cfg), window, stop, cfg.run.realtime_priority))
