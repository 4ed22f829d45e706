"""The mounting check (``run.mounting_check``): the tilt played on a stand loop of its own
(``mounting_check``) and its verdict from the tilt's samples: the stand's measured angles
interpolated at the instrument's instants, the response fitted and judged (``mounting_result``,
``benchctl.run.mounting``)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from benchctl.config import BenchConfig, axis_map
from benchctl.errors import (
    DataError,
)
from benchctl.run import mounting as mt
from benchctl.run import prechecks as pc
from benchctl.run.context import RunContext
from benchctl.run.live import RunningSigma
from benchctl.run.motion import new_loop, play
from benchctl.run.prepare import mounting_plan
from benchctl.run.state import StateMachine


def mounting_result(
    stand_rows: list[tuple[float, dict[str, float]]],
    samples: list[Any],
    axes: tuple[str, ...],
    cfg: BenchConfig,
) -> pc.CheckResult:
    """The mounting check's precheck from the tilt's stand samples ((t_host, angles) each) and
    instrument samples: the stand's measured angles interpolated at the instrument's instants,
    the response fitted and judged (``benchctl.run.mounting``)."""

    mc = cfg.run.mounting_check
    mapping = axis_map(cfg.instrument.axes)
    values: dict[str, Any] = {
        "axes": list(axes), "tilt_deg": mc.tilt_deg, "gain_tolerance": mc.gain_tolerance,
        "cross_tolerance": mc.cross_tolerance,
        "instrument_axes": {a: {"output": o, "sign": sg} for a, (o, sg) in mapping.items()},
    }
    name = "mounting"
    ts = np.array([t for t, _ in stand_rows], dtype=float)
    order = np.argsort(ts, kind="stable")
    readings = sorted({r for s in samples for r in s.angle_deg},
                      key=lambda r: (r not in axes, axes.index(r) if r in axes else 0, r))
    ti = np.array([s.t_host for s in samples], dtype=float)
    try:
        if not readings:
            raise DataError("mounting check: no instrument sample during the tilt")
        x = {a: np.array([stand_rows[i][1].get(a, math.nan) for i in order], dtype=float)
             for a in axes}
        y = {r: np.array([s.angle_deg.get(r, math.nan) for s in samples], dtype=float)
             for r in readings}
        resp, delay = mt.fit_sampled(ts[order], x, ti, y)
    except DataError as e:
        return pc.CheckResult(name, False, f"{e} (run.mounting_check)", values)
    values["response"] = resp.to_dict()
    values["delay_s"] = delay
    where = str(cfg.source) if cfg.source is not None else "the bench config"
    verdict = mt.judge(resp, axes, mapping, mc.gain_tolerance, mc.cross_tolerance, where)
    values["findings"] = {f.reading: f.kind for f in verdict.findings}
    if verdict.ok:
        seen = ", ".join(f"{r} {resp.gain[r][a]:.3f}× the stand's {a}"
                         for r in readings for a in axes if r == a)
        return pc.CheckResult(name, True, f"mounted as configured: {seen}", values)
    return pc.CheckResult(name, False, verdict.detail, values)


def mounting_check(run: RunContext) -> None:
    """The mounting check (``run.mounting_check``; ``benchctl.run.mounting``): each axis
    of the profile tilted in turn to a few degrees and back, on a stand loop of its own
    (the same path as the motion: setpoints or the trajectory queue, every limit and
    tracking check), recorded like the rest of the run (``mounting_start``,
    ``mounting_motion_start``: outside the analysis window, which starts at the profile's
    ``motion_start``). The instrument's response is fitted and judged: a unit mounted
    reversed or with its axes swapped is a precheck FAILED (the run refused, the stand
    back at rest at zero — the tilt ends there, and the stand's own ramp to zero makes
    sure — then the one cleanup path)."""
    mc = run.cfg.run.mounting_check
    cfg, w, rec, stand = run.cfg, run.writer, run.recorder, run.stand
    if not mc.enabled:
        return
    assert w is not None and rec is not None and stand is not None and run.loop is not None
    plan = run.prep.tilt or mounting_plan(cfg, run.axes, str(cfg.source or "the config"))
    mode = plan.mode
    stand_rows: list[tuple[float, dict[str, float]]] = []

    def tap(s: Any) -> None:
        stand_rows.append((s.t_host, dict(s.angle_deg)))

    w.event("mounting_start", axes=list(run.axes), tilt_deg=mc.tilt_deg, hold_s=mc.hold_s,
            duration_s=plan.duration_s, mode=mode)
    run.display.message(
        f"mounting check: {' then '.join(run.axes)} tilted to +{mc.tilt_deg:g}° and back "
        f"({plan.duration_s:.0f} s)")
    run.loop.stop()  # the hold loop: the tilt's own loop takes the stand over
    run.loop = loop = new_loop(run, plan, StateMachine(run.clock))
    loop.motion_event = "mounting_motion_start"
    rec.collect(True)
    rec.stand_taps.append(tap)
    try:
        loop.start()
        play(run, loop, "mounting check")
    finally:
        rec.stand_taps.remove(tap)
        samples = rec.collect(False)
    # the live σ: the profile's motion only
    rec.sigma = RunningSigma(run.axes, clock=run.clock)
    loop.stop()
    # the tilt ended at rest near zero (the loop's settle): now at zero with the stand's
    # own "moving" off, as a table or a pre-test needs to start
    stand.go_to_zero()
    run.loop = new_loop(run, run.plan)
    run.loop.start()  # hold until the motion (or the pre-test) begins
    result = mounting_result(stand_rows, samples, run.axes, cfg)
    w.update_meta(mounting_check=result.values)
    run.precheck(result)
