"""The equalisation phase (``run.equalise``): a pre-test played and recorded, the stand's
response on the profile's lines estimated from it, and the drive corrected and checked like any
motion: a new plan, the prepared one left as it was."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np

from benchctl.analysis.equalise import corrected_table, estimate_response, response_at
from benchctl.analysis.fidelitylimits import reach_of
from benchctl.errors import DataError, LimitError
from benchctl.profiles import check_motion
from benchctl.recording import load_recording
from benchctl.run.context import RunContext
from benchctl.run.live import RunningSigma
from benchctl.run.motion import new_loop, play
from benchctl.run.plan import MotionPlan, make_plan
from benchctl.run.prepare import motion_rate_hz
from benchctl.run.state import RunState, StateMachine

log = logging.getLogger(__name__)


def equalise(run: RunContext) -> MotionPlan:
    """The equalisation pre-test (``run.equalise``): the low-level multisine played and
    recorded, the stand's response on the profile's lines estimated, the drive corrected
    and checked against the limits like any motion; the main motion's loop then waits in
    hold with the corrected plan, which is returned (the run's plan is not changed here)."""

    pre, w, stand = run.prep.pretest, run.writer, run.stand
    assert pre is not None and w is not None and stand is not None and run.loop is not None
    cfg, eq = run.cfg, run.cfg.run.equalise
    run.machine.to(RunState.EQUALISING, "pre-test")
    run.loop.stop()  # the hold loop: the pre-test's own loop takes the stand over
    run.loop = loop = new_loop(run, pre.plan, StateMachine(run.clock))
    loop.motion_event = "equalise_motion_start"
    if pre.plan.mode == "table":
        assert pre.plan.tables is not None
        stand.upload_table(pre.plan.tables)
        w.event("table_uploaded", axes=list(pre.plan.tables), pretest=True)
    w.event("equalise_start", level=eq.level, duration_s=pre.plan.duration_s,
            axes={a: d.to_dict() for a, d in pre.designs.items()})
    run.display.message(f"equalisation pre-test: {pre.plan.duration_s:.1f} s at "
                        f"{eq.level:g} × the profile's amplitudes")
    loop.start()
    play(run, loop)
    t_start = loop.t_motion_start
    assert t_start is not None
    # the pre-test's loop holds the stand (heartbeat, samples, checks) until the main
    # motion's loop takes over, however long the correction takes to compute
    if run.recorder is not None:  # the live σ: the profile's motion only
        run.recorder.sigma = RunningSigma(run.axes)
    # the response per axis, from the recording (the same instants the verdict will use)
    rec = load_recording(run.path)
    target = run.prep.motion
    rate = motion_rate_hz(cfg.stand)
    drives, report = {}, {}
    for axis, design in pre.designs.items():
        tr, xr, _, _ = rec.pair(axis, window=False)
        drive = None
        if cfg.stand.mode == "stream":  # the stand's input: the setpoints as they went out
            drive = (rec.column("setpoints", "t_send"), rec.column("setpoints", f"{axis}_deg"))
        try:
            resp = estimate_response(tr, xr, design, t_start, drive)
        except DataError as e:
            raise DataError(f"{run.path}: equalisation pre-test on {axis}: {e}") from None
        tab = target.tables[axis]
        h, sd = response_at(resp, tab.freq_hz)
        corr = corrected_table(tab, h, sd, reach_of(cfg.stand.limits), rate,
                               min_gain_db=eq.min_gain_db, max_boost_db=eq.max_boost_db,
                               max_uncertainty_db=eq.max_uncertainty_db)
        drives[axis] = corr.drive
        report[axis] = {**corr.to_dict(), "pretest": design.to_dict(),
                        "pretest_response": resp.to_dict()}
    drive = dataclasses.replace(target, table_by_axis=drives)
    try:  # the corrected drive through the same checks as any motion
        result = check_motion(drive, cfg.stand.limits, rate_hz=rate)
    except LimitError as e:
        raise LimitError(
            f"{run.path}: the equalised drive (field stand.limits): {e}"
        ) from None

    def evaluate(t: np.ndarray) -> dict[str, np.ndarray]:
        return {a: np.asarray(v, dtype=float) for a, v in result.motion.evaluate(t).items()}

    old = run.plan  # the prepared plan stays as it was: equalisation makes a new one
    plan = make_plan(evaluate, old.axes, old.duration_s, 1.0 / old.period_s,
                     old.fade_in_s, old.fade_out_s, mode=old.mode,
                     tables=dict(result.motion.tables or {}))
    disturbed = {"missed_cycles": loop.missed_cycles, "rejoins": loop.rejoins,
                 "underruns": loop.underruns}
    summary = {"level": eq.level, "drive_check": result.to_dict(), "axes": report,
               "pretest_stats": disturbed}
    if any(disturbed.values()):  # the stand left the pre-test's lines for a moment
        msg = ("equalisation: the pre-test's motion was disturbed ("
               + ", ".join(f"{k} {v}" for k, v in disturbed.items() if v)
               + "): the response on its lines may be off by tenths of a dB")
        summary["warning"] = msg
        log.warning("%s", msg)
        run.display.message(msg)
    w.event("equalise_done", **summary)
    w.update_meta(equalisation=summary)
    run.meta["equalisation"] = summary
    for axis, r in report.items():
        bad = r["not_corrected"]
        run.display.message(
            f"equalised {axis}: response {min(r['gain_db']):+.2f} … {max(r['gain_db']):+.2f} dB"
            f" on {len(r['freq_hz'])} lines; "
            + (f"{len(bad)} line(s) not fully corrected" if bad else "every line corrected"))
    if plan.mode == "table":
        assert plan.tables is not None
        stand.upload_table(plan.tables)
        w.event("table_uploaded", axes=list(plan.tables))
    run.supervisor.check()  # a fault while the correction was computed
    loop.stop()
    run.loop = new_loop(run, plan)
    run.loop.start()  # hold until the motion begins
    return plan
