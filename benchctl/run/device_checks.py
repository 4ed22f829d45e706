"""The prechecks made on the open devices and the host, once the stand loop holds the stand:
the loop's real-time priority (``realtime``), the host's fitness (``host_check``), the
instrument's rate and its agreement with the stand at rest, then the stand enabled and at zero
(``rate_and_zero``). Each is recorded as the run's precheck (``benchctl.run.prechecks``)."""

from __future__ import annotations

import logging

from benchctl.run import fitness
from benchctl.run import prechecks as pc
from benchctl.run.context import RunContext
from benchctl.run.realtime import RealtimeResult, not_requested
from benchctl.run.stand_loop import StandLoop

log = logging.getLogger(__name__)

RATE_WINDOWS = 3  # the instrument's rate is measured over up to this many windows
REALTIME_ANSWER_S = 2.0  # the stand loop says whether it got real-time priority within this


def realtime(run: RunContext, loop: StandLoop) -> None:
    """Record and say whether the stand loop thread got ``run.realtime_priority``."""
    assert run.writer is not None
    priority = run.cfg.run.realtime_priority
    if priority is None:
        return
    if run.clock.virtual:
        got = not_requested("simulated time")
    else:
        loop.realtime_known.wait(REALTIME_ANSWER_S)
        got = loop.realtime or RealtimeResult(
            priority, False, f"real-time priority {priority}: not granted: the stand loop "
            f"did not answer within {REALTIME_ANSWER_S:g} s")
    run.writer.event("realtime_priority", **got.to_dict())
    run.display.message(
        got.detail if got.granted or got.requested is None
        else f"{got.detail}; the run goes on at normal priority"
    )


def host_check(run: RunContext) -> None:
    """The host fitness check (``run.host_check``): a precheck, not measured on simulated
    time (unless a probe is handed in)."""
    cfg, w = run.cfg, run.writer
    assert w is not None
    skipped = (fitness.SKIP_DISABLED if not cfg.run.host_check.enabled
               else fitness.SKIP_VIRTUAL if run.host_probe is None and run.clock.virtual
               else None)
    if skipped is not None:
        w.event("host_check", skipped=True, reason=skipped)
        run.display.message(skipped)
        return
    check = fitness.host_check(cfg, run.clock, run.supervisor.stop_event,
                               probe=run.host_probe, setter=run.priority_setter)
    run.supervisor.check()  # a fault or a signal while it measured
    warning = check.warning()
    if warning is not None:
        run.host_warnings.append(warning)
        log.warning("%s", warning)
    result = check.check_result()
    shown = (check.line if check.ok
             else f"{check.line}: the run goes on, with a warning in its record"
             if result.ok else f"{check.line}: the run is refused before the stand moves")
    run.precheck(result, shown)


def rate_and_zero(run: RunContext) -> None:
    """The instrument streams at its rate (measured again on a wrong window, up to
    ``RATE_WINDOWS``) and agrees with the stand at rest; then the stand is enabled (from here
    on the cleanup ramps it to zero) and brought to zero."""
    cfg, w, rec, stand = run.cfg, run.writer, run.recorder, run.stand
    assert w is not None and rec is not None and stand is not None

    # a window with the wrong rate is measured again (a host or a bus held up for a moment
    # skews one window; an instrument at the wrong rate fails every one)
    for attempt in range(1, RATE_WINDOWS + 1):
        rec.collect(True)
        t0 = run.clock.monotonic()
        run.wait(cfg.run.precheck_window_s)
        samples = rec.collect(False)
        window = run.clock.monotonic() - t0
        rate = pc.check_instrument_rate(
            samples,
            window,
            cfg.instrument.expected_rate_hz,
            cfg.run.instrument_rate_tolerance,
            run.axes,
        )
        if rate.ok or attempt == RATE_WINDOWS:
            break
        w.event("precheck", **rate.to_dict(), attempt=attempt, measured_again=True)
        run.display.message(
            f"precheck {rate.name}: {rate.detail}; measuring again ({attempt}/{RATE_WINDOWS})"
        )
    run.precheck(rate)
    here = stand.read_sample()
    run.precheck(
        pc.check_static_agreement(
            samples, here.angle_deg, cfg.instrument.static_tolerance_deg, run.axes
        )
    )
    stand.enable()
    run.moved = True  # from here on the cleanup ramps to zero
    if any(abs(v) > cfg.stand.zero_tolerance_deg for v in here.angle_deg.values()):
        run.display.message("bringing the stand to zero")
        stand.go_to_zero()
    run.precheck(pc.check_stand_at_zero(stand.read_sample(), cfg.stand.zero_tolerance_deg))
