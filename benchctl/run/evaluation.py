"""The evaluate phase: the window the verdict is made on, the recording evaluated over it on the
one evaluation path (``benchctl.evaluate``, the same the precision checks take), each axis
judged, and the report with its measurements, warnings and why the motion ended."""

from __future__ import annotations

import logging
import math
from typing import Any

from benchctl.evaluate import EvaluationOptions, EvaluationRequest, RunProfile, evaluate
from benchctl.results.measurements import (
    WARNING,
    Measurement,
    axis_measurements,
    limits_from_config,
    precheck_measurements,
    reported_serial,
    serial_measurement,
)
from benchctl.run.context import RunContext
from benchctl.run.meta import REPORT_META, deviations
from benchctl.run.precision import ended_summary, relative_halfwidth, whole_periods_in
from benchctl.run.report import Report, axis_verdict

log = logging.getLogger(__name__)


def analysis_window(run: RunContext) -> tuple[float, float]:
    """The window the verdict is made on (host s): the profile's steady part (fades excluded),
    the whole periods up to a stop the precision checks asked for, or the whole motion when it
    is mostly fades."""
    assert run.loop is not None and run.loop.t_motion_start is not None
    p = run.plan
    t0 = run.loop.t_motion_start
    early = run.loop.ended_early
    if early is not None and run.precision is not None:  # the whole periods to the stop
        lo = t0 + p.fade_in_s
        n = whole_periods_in(early["t_profile_s"] - p.fade_in_s, run.precision.period_s)
        return lo, lo + n * run.precision.period_s
    lo, hi = t0 + p.fade_in_s, t0 + p.duration_s - p.fade_out_s
    if hi - lo < 0.5 * p.duration_s:  # mostly fades: analyse the whole motion
        lo, hi = t0, t0 + p.duration_s
    return lo, hi


def evaluation(run: RunContext, window: tuple[float, float], t_motion_start: float | None,
               **more: Any) -> EvaluationRequest:
    """What the verdict and the precision checks evaluate over ``window``: every axis, the
    bench config's analysis options and settling, the profile as this run plays it (its
    motion started at ``t_motion_start``, host s); the recording is still open (no
    integrity to check yet)."""
    a = run.cfg.run.analysis
    return EvaluationRequest(
        axes=run.axes, window=window, options=EvaluationOptions.of_config(a),
        settle_s=a.departure_settle_s,
        profile=RunProfile.of_run(run.prep.motion, t_motion_start, run.cfg),
        require_intact=False, source=str(run.path), **more)


def analyse(run: RunContext, window: tuple[float, float]) -> tuple[Report, dict[str, Any]]:
    """The verdict: the recording evaluated over ``window`` (``benchctl.evaluate``: the
    profile as this run plays it, the bench config's analysis options, the underruns and
    rejoins left out with the settling it states), each axis judged, the report."""
    t0 = run.loop.t_motion_start if run.loop is not None else None
    ev = evaluate(run.path, evaluation(run, window, t0, excitation_alarm=True))
    results: dict[str, Any] = dict(ev.results)
    for msg in ev.alarms.values():
        log.warning("%s", msg)
    verdicts = {axis: axis_verdict(axis, res, run.cfg.run.limit_sigma_deg, run.rule)
                for axis, res in results.items()}
    meta = {k: run.meta.get(k) for k in REPORT_META}
    meta["timing"] = run.cfg.timing.to_dict()  # the bench's offset, applied by rec.pair
    measured, warnings = measurements(run, verdicts, results)
    report = Report(verdicts, run.path, meta, run.stats(), window,
                    decision_rule=run.rule, measurements=measured,
                    deviations=deviations(run.prep.meta), warnings=warnings)
    report.ended = ended(run, report)
    return report, results


def measurements(run: RunContext, verdicts: dict[str, Any],
                 results: dict[str, Any]) -> tuple[list[Measurement], list[str]]:
    """Every result with its limits and outcome (benchctl.results.measurements), and the
    warnings for the record: the analyses', a serial mismatch."""
    limits = limits_from_config(run.cfg)
    out = precheck_measurements(run.prechecks)
    for axis, v in verdicts.items():
        out.extend(axis_measurements(axis, v.to_dict(full=True), limits, run.rule))
    warnings = [*run.host_warnings]
    warnings += [f"{axis}: {w}" for axis, r in results.items()
                 for w in getattr(r, "warnings", [])]
    meta = run.writer.meta if run.writer is not None else run.meta
    dut = (meta.get("devices") or {}).get("instrument")
    sm = serial_measurement(run.opts.serial, reported_serial(dut))
    if run.cfg.unit.serial_check != "require":  # else its precheck says it, decisive
        out.append(sm)
    if sm.outcome == WARNING:
        warnings.append(f"serial mismatch: {sm.note}")
        log.warning("serial mismatch: %s", sm.note)
    return out, warnings


def ended(run: RunContext, report: Report) -> dict[str, Any]:
    """Why the motion ended, and the precision the verdict reached (the report's
    ``ended``)."""
    loop = run.loop
    early = None if loop is None else loop.ended_early
    motion_s = None
    if loop is not None and loop.t_motion_start is not None and loop.t_motion_end is not None:
        motion_s = loop.t_motion_end - loop.t_motion_start
    precision = max((relative_halfwidth(v.sigma_deg, v.sigma_ci95_deg)
                     for v in report.axes.values()), default=math.inf)
    period = None
    tables = getattr(run.prep.motion, "tables", None) or {}
    if tables and not getattr(run.prep.motion, "segments", None):
        period = next(iter(tables.values())).period_s
    lo, hi = report.window
    periods = None if not period else whole_periods_in(hi - lo, float(period))
    return ended_summary(early, precision, run.prep.meta.get("precision_requested"),
                         motion_s, periods, period)
