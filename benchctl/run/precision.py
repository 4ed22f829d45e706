"""A test as long as its precision needs (``run.precision``, ``benchctl run --precision``).

The run may end before the profile does once σ is known well enough: at the end of each whole
period ``T_p`` of the profile's multisine (every line excited once more), σ and its 95 %
interval are estimated on the recording so far — the analysis the verdict makes, over the
whole periods from the end of the fade-in — and when, on every axis, the interval's relative
half-width ``max(σ̂ − lo, hi − σ̂) / σ̂`` is within the requested precision and no excitation
band is beyond its alarm level, the stand fades out from where it is (the profile's own fade,
``StandLoop.request_end``) and the verdict is made on the whole periods up to the stop.

The rule itself is :func:`decide_stop` (pure); :class:`PrecisionWatch` schedules the checks
and runs each one in a worker thread, so the stand loop and the main thread's watchdog are
never held up by an analysis; :func:`check_window` is one check, on the one evaluation path
(``benchctl.evaluate``) the verdict takes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from benchctl.analysis.excitation import breached
from benchctl.clock import REAL, Clock, ThreadLike
from benchctl.errors import BenchError, ConfigError
from benchctl.evaluate import EvaluationRequest, evaluate

MIN_PERIODS = 1  # never a stop before this many whole periods (every line excited)
CHECK_DELAY_S = 1.5  # a period is checked this long after its end (the streams' last samples)
REASON_PRECISION = "precision reached"
REASON_COMPLETE = "profile complete"


@dataclass(frozen=True)
class StopDecision:
    """Whether the run may stop now, and why (or why not)."""

    stop: bool
    reason: str


def relative_halfwidth(sigma: float, ci95: Sequence[float]) -> float:
    """The larger side of σ's 95 % interval relative to σ̂ (``inf`` when undefined)."""
    lo, hi = float(ci95[0]), float(ci95[1])
    if not (math.isfinite(sigma) and sigma > 0 and math.isfinite(lo) and math.isfinite(hi)):
        return math.inf
    return max(sigma - lo, hi - sigma) / sigma


def decide_stop(
    precision: Mapping[str, float],
    requested: float | None,
    periods: int,
    excitation_alarm: Mapping[str, bool] | None = None,
) -> StopDecision:
    """The stop rule. ``precision``: each axis's relative half-width of σ's 95 % interval over
    ``periods`` whole periods; ``requested``: the precision asked for (None: none, the profile
    runs to its end); ``excitation_alarm``: per axis, True when an excitation band is beyond its
    alarm level (the stand does not play the profile's spectrum well enough to stop on it).

    Stop only with at least ``MIN_PERIODS`` whole periods, an interval on every axis, no
    excitation alarm, and every axis within ``requested``."""
    if requested is None:
        return StopDecision(False, "no precision requested")
    if not 0.0 < requested < 1.0:
        raise ValueError(f"requested precision {requested!r}: expected 0 < value < 1")
    if periods < MIN_PERIODS:
        return StopDecision(
            False, f"{periods} whole period(s) so far, at least {MIN_PERIODS} needed"
        )
    if not precision:
        return StopDecision(False, "no axis has a σ interval")
    alarms = sorted(a for a, on in (excitation_alarm or {}).items() if on)
    if alarms:
        return StopDecision(False, f"excitation beyond its alarm level on {', '.join(alarms)}")
    axis, worst = max(precision.items(), key=lambda kv: (math.isnan(kv[1]), kv[1]))
    if not math.isfinite(worst):
        return StopDecision(False, f"no finite σ interval on {axis}")
    if worst <= requested:
        return StopDecision(True, REASON_PRECISION)
    return StopDecision(
        False, f"±{100 * worst:.2f} % on {axis}, ±{100 * requested:.2f} % requested"
    )


@dataclass
class AxisCheck:
    sigma: float
    ci95: tuple[float, float]
    precision: float  # relative half-width of ci95
    excitation: str | None = None  # the excitation judgement (ok, alarm, abort, …), if any
    alarm: bool = False

    def to_dict(self) -> dict[str, Any]:
        return {"sigma": self.sigma, "sigma_ci95": list(self.ci95), "precision": self.precision,
                "excitation": self.excitation, "excitation_alarm": self.alarm}


@dataclass
class PrecisionCheck:
    """One check: ``periods`` whole periods in ``window`` (host time), per axis σ and interval,
    the decision; ``error`` when the analysis could not be made (the run goes on)."""

    periods: int
    window: tuple[float, float]
    axes: dict[str, AxisCheck] = field(default_factory=dict)
    decision: StopDecision = StopDecision(False, "not checked")
    error: str | None = None
    seconds: float = 0.0  # how long the check took

    @property
    def precision(self) -> float:
        """The worst axis's relative half-width (``inf`` without any)."""
        return max((c.precision for c in self.axes.values()), default=math.inf)

    def to_dict(self) -> dict[str, Any]:
        return {
            "periods": self.periods,
            "window": list(self.window),
            "precision": self.precision if math.isfinite(self.precision) else None,
            "stop": self.decision.stop,
            "reason": self.decision.reason if self.error is None else self.error,
            "axes": {a: c.to_dict() for a, c in self.axes.items()},
            "check_s": self.seconds,
        }


def profile_period(motion: Any, axes: Sequence[str], where: str) -> float:
    """The profile's repetition period ``T_p`` (every axis's harmonic table must have the same
    one); ``ConfigError`` naming ``where`` when the profile has none (a precision stop needs
    whole periods of a multisine)."""
    tables = getattr(motion, "tables", None) or {}
    if getattr(motion, "segments", None) or not tables:
        raise ConfigError(
            f"{where}: a precision stop needs a periodic multisine profile (a harmonic table "
            "with a repetition period); this profile has none"
        )
    periods = set()
    for a in axes:
        tab = tables.get(a)
        if tab is None or not tab.period_s:
            raise ConfigError(f"{where}: the profile gives axis {a} no repetition period")
        periods.add(float(tab.period_s))
    if len(periods) != 1 or not all(p > 0 for p in periods):
        raise ConfigError(f"{where}: the profile's axes repeat with different periods {periods}")
    return periods.pop()


def check_window(path: Path, request: EvaluationRequest) -> dict[str, AxisCheck]:
    """σ and its interval per axis on the recording at ``path`` as written so far, over
    ``request.window`` (host time, whole periods): the verdict's evaluation
    (``run.evaluation.evaluation``: the same crop, line set and options; no sine steps nor
    cross-axis response, which the stop does not look at), and the excitation judgement over
    the same window."""

    ev = evaluate(path, replace(request, steps=False, cross_axis=False, excitation=True))
    out: dict[str, AxisCheck] = {}
    for axis, res in ev.results.items():
        ci = (float(res.sigma_ci95[0]), float(res.sigma_ci95[1]))
        # the stop is judged on the part of the interval more motion narrows: timing's share
        # (an offset between the streams, benchctl.analysis.timing) does not shrink with time
        stat = res.timing.get("sigma_ci95_statistical") or ci
        # departures that leave too little to judge σ on: no stop, the motion goes on
        reached = (relative_halfwidth(float(res.sigma), (float(stat[0]), float(stat[1])))
                   if res.judgeable else math.inf)
        check = AxisCheck(float(res.sigma), ci, reached)
        fid = ev.fidelity.get(axis)
        if isinstance(fid, str):
            check.excitation = f"not judged ({fid})"
        elif fid is not None:
            check.excitation = fid.judgement
            check.alarm = bool(breached(fid))
        out[axis] = check
    return out


Analyse = Callable[[tuple[float, float]], dict[str, AxisCheck]]


class PrecisionWatch:
    """The checks of one run. ``poll(now)`` (the main thread, often) starts a check in a worker
    thread when a whole period has ended since the last, and returns a finished check (with
    its decision) once, else None. Checks never overlap: a check still running when the next
    period ends is followed by one over all the periods by then."""

    def __init__(
        self,
        analyse: Analyse,
        requested: float,
        t_steady: float,
        period_s: float,
        max_periods: int,
        delay_s: float = CHECK_DELAY_S,
        *,
        clock: Clock = REAL,
    ) -> None:
        self.analyse = analyse
        self.requested = requested
        self.t_steady = t_steady  # host time the first period begins (end of the fade-in)
        self.period_s = period_s
        self.max_periods = max_periods  # the profile's own: a check there stops nothing
        self.delay_s = delay_s
        self.clock = clock
        self.checked = 0  # periods of the last check started
        self.checks: list[PrecisionCheck] = []
        self._thread: ThreadLike | None = None
        self._done: PrecisionCheck | None = None
        self._lock = clock.lock()

    def periods_at(self, now: float) -> int:
        """Whole periods recorded (and settled) by host time ``now``."""
        return max(0, math.floor((now - self.delay_s - self.t_steady) / self.period_s + 1e-9))

    def window(self, periods: int) -> tuple[float, float]:
        return self.t_steady, self.t_steady + periods * self.period_s

    @property
    def busy(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def poll(self, now: float) -> PrecisionCheck | None:
        with self._lock:
            done, self._done = self._done, None
        if done is not None:
            return done
        if self.busy:
            return None
        n = min(self.periods_at(now), self.max_periods - 1)
        if n >= MIN_PERIODS and n > self.checked:
            self.checked = n
            self._thread = self.clock.thread(self._run, args=(n,), name="precision check")
            self._thread.start()
        return None

    def _run(self, n: int) -> None:
        win = self.window(n)
        t0 = self.clock.monotonic()
        check = PrecisionCheck(n, win)
        try:
            check.axes = self.analyse(win)
            check.decision = decide_stop(
                {a: c.precision for a, c in check.axes.items()}, self.requested, n,
                {a: c.alarm for a, c in check.axes.items()},
            )
        except (BenchError, ValueError, ArithmeticError, OSError) as e:
            check.error = f"no precision check over {n} period(s): {e}"
            check.decision = StopDecision(False, check.error)
        check.seconds = self.clock.monotonic() - t0
        with self._lock:
            self._done = check
            self.checks.append(check)

    def join(self, timeout_s: float = 10.0) -> None:
        t = self._thread
        if t is not None:
            t.join(timeout_s)


def ended_summary(
    early: Mapping[str, Any] | None,
    precision: float,
    requested: float | None,
    motion_s: float | None,
    periods: int | None,
    period_s: float | None,
) -> dict[str, Any]:
    """The report's ``ended``: why the motion ended and the precision the verdict has."""
    return {
        "reason": REASON_PRECISION if early else REASON_COMPLETE,
        "precision": precision if math.isfinite(precision) else None,
        "requested": requested,
        "motion_s": motion_s,
        "periods": periods,
        "period_s": period_s,
    }


def whole_periods_in(span_s: float, period_s: float) -> int:
    """Whole periods in ``span_s`` (a hair's tolerance for float sums)."""
    return int(np.floor(span_s / period_s + 1e-6))
