"""A run's results as measurements with limits, a decision rule and an outcome.

Each result — σ per axis, mean error, delay, gain and phase at the traditional periods, the
linearity spread of sine steps, the excitation fidelity, the prechecks, the serial match — is a
:class:`Measurement` ``{name, axis, value, unit, low, high, ci95, outcome, rule, decisive}``.

Decision rules (ISO 14253-1 style), for a measurement with limits ``[low, high]`` (either may
be open) and, where it has one, a 95 % interval ``ci95``:

- ``simple`` (simple acceptance): PASS when ``low ≤ value ≤ high``, else FAIL;
- ``guarded`` (guarded acceptance): PASS only when the whole interval lies within the limits,
  FAIL when the whole interval lies outside them, otherwise INCONCLUSIVE.

The rule chosen for the run (``run.decision_rule`` / ``--decision-rule``) applies to every
measurement with an interval (σ, and gain/phase when limits are set for them); one without an
interval is judged by the simple rule and says so in its ``rule``. A value that is missing or
not finite FAILs. A measurement without limits, or a period the profile does not excite, is
``NOT_JUDGED`` (its value is recorded for information).

``decisive`` measurements make the run's outcome (:func:`overall`): any FAIL → FAIL, else any
INCONCLUSIVE → INCONCLUSIVE, else PASS. Decisive: σ, the linearity spread, the prechecks, and
gain/phase/delay/mean error when ``run.limits`` gives limits for them. Informative (recorded,
never deciding): the excitation fidelity (its alarm stays a warning) and the serial match (a
mismatch is a warning, the run still judged on what it measured). An informative measurement
is never FAIL: beyond its limit its outcome is ``WARNING`` (:func:`informative`); a serial
mismatch blocks a run only under ``unit.serial_check: require``, as a failed precheck.
σ is INCONCLUSIVE under either rule when the stand's motion departed from the profile for too
much of the window (:mod:`benchctl.analysis.departures`): never a PASS or FAIL on σ of another
motion.

Plans build their own limits (:class:`Limits`) and call :func:`judge` on the report's axes.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from benchctl.outcomes import Outcome

# a measurement's outcomes (``Outcome``), also by these names; WARNING: an informative
# measurement beyond its limit, shown and recorded, never a FAIL (it decides nothing: the
# excitation fidelity's alarm, a serial mismatch)
PASS, FAIL, INCONCLUSIVE = Outcome.PASS, Outcome.FAIL, Outcome.INCONCLUSIVE
NOT_JUDGED, WARNING = Outcome.NOT_JUDGED, Outcome.WARNING
OUTCOMES = (PASS, FAIL, INCONCLUSIVE, NOT_JUDGED, WARNING)
RULES = ("simple", "guarded")
RULE_TEXT = {
    "simple": (
        "simple acceptance: PASS when the measured value is within the limit(s), FAIL "
        "otherwise (the measurement uncertainty is not taken into account)"
    ),
    "guarded": (
        "guarded acceptance with the 95 % interval: PASS only when the whole interval is "
        "within the limit(s), FAIL when the whole interval is beyond them, INCONCLUSIVE "
        "otherwise"
    ),
}
TRADITIONAL_PERIODS_S = (3.0, 5.0, 7.0, 10.0)


def _finite(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def decide(
    value: float | None,
    low: float | None,
    high: float | None,
    ci95: Sequence[float | None] | None = None,
    rule: str = "simple",
) -> Outcome:
    """The outcome of one measurement under ``rule`` (see the module notes).

    ``guarded`` needs ``ci95`` (lower, upper); a bound that is missing or not finite can
    neither show the value inside nor outside, so that side does not decide."""
    if rule not in RULES:
        raise ValueError(f"decision rule {rule!r}: expected one of {', '.join(RULES)}")
    if low is None and high is None:
        return Outcome.NOT_JUDGED
    if not _finite(value):
        return Outcome.FAIL
    assert value is not None
    if rule == "simple" or ci95 is None:
        ok = (low is None or value >= low) and (high is None or value <= high)
        return Outcome.PASS if ok else Outcome.FAIL
    lo = ci95[0] if _finite(ci95[0]) else None
    hi = ci95[1] if _finite(ci95[1]) else None
    inside = (
        (low is None or (lo is not None and lo >= low))
        and (high is None or (hi is not None and hi <= high))
    )
    if inside:
        return Outcome.PASS
    outside = (high is not None and lo is not None and lo > high) or (
        low is not None and hi is not None and hi < low
    )
    return Outcome.FAIL if outside else Outcome.INCONCLUSIVE


def informative(outcome: Outcome) -> Outcome:
    """An informative measurement's outcome: a FAIL is a ``WARNING`` (it decides nothing, so
    it is never shown as a failure); every other outcome as it is."""
    return Outcome.WARNING if outcome == Outcome.FAIL else outcome


def combine(outcomes: Iterable[Outcome]) -> Outcome:
    """FAIL if any FAIL, else INCONCLUSIVE if any, else PASS if any PASS, else NOT_JUDGED."""
    seen = set(outcomes)
    for o in (Outcome.FAIL, Outcome.INCONCLUSIVE, Outcome.PASS):
        if o in seen:
            return o
    return Outcome.NOT_JUDGED


@dataclass
class Measurement:
    name: str
    axis: str | None
    value: float | str | bool | None
    unit: str | None
    low: float | None
    high: float | None
    ci95: list[float | None] | None
    outcome: Outcome
    rule: str  # simple | guarded | check (a precheck: pass or fail as such)
    decisive: bool = True
    note: str | None = None
    # σ's uncertainty budget (benchctl.analysis.budget): on the σ measurement, of its value
    uncertainty: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        extra = {} if self.uncertainty is None else {"uncertainty": self.uncertainty}
        return {
            "name": self.name,
            "axis": self.axis,
            "value": self.value,
            "unit": self.unit,
            "low": self.low,
            "high": self.high,
            "ci95": None if self.ci95 is None else list(self.ci95),
            "outcome": self.outcome,
            "rule": self.rule,
            "decisive": self.decisive,
            "note": self.note,
            **extra,
        }


def overall(measurements: Iterable[Measurement]) -> Outcome:
    """The run's outcome from its decisive measurements (NOT_JUDGED when none was judged)."""
    return combine(m.outcome for m in measurements if m.decisive)


@dataclass(frozen=True)
class Limits:
    """Limits of a run's measurements. ``sigma_deg``: σ ≤ this per axis; ``linearity_spread``:
    max − min of the sine steps' gains; ``excitation_db``: the excitation's overall rms error
    and worst band within ± this (informative); ``gain``: (low, high) for the gain at the
    traditional periods; ``phase_deg``: |phase| ≤ this there; ``delay_s``: |delay| ≤ this;
    ``mean_error_deg``: |mean error| ≤ this. None: not judged."""

    sigma_deg: float
    linearity_spread: float | None = 0.01
    excitation_db: float | None = 1.5
    gain: tuple[float | None, float | None] | None = None
    phase_deg: float | None = None
    delay_s: float | None = None
    mean_error_deg: float | None = None
    periods_s: tuple[float, ...] = field(default=TRADITIONAL_PERIODS_S)


def limits_from_config(cfg: Any) -> Limits:
    """The limits a bench config states (``run.limit_sigma_deg``,
    ``run.linearity_spread_limit``, ``run.excitation.alarm_db``, ``run.limits``)."""
    run = cfg.run
    extra = getattr(run, "limits", None)
    gain = None
    if extra is not None and (extra.gain_min is not None or extra.gain_max is not None):
        gain = (extra.gain_min, extra.gain_max)
    return Limits(
        sigma_deg=float(run.limit_sigma_deg),
        linearity_spread=float(run.linearity_spread_limit),
        excitation_db=float(run.excitation.alarm_db),
        gain=gain,
        phase_deg=None if extra is None else extra.phase_deg,
        delay_s=None if extra is None else extra.delay_s,
        mean_error_deg=None if extra is None else extra.mean_error_deg,
    )


def _sym(limit: float | None) -> tuple[float | None, float | None]:
    return (None, None) if limit is None else (-float(limit), float(limit))


def _num(v: Any) -> float | None:
    return float(v) if _finite(v) else None


def _ci(v: Any) -> list[float | None] | None:
    if v is None:
        return None
    return [_num(v[0]), _num(v[1])]


def _measure(
    name: str, axis: str | None, value: Any, unit: str, lim: tuple[float | None, float | None],
    ci95: Any, rule: str, *, decisive: bool = True, note: str | None = None,
) -> Measurement:
    ci = _ci(ci95)
    used = rule if ci is not None else "simple"
    outcome = decide(_num(value), lim[0], lim[1], ci, used)
    judged = outcome != Outcome.NOT_JUDGED
    if not decisive:
        outcome = informative(outcome)
    return Measurement(name, axis, _num(value), unit, lim[0], lim[1], ci, outcome, used,
                       decisive and judged, note)


def axis_measurements(
    axis: str, verdict: Mapping[str, Any], limits: Limits, rule: str = "simple"
) -> list[Measurement]:
    """The measurements of one axis from its report entry (``AxisVerdict.to_dict(full=True)``
    or ``report.json``'s ``axes[axis]``): σ, mean error, delay, gain and phase at the periods,
    the linearity spread (sine steps) and the excitation fidelity."""
    sigma = _measure("sigma", axis, verdict.get("sigma"), "deg", (None, limits.sigma_deg),
                     verdict.get("sigma_ci95"), rule)
    why = _sigma_inconclusive(verdict)
    if why is not None and sigma.outcome != Outcome.NOT_JUDGED:
        sigma.outcome, sigma.note = Outcome.INCONCLUSIVE, f"not judged: {why}"
    budget = verdict.get("budget", (verdict.get("analysis") or {}).get("budget"))
    if isinstance(budget, Mapping):
        sigma.uncertainty = dict(budget)
    out = [
        sigma,
        _measure("mean error", axis, verdict.get("mean_error"), "deg",
                 _sym(limits.mean_error_deg), None, rule),
        _measure("delay", axis, verdict.get("delay"), "s", _sym(limits.delay_s), None, rule),
    ]
    analysis = verdict.get("analysis") or {}
    by_period = {float(p["period_s"]): p for p in analysis.get("periods") or []
                 if p.get("period_s") is not None}
    gain_lim = limits.gain if limits.gain is not None else (None, None)
    for period in limits.periods_s:
        p = by_period.get(float(period))
        tag = f"{period:g} s"
        if p is None or not p.get("excited"):
            why = "not excited by the profile" if p is not None else "not analysed"
            for name, unit, lim in (("gain", "1", gain_lim),
                                    ("phase", "deg", _sym(limits.phase_deg))):
                out.append(Measurement(f"{name} at {tag}", axis, None, unit, lim[0], lim[1],
                                       None, Outcome.NOT_JUDGED, rule, False, why))
            continue
        out.append(_measure(f"gain at {tag}", axis, p.get("gain"), "1", gain_lim,
                            p.get("gain_ci95"), rule))
        out.append(_measure(f"phase at {tag}", axis, p.get("phase_deg"), "deg",
                            _sym(limits.phase_deg), p.get("phase_ci95_deg"), rule))
    lin = verdict.get("linearity")
    if lin is not None:
        limit = limits.linearity_spread if limits.linearity_spread is not None else lin.get(
            "limit")
        out.append(_measure("linearity spread", axis, lin.get("spread"), "1", (None, limit),
                            None, rule, note="max − min gain over the sine steps"))
    ex = verdict.get("excitation")
    if ex is not None:
        judged = ex.get("judgement") not in (None, "not judged")
        lim = _sym(limits.excitation_db) if judged else (None, None)
        out.append(_measure("excitation rms error", axis, ex.get("rms_error_db"), "dB", lim,
                            None, rule, decisive=False,
                            note=f"judgement {ex.get('judgement')} (informative)"))
        wb = ex.get("worst_band") or {}
        out.append(_measure(
            "excitation worst band", axis, wb.get("error_db"), "dB", lim, None, rule,
            decisive=False,
            note=None if not wb else f"band centred at {wb.get('centre_hz', math.nan):.4g} Hz",
        ))
    return out


def _sigma_inconclusive(verdict: Mapping[str, Any]) -> str | None:
    """Why an axis's σ is not to be judged: the stand's motion departed from the profile for
    too much of the window (``sigma_inconclusive``, or the analysis's ``departures``)."""
    why = verdict.get("sigma_inconclusive")
    if isinstance(why, str) and why:
        return why
    dep = (verdict.get("analysis") or {}).get("departures")
    if isinstance(dep, Mapping) and dep.get("too_little"):
        return str(dep.get("too_little_reason") or "the departures from the profile left too "
                   "little of its motion")
    return None


def judge(axes: Mapping[str, Mapping[str, Any]], limits: Limits,
          rule: str = "simple") -> list[Measurement]:
    """Every axis's measurements against ``limits`` (a plan's own limits, say) from a report's
    ``axes`` (``report.json`` or ``Report.to_dict()``); :func:`overall` gives the outcome."""
    out: list[Measurement] = []
    for axis, v in axes.items():
        out.extend(axis_measurements(axis, v, limits, rule))
    return out


def precheck_measurements(prechecks: Iterable[Mapping[str, Any]]) -> list[Measurement]:
    """The prechecks run (``CheckResult.to_dict()``: name, ok, detail): PASS or FAIL each."""
    return [
        Measurement(f"precheck: {p.get('name')}", None, bool(p.get("ok")), None, None, None,
                    None, Outcome.PASS if p.get("ok") else Outcome.FAIL, "check", True,
                    p.get("detail") or None)
        for p in prechecks
    ]


def reported_serial(identity: Mapping[str, Any] | None) -> str | None:
    """The unit's serial as the instrument reports it, or None where it reports none (an
    empty serial; a broadcast protocol's source address is not a serial)."""
    if not identity:
        return None
    s = str(identity.get("serial") or "").strip()
    extra = identity.get("extra") or {}
    if not s or "source_address" in extra:
        return None
    return s


def _norm(s: str) -> str:
    s = s.strip().casefold()
    return str(int(s)) if s.isdigit() else s


def serial_match(typed: str, reported: str | None) -> bool | None:
    """Whether the typed serial is the reported one (case, spaces and leading zeros of a
    numeric serial ignored); None when the instrument reports none."""
    if reported is None:
        return None
    return _norm(typed) == _norm(reported)


def serial_measurement(typed: str, reported: str | None) -> Measurement:
    """The serial typed by the operator against the instrument's (informative: a mismatch is
    a ``WARNING``)."""
    match = serial_match(typed, reported)
    outcome = (Outcome.NOT_JUDGED if match is None else Outcome.PASS if match
               else Outcome.WARNING)
    note = ("the instrument reports no serial" if match is None else
            f"typed {typed!r}, instrument reports {reported!r}")
    return Measurement("serial match", None, match, None, None, None, None, outcome, "check",
                       False, note)


__all__ = [
    "FAIL",
    "INCONCLUSIVE",
    "NOT_JUDGED",
    "OUTCOMES",
    "PASS",
    "RULES",
    "RULE_TEXT",
    "WARNING",
    "Limits",
    "Measurement",
    "axis_measurements",
    "combine",
    "decide",
    "informative",
    "judge",
    "limits_from_config",
    "overall",
    "precheck_measurements",
    "reported_serial",
    "serial_match",
    "serial_measurement",
]
