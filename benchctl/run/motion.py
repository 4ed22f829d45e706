"""The motion phase: a stand loop playing a plan, watched by the one watch loop (``watch``).

The motion, the mounting check's tilt and the equalisation pre-test are each played by a stand
loop of their own (``new_loop``) and watched the same way: every 0.1 s the loop alive and
cycling, the instrument talking, a time limit, the display (``check_loop``, ``snapshot``). The
motion adds its own watches: the running excitation estimates and the precision checks, which
may end it early (``benchctl.run.precision``)."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from typing import Any

from benchctl.analysis.fidelitylimits import limits_of, reach_of
from benchctl.analysis.runningfidelity import RunningFidelity
from benchctl.config import BenchConfig
from benchctl.errors import RecordingError, SafetyAbort
from benchctl.run.context import RunContext
from benchctl.run.display import Snapshot
from benchctl.run.evaluation import analysis_window, evaluation
from benchctl.run.plan import MotionPlan
from benchctl.run.precision import (
    PrecisionCheck,
    PrecisionWatch,
    check_window,
    profile_period,
    whole_periods_in,
)
from benchctl.run.stand_loop import HOST_STALL_S, LoopLimits, StandLoop
from benchctl.run.state import StateMachine

STALL_S = 3.0  # the stand loop silent this long (beyond device timeouts) is a fault
FIDELITY_EVERY_S = 1.0  # the running excitation estimate: updated this often during the motion


def new_loop(run: RunContext, plan: MotionPlan, machine: StateMachine | None = None) -> StandLoop:
    """A stand loop for ``plan`` (not started); ``machine``: whose states it moves (the
    run's; the pre-test its own, so the run stays in ``equalising``)."""
    cfg = run.cfg
    assert run.stand is not None and run.recorder is not None
    return StandLoop(
        run.stand,
        run.recorder,
        run.supervisor,
        run.machine if machine is None else machine,
        plan,
        LoopLimits(
            angle_deg=cfg.stand.limits.angle_deg,
            tracking_tolerance_deg=cfg.stand.tracking_tolerance_deg,
            following_lag_s=cfg.stand.following_lag_s,
            profile_tolerance_deg=cfg.run.profile_tolerance_deg,
            silence_timeout_s=cfg.instrument.silence_timeout_s,
            heartbeat_period_s=cfg.stand.heartbeat_period_s,
            sample_rate_hz=cfg.stand.sample_rate_hz,
            zero_tolerance_deg=cfg.stand.zero_tolerance_deg,
            rate_deg_s=cfg.stand.limits.rate_deg_s,
            accel_deg_s2=cfg.stand.limits.accel_deg_s2,
            buffer_s=cfg.stand.buffer_s,
        ),
        clock=run.clock,
        host_cost_s=cfg.sim.host_cost_s if cfg.sim is not None and run.clock.virtual else 0.0,
        realtime_priority=cfg.run.realtime_priority,
        priority_setter=run.priority_setter,
    )


def play(run: RunContext, loop: StandLoop, what: str = "pre-test") -> None:
    """Play ``loop``'s plan (``what``: the pre-test, the mounting check) to its end,
    watching it as the motion is watched (faults, stalls, a silent instrument, a time
    limit)."""
    watch(run, loop, what, loop.plan.duration_s)
    run.supervisor.check()


def watch(
    run: RunContext,
    loop: StandLoop,
    what: str,
    duration_s: float,
    before: Callable[[float, float], None] | None = None,
    after: Callable[[float, float], None] | None = None,
) -> None:
    """The one watch loop over a stand loop playing ``what`` until its motion is done or a
    fault is raised: every 0.1 s the loop's health (``check_loop``), a time limit (the
    motion's ``duration_s`` and a minute for settling and slack: a hung loop cannot hang
    the run) and the display; ``before``/``after`` (given the time) add the motion's own
    watches, before the health check and after the time limit (each called with the time
    and the time the watch began)."""
    loop.begin_motion()
    limit = duration_s + 60.0
    t0 = run.clock.monotonic()
    t_wake = t0
    resumed = -math.inf  # this thread's last wake-up after a stall of the process
    while not loop.motion_done.wait(0.1):
        if run.supervisor.faulted:
            break
        now = run.clock.monotonic()
        if before is not None:
            before(now, t0)
        if now - t_wake > 0.1 + HOST_STALL_S:  # this process was held up: the threads
            resumed = now  # get a moment to catch up before their silence counts
        t_wake = now
        check_loop(run.cfg, loop, now, resumed, what)
        if now - t0 > limit:
            raise SafetyAbort(f"{what} did not finish within {limit:.0f} s")
        if after is not None:
            after(now, t0)
        run.display.update(snapshot(run))


def check_loop(cfg: BenchConfig, loop: StandLoop, now: float, resumed: float, what: str) -> None:
    """The main thread's watch over a stand loop playing ``what``: the loop alive, cycling,
    and the instrument talking — counted from ``resumed``, this process's last wake-up
    after a stall of its own, so a held-up host is never taken for a silent device."""
    if not loop.alive:
        raise SafetyAbort(f"stand loop ended without finishing the {what}")
    last = loop.t_last_cycle
    stall = STALL_S + cfg.stand.timeout_s * (cfg.stand.retries + 1)
    if last is not None and now - max(last, resumed) > stall:
        raise SafetyAbort(f"stand loop stalled: no cycle for {now - last:.1f} s")
    silent = min(loop.instrument_silence(now), now - resumed)
    if silent > cfg.instrument.silence_timeout_s + 0.5:
        raise SafetyAbort(
            f"instrument silent: no sample for {silent:.2f} s "
            f"(silence_timeout_s = {cfg.instrument.silence_timeout_s} s)"
        )


def motion(run: RunContext) -> None:
    """The motion: fade-in → running → fade-out, played by the stand loop waiting in hold and
    watched by the one watch loop, with the running excitation estimates
    (``run.excitation.abort_run``) and the precision checks (``run.precision``)."""
    loop = run.loop
    assert loop is not None and run.recorder is not None
    fidelity: list[Any] | None = None  # the running excitation estimates, once moving
    t_fidelity: float | None = None  # the last update (first: the watch's start)

    def excitation(now: float, t0: float) -> None:
        nonlocal fidelity, t_fidelity
        if t_fidelity is None:
            t_fidelity = t0
        if fidelity is None and loop.t_motion_start is not None:
            fidelity = excitation_watch(run)
        if fidelity and now - t_fidelity >= FIDELITY_EVERY_S:
            t_fidelity = now
            for rf in fidelity:
                rf.update()
                why = rf.abort_reason()
                if why:
                    raise SafetyAbort(why)

    def precision(now: float, _t0: float) -> None:
        if run.precision is None and loop.t_motion_start is not None:
            run.precision = precision_watch(run)
        if run.precision is not None:
            precision_poll(run, now)

    watch(run, loop, "motion", run.plan.duration_s, excitation, precision)
    run.recorder.stand_taps.clear()
    run.supervisor.check()


def excitation_watch(run: RunContext) -> list[Any]:
    """The running excitation estimates (``run.excitation.abort_run``): one per axis with
    a harmonic table and a band to judge, listening to the stand's samples from now on."""

    ex = run.cfg.run.excitation
    motion = run.prep.motion
    tables = getattr(motion, "tables", None) or {}
    if not ex.abort_run or getattr(motion, "segments", None) or run.recorder is None:
        return []
    assert run.loop is not None and run.loop.t_motion_start is not None
    out = []
    for axis in run.axes:
        if axis not in tables:
            continue
        rf = RunningFidelity(tables[axis], analysis_window(run), run.loop.t_motion_start,
                             limits=limits_of(ex), reach=reach_of(run.cfg.stand.limits),
                             axis=axis)
        if not rf.bands:
            continue

        def tap(s: Any, rf: RunningFidelity = rf, axis: str = axis) -> None:
            rf.add(s.t_host, s.angle_deg.get(axis, math.nan))

        run.recorder.stand_taps.append(tap)
        out.append(rf)
    return out


def precision_watch(run: RunContext) -> PrecisionWatch | None:
    """The precision checks, once moving (None when no precision was requested)."""
    requested = run.prep.meta.get("precision_requested")
    loop, plan = run.loop, run.plan
    if requested is None or loop is None or loop.t_motion_start is None:
        return None
    period = profile_period(run.prep.motion, run.axes, "run.precision")
    t_start = loop.t_motion_start
    steady = plan.duration_s - plan.fade_in_s - plan.fade_out_s

    def analyse(window: tuple[float, float]) -> dict[str, Any]:
        return check_window(run.path, evaluation(run, window, t_start))

    return PrecisionWatch(analyse, float(requested), t_start + plan.fade_in_s, period,
                          whole_periods_in(steady, period), clock=run.clock)


def precision_poll(run: RunContext, now: float) -> None:
    """A finished check: into the recording; when it says stop, the stand loop fades out."""
    watch, loop = run.precision, run.loop
    assert watch is not None and loop is not None
    check: PrecisionCheck | None = watch.poll(now)
    if check is None:
        return
    assert run.writer is not None
    with contextlib.suppress(RecordingError):
        run.writer.event("precision_check", **check.to_dict())
    msg = (f"precision check, {check.periods} period(s): "
           + ("σ " + ", ".join(f"{a} {c.sigma:.4f}° ±{100 * c.precision:.2f} %"
                               for a, c in check.axes.items()) + "; " if check.axes else "")
           + check.decision.reason)
    run.display.message(msg)
    if check.decision.stop and loop.ended_early is None:
        loop.request_end(reason=check.decision.reason, precision=check.precision,
                         requested=watch.requested, periods=check.periods,
                         check_window=list(check.window))


def snapshot(run: RunContext) -> Snapshot:
    """What the display shows of the run now."""
    assert run.recorder is not None and run.loop is not None
    live = run.recorder.live
    elapsed = remaining = None
    if live.t_motion_start is not None:
        elapsed = run.clock.monotonic() - live.t_motion_start
        remaining = run.loop.plan.duration_s - elapsed  # shorter after an early stop
    return Snapshot(
        state=str(run.machine.state),
        elapsed_s=elapsed,
        remaining_s=remaining,
        stand_deg=dict(live.stand.angle_deg) if live.stand else {},
        instrument_deg={a: live.instrument.angle_deg.get(a, float("nan")) for a in run.axes}
        if live.instrument
        else {},
        tracking_error_deg=dict(live.tracking_error_deg),
        sigma_deg=run.recorder.sigma.sigma(),
        missed_cycles=run.loop.missed_cycles,
        instrument_samples=run.recorder.n_instrument,
        serial=run.opts.serial,
        operator=run.opts.operator,
        limit_deg=run.cfg.run.limit_sigma_deg,
        cycles=run.loop.cycles,
        rejoins=run.loop.rejoins,
        mode=run.plan.mode,
        underruns=run.loop.underruns,
        sigma_judged_after_s=sigma_judged_after(run),
    )


def sigma_judged_after(run: RunContext) -> float | None:
    """Motion time from which the running σ is judged live: the fade-in and one whole
    period of a periodic multisine (every line excited once); None without a period."""
    plan = run.plan
    periods = [t.period_s for t in (plan.tables or {}).values()]
    if not periods or None in periods or getattr(run.prep.motion, "segments", None):
        return None
    return plan.fade_in_s + max(float(p) for p in periods if p is not None)
