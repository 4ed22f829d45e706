"""The whole test, start to verdict: ``run_test(cfg, profile_path, options) -> RunResult``.

This module keeps the phases, in order, and the abort path; each phase's work is in a module of
its own, taking the run as a ``RunContext`` (``benchctl.run.context``). Order of things (each
state change is an event in the recording):

1. **prepare**, before anything opens: the profile is loaded, synthesised and checked against
   the stand limits, its axes the stand's and the instrument's, the plan made
   (``benchctl.run.prepare``: the same for the CLI, plans and the Python API); bad input →
   ``BenchError``, exit 2, nothing moves, no recording. The prepared plan is never changed;
2. on a real stand, its lock is taken (one run per stand: ``benchctl.run.lock``; a stand in use
   is refused with ``StandInUse`` naming the holder, nothing opened); the recording is created
   (metadata, ``benchctl.run.meta``: config, profile with seed, serial, operator, station,
   software version, start time), with the run's log ``benchctl.log``; with a ``sim:`` section
   the simulators are started (their output in the recording's ``sim.log``);
3. **prechecks**: disk space, the profile within the limits; the **devices** opened
   (``benchctl.run.devices``: their close pushed on the run's ``ExitStack``, the backstop of
   the cleanup path), each answers and identifies itself (identities into the metadata), stand
   ready and at rest; the stand loop starts and **holds** the stand (asking for
   ``run.realtime_priority``, recorded whether granted) and the host's scheduling latency is
   measured and judged (``benchctl.run.fitness``; not on simulated time); the instrument
   streams at its rate and agrees with the stand at rest, then the stand is enabled and
   brought to zero (``benchctl.run.device_checks``), the **mounting check** tilts each axis to
   a few degrees and back and refuses a unit mounted reversed or with its axes swapped
   (``run.mounting_check``; ``benchctl.run.mounting_check``), and (table mode) the table is
   uploaded;
4. with ``run.equalise``, **equalising**: a pre-test played, the drive corrected, a new plan
   (``benchctl.run.equalise``);
5. **fade-in → running → fade-out**, driven by the stand loop on the profile's own time and
   watched by the one watch loop (``benchctl.run.motion``);
6. the stand **settles** at rest, is disabled, the devices are closed (the same cleanup path
   an abort takes, here with nothing to ramp);
7. **analysing**: per axis, on the steady part of the profile (fades excluded), measurements
   with their limits judged by the decision rule (``benchctl.run.evaluation``,
   ``benchctl.results.measurements``), verdict, report, archive; → **done**, the recording
   closed ``done``.

Every run — done or aborted — ends with ``record.json`` in the recording
(``benchctl.results.record``); an aborted one says whether the operator stopped it, the
equipment failed or the software did. The run's outputs — the report files, the record and
report.html, the verdict's banner, the index line, the archive — are one list of sinks
(``benchctl.run.outputs``), the same for a done run and an aborted one.

Any fault on the way — from any thread, a signal (SIGINT, SIGTERM, SIGHUP, SIGQUIT), a recording
that cannot be written, or an exception here — goes to the supervisor, and the one cleanup path
(``Session._abort``) ends the run ``aborted`` with the first fault's reason: the safety shutdown
first (``benchctl.run.supervisor.shutdown``: loops stopped, the stand brought to rest, disabled,
the devices closed, the recording closed), then the outputs.

A full disk (ENOSPC, EDQUOT, EFBIG) anywhere — the recording's streams, the report, the record,
the archive's index — is such a fault (``recording: disk full: cannot write <file> …``): the
stand is brought to rest and disabled, ``end.json`` is written in the room the recording kept
for it (``benchctl.recording.writer``), and the run exits 2. A verdict measured before the
outputs failed is kept: printed, in ``end.json`` (``measured``) and in the record
(``abort.measured_verdict``) — but the run is ABORTED, not PASS: its report or record is not
complete.
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchctl.clock import REAL, Clock
from benchctl.clock.virtual import VirtualClock
from benchctl.config import BenchConfig
from benchctl.devices.base import AngleSensor, Stand
from benchctl.errors import DISK_FULL_ERRNOS, ConfigError, RecordingError, SafetyAbort
from benchctl.exits import run_log, set_log_dir
from benchctl.outcomes import ExitCode, Outcome
from benchctl.recording import RecordingWriter
from benchctl.redact import redact
from benchctl.results.measurements import Measurement, precheck_measurements, reported_serial
from benchctl.results.record import abort_kind, write_record
from benchctl.run import fitness
from benchctl.run import prechecks as pc
from benchctl.run.device_checks import host_check, rate_and_zero, realtime
from benchctl.run.devices import (
    SIM_LOG,
    DeviceFactory,
    announce_disturbances,
    close_at_exit,
    identity_of,
    identity_text,
    open_devices,
    recording_dir,
    simulators,
)
from benchctl.run.display import Display, NullDisplay, SafeDisplay
from benchctl.run.equalise import equalise
from benchctl.run.evaluation import analyse, analysis_window
from benchctl.run.lock import stand_lock
from benchctl.run.meta import base_meta, deviations
from benchctl.run.motion import motion, new_loop
from benchctl.run.mounting_check import mounting_check
from benchctl.run.outputs import (
    Console,
    FinishedRun,
    IndexLine,
    RecordFiles,
    ReportFiles,
    ResultsArchive,
    Sink,
    begin_archive,
    emit,
    measured_line,
    record_in,
    stand_lines,
)
from benchctl.run.plan import MotionPlan
from benchctl.run.precision import PrecisionWatch
from benchctl.run.prepare import PreparedMotion, RunOptions, prepare_motion
from benchctl.run.realtime import PrioritySetter
from benchctl.run.recorder import Recorder
from benchctl.run.report import Report, archive, archive_abort, write_report
from benchctl.run.result import RunResult, measured_verdict, stand_after
from benchctl.run.serialized_stand import SerializedStand
from benchctl.run.stand_loop import StandLoop, start_instrument
from benchctl.run.state import RunState, StateMachine
from benchctl.run.supervisor import Supervisor, describe, fault_source, shutdown
from benchctl.text import check_serial

if TYPE_CHECKING:  # imported where used: the archive pulls in SQLAlchemy
    from benchctl.archive.service import RunArchive


log = logging.getLogger(__name__)


# -------------------------------------------------------------------------- the run
class Session:
    """One run. ``run()`` returns a ``RunResult``; it never raises once the recording exists."""

    def __init__(
        self,
        cfg: BenchConfig,
        prepared: PreparedMotion,
        opts: RunOptions,
        display: Display | None = None,
        device_factory: DeviceFactory | None = None,  # default: open_devices on the clock
        start_simulators: bool = False,  # cfg has a sim: section: run them (after the recording)
        supervisor: Supervisor | None = None,  # the caller's (a plan asks a run to stop by it)
        run_archive: RunArchive | None = None,  # begun by run_test: the start's archive work
        *,
        clock: Clock | None = None,  # the run's (default: the supervisor's, else the real one)
        host_probe: fitness.Probe | None = None,  # measures the host (default: measure_host)
        priority_setter: PrioritySetter | None = None,  # the stand loop's (default: the OS's)
    ) -> None:
        if clock is None:
            clock = supervisor.clock if supervisor is not None else REAL
        #: every time read, wait, lock and thread of the run (``benchctl.clock``)
        self.clock = clock
        self.start_simulators = start_simulators
        #: the host fitness check's measurement: handed in, it runs on simulated time too
        self.host_probe = host_probe
        self.priority_setter = priority_setter
        self.host_warnings: list[str] = []  # the host check's, into the record's warnings
        self.run_archive = run_archive
        self.log_path: Path | None = None
        self.cfg = cfg
        self.prep = prepared
        #: the plan the motion plays: the prepared one, or the one equalisation made of it
        self.plan: MotionPlan = prepared.plan
        self.opts = opts
        self.display: Display = display or NullDisplay()
        self.device_factory: DeviceFactory = (
            device_factory if device_factory is not None else partial(open_devices, clock=clock)
        )
        if cfg.unit.serial_pattern is not None:  # the config's form of a serial
            check_serial(opts.serial, "serial", cfg.unit.serial_pattern,
                         f"unit.serial_pattern of {cfg.source or 'the config'}")
        self.out_dir = opts.out_dir or cfg.run.output_dir
        self.path = recording_dir(self.out_dir, opts.serial, clock=clock)
        self.axes = prepared.plan.axes
        self.machine = StateMachine(clock)
        self.supervisor = supervisor if supervisor is not None else Supervisor(clock=clock)
        self.writer: RecordingWriter | None = None
        self.stand: Stand | None = None
        self.sensor: AngleSensor | None = None
        self.loop: StandLoop | None = None
        self.recorder: Recorder | None = None
        self.moved = False
        self.meta: dict[str, Any] = {}
        self._final_stats: dict[str, Any] | None = None
        self.precision: PrecisionWatch | None = None  # the precision checks (run.precision)
        self.prechecks: list[dict[str, Any]] = []  # each precheck's result, as recorded
        self.rule = opts.decision_rule or cfg.run.decision_rule
        self.report: Report | None = None  # the verdict, once the analysis has measured it
        self._end_steps: list[dict[str, Any]] = []  # the cleanup at the motion's normal end
        # where that cleanup left the stand (ShutdownReport.final_state): an abort after it
        # has no stand left open to read
        self._end_final: dict[str, Any] | None = None

    def run(self) -> RunResult:
        """The whole run. Raises (``BenchError``) only when the recording cannot be created;
        after that every way out — a signal (SIGINT, SIGTERM, SIGHUP, SIGQUIT, the run's from
        here on), a fault, a full disk, an exception — is a ``RunResult`` through ``_abort``."""
        self.meta = base_meta(self.cfg, self.opts, self.rule, self.prep.meta)
        self.machine.subscribe(self._on_state)
        self.display = SafeDisplay(self.display)  # a terminal gone (SIGHUP) must not stop cleanup
        with self.supervisor.signals(), contextlib.ExitStack() as stack:
            self._open_recording(stack)
            try:
                if self.start_simulators:
                    self._start_simulators(stack)
                self.supervisor.check()  # a signal while the recording was being created
                self._prechecks()
                self._devices(stack)
                self._hold()
                if self.prep.pretest is not None:
                    self.plan = equalise(self)  # the prepared plan stays as it was
                motion(self)
                self._settle()
                window, report, results = self._evaluate()
                return self._outputs(window, report, results)
            except BaseException as e:  # every way out, the same path
                if not isinstance(e, SafetyAbort) or not self.supervisor.faulted:
                    self.supervisor.fault(RecordingError.disk_full(e, self.path) or e,
                                          fault_source(e))
                return self._abort()
            finally:
                self.display.close()

    # ---- the phases, in order
    def _open_recording(self, stack: contextlib.ExitStack) -> None:
        """The recording, with the run's log (on the run's ``stack``: unwound after the
        cleanup)."""
        try:
            self.writer = RecordingWriter(
                self.path, self.axes, self.meta, on_error=self._recording_failed,
                clock=self.clock,
            )
        except OSError as e:
            full = RecordingError.disk_full(e, self.path)
            if full is not None:  # nothing opened, nothing moved
                raise full from None
            raise ConfigError(
                f"{self.path}: cannot create the recording folder: {e.strerror}"
            ) from None
        self.meta = self.writer.meta
        self.log_path = stack.enter_context(run_log(self.path))
        self.display.message(f"recording to {self.path}")

    def _start_simulators(self, stack: contextlib.ExitStack) -> None:
        """With a ``sim:`` section, the simulators (on the run's ``stack``: they stop after the
        stand is at rest), the run's config pointed at them."""
        assert self.writer is not None
        self.cfg = stack.enter_context(simulators(
            self.cfg, self.path / SIM_LOG, self.clock,
            partial(announce_disturbances, writer=self.writer, display=self.display,
                    supervisor=self.supervisor),
            horizon_s=self.plan.duration_s + 600.0,
        ))
        self.writer.update_meta(config=redact(self.cfg.model_dump(mode="json")))

    def _prechecks(self) -> None:
        """The prechecks before a device opens: disk space, the profile within the limits."""
        self.machine.to(RunState.PRECHECKS)
        self.precheck(pc.check_disk(self.out_dir, self.cfg.run.min_free_disk_mb,
                                    quiet=self.clock.virtual))
        self.precheck(self.prep.check)

    def _devices(self, stack: contextlib.ExitStack) -> None:
        """The devices opened, their close the run's ``stack``'s backstop (the cleanup path
        closes them first), every stand sample and setpoint recorded from here on, cleanup
        included; each device answers and identifies itself, the unit is the one named, the
        stand is ready and at rest."""
        cfg, w = self.cfg, self.writer
        assert w is not None
        stand_raw, self.sensor = self.device_factory(cfg, self.path)
        close_at_exit(stack, stand_raw, self.sensor)
        self.recorder = rec = Recorder(w, self.supervisor, self.axes, clock=self.clock)
        rec.attach(stand_raw)
        stand = SerializedStand(stand_raw, clock=self.clock).as_stand()
        self.stand = stand
        ids = {"stand": identity_of(stand.connect())}
        self.precheck(
            pc.CheckResult("stand answers", True, identity_text(ids["stand"]), ids["stand"])
        )
        ids["instrument"] = identity_of(self.sensor.connect())
        self.precheck(
            pc.CheckResult(
                "instrument answers", True, identity_text(ids["instrument"]), ids["instrument"]
            )
        )
        w.update_meta(devices=ids)
        if cfg.unit.serial_check == "require":  # the unit named must be the one mounted
            self.precheck(pc.check_serial(self.opts.serial, reported_serial(ids["instrument"])))
        status = stand.read_status()
        if status.fault or status.estop:  # latched: the check names the command that clears it
            self.precheck(pc.check_stand_ready(status, None, self.axes, cfg.source))
        self.precheck(pc.check_stand_ready(status, stand.read_sample(), self.axes, cfg.source))

    def _hold(self) -> None:
        """The stand loop holds the stand; the prechecks on the host and the instrument, the
        stand enabled and at zero, the mounting check, then (table mode) the table uploaded."""
        assert self.stand is not None and self.sensor is not None and self.recorder is not None
        self.loop = new_loop(self, self.plan)
        start_instrument(self.sensor, self.recorder)
        self.loop.start()  # hold: heartbeat and stand samples from now on
        realtime(self, self.loop)
        host_check(self)
        rate_and_zero(self)
        mounting_check(self)
        if self.plan.mode == "table" and self.prep.pretest is None:
            assert self.plan.tables is not None and self.writer is not None
            self.stand.upload_table(self.plan.tables)
            self.writer.event("table_uploaded", axes=list(self.plan.tables))

    def _settle(self) -> None:
        """The motion's normal end: the stand at rest, disabled, the devices closed — the same
        cleanup path an abort takes, nothing to ramp; a step that failed is a fault."""
        rep = shutdown(
            stop_loops=self._stop_loops,
            stand=self.stand,
            sensor=self.sensor,
            writer=None,
            state="done",
            reason="",
            moved=False,
        )
        self._final_stats = self.stats()
        # shown and recorded again should the run abort after this (a full disk)
        self._end_steps = [{**st, "when": "motion end"} for st in rep.steps]
        self._end_final = rep.final_state
        self.stand = self.sensor = None  # closed: an abort from here has nothing to move
        self.moved = False
        for step in rep.steps:
            if not step["ok"]:
                raise SafetyAbort(f"cleanup step {step['step']} failed: {step['detail']}")
        self.supervisor.check()

    def _evaluate(self) -> tuple[tuple[float, float], Report, dict[str, Any]]:
        """The verdict over the analysis window (``benchctl.run.evaluation``), kept (printed,
        end.json) should an abort follow."""
        self.machine.advance_to(RunState.ANALYSING)
        window = analysis_window(self)
        report, results = analyse(self, window)
        self.report = report
        self.supervisor.check()  # a signal during the analysis still ends the run
        return window, report, results

    def _outputs(self, window: tuple[float, float], report: Report,
                 results: dict[str, Any]) -> RunResult:
        """The outputs that make the run done (a full disk: raised, the run's abort), the
        recording closed ``done``, then the outputs again on the final data files."""
        assert self.writer is not None
        run = self._finished(report.verdict, report.exit_code, report.verdict,
                             report=report, results=results)
        files = emit(self._sinks(), run)
        self.writer.event("verdict", **report.to_dict(full=False))
        self.machine.to(RunState.DONE)
        self.writer.close(
            "done",
            report.verdict,
            analysis_window=list(window),
            stats=report.stats,
            report=[f.name for f in files if f.parent == self.path],
        )
        # the data files are final now: the record and the report again, with their
        # SHA-256 (the record above stands should this one not be written), the
        # verdict shown, the archive
        again = emit(self._sinks(), replace(run, closed=True))
        return RunResult(
            "done",
            report.verdict,
            report.exit_code,
            self.path,
            report,
            report.stats,
            log=self.log_path,
            record=record_in(again) or record_in(files),
        )

    def _sinks(self) -> list[Sink]:
        """The run's outputs in their order (``benchctl.run.outputs``), each handed its writer
        from here: the same list for a done run and an aborted one."""
        return [
            ReportFiles(write_report),
            RecordFiles(write_record),
            Console(self.display),
            IndexLine(archive, archive_abort),
            ResultsArchive(self.cfg, self.run_archive),
        ]

    def _finished(self, outcome: Outcome, exit_code: ExitCode, reason: str, *,
                  report: Report | None = None, results: dict[str, Any] | None = None,
                  abort: dict[str, Any] | None = None, measured: dict[str, Any] | None = None,
                  closed: bool = False) -> FinishedRun:
        """The run at its end for its outputs: with a report, its measurements, deviations and
        warnings; without one (aborted before the analysis), the prechecks' and the host's."""
        if report is not None:
            measurements: list[Measurement] = report.measurements
            departures, warnings = report.deviations, report.warnings
        else:
            measurements = precheck_measurements(self.prechecks)
            departures, warnings = self._deviations(), list(self.host_warnings)
        return FinishedRun(
            outcome, exit_code, reason, self.path, Path(self.out_dir),
            meta=self.writer.meta if self.writer is not None else self.meta,  # + devices
            decision_rule=self.rule, clock=self.clock, measurements=measurements,
            deviations=departures, warnings=warnings, report=report, results=results or {},
            abort=abort, measured=measured, log=self.log_path, figures=self.cfg.run.figures,
            closed=closed,
        )

    # ---- the abort path
    def _abort(self) -> RunResult:
        """The one cleanup path after the first fault; never raises (each step is guarded)."""
        f = self.supervisor.first
        reason = f.reason if f else "aborted"
        abort: dict[str, Any] = {
            "kind": abort_kind(f.error if f else None, f.source if f else None),
            "reason": reason,
            "source": f.source if f else None,
            "error": type(f.error).__name__ if f else None,
        }
        if f is not None and isinstance(f.error, RecordingError) and f.error.errno in \
                DISK_FULL_ERRNOS and self.writer is not None:
            # a full disk: the room kept for end.json now takes the abort's events and end.json
            with contextlib.suppress(OSError):
                self.writer.release_reserve()
        try:
            self.machine.abort(reason)
        except Exception as e:  # a listener's failure must not skip the cleanup
            log.warning("abort state not recorded: %s", describe(e))
        self.display.message(f"ABORTED: {reason}")
        self.display.message("bringing the stand to rest and closing the recording")
        try:
            stats = self.stats()
        except Exception as e:
            log.warning("run statistics not available: %s", describe(e), exc_info=e)
            stats = {}
        extra: dict[str, Any] = {"stats": stats}
        if self.supervisor.later:
            extra["later_faults"] = [g.reason for g in self.supervisor.later]
        if self._end_steps:  # the stand was brought to rest at the motion's end
            extra["motion_end_shutdown"] = self._end_steps
        measured = measured_verdict(self.report)
        if measured is not None:
            extra["measured"] = measured
            abort["measured_verdict"] = measured["verdict"]
            self.display.message(measured_line(measured))
        rep = shutdown(
            stop_loops=self._stop_loops,
            stand=self.stand,
            sensor=self.sensor,
            writer=self.writer,
            state="aborted",
            reason=reason,
            # the loop's own plan: the mounting check's tilt is streamed even on a table stand
            table_mode=self.loop is not None
            and self.loop.plan.mode == "table"
            and self.loop.t_motion_start is not None,
            moved=self.moved,
            extra=extra,
        )
        steps = [*self._end_steps, *rep.steps]
        abort["shutdown"] = steps  # the record and its report show the cleanup, step by step
        where = stand_after(
            rep.final_state if self.stand is not None or self._end_final is None
            else self._end_final,
            zero_tolerance_deg=self.cfg.stand.zero_tolerance_deg, config=self.cfg.source,
            known=self.stand is not None or self._end_final is not None,
        )
        abort["stand"] = where
        for s in steps:
            self.display.message(f"  {s['step']}: {'ok' if s['ok'] else 'FAILED ' + s['detail']}"
                                 + (f" (at the {s['when']})" if s.get("when") else ""))
        run = self._finished(Outcome.ABORTED, Outcome.ABORTED.exit_code, reason,
                             report=self.report, abort=abort, measured=measured, closed=True)
        record = record_in(emit(self._sinks(), run))
        return RunResult(
            "aborted", reason, Outcome.ABORTED.exit_code, self.path, None, stats, steps,
            log=self.log_path, abort=abort, record=record, measured=measured,
        )

    # ---- what the phases share
    def _on_state(self, old: RunState, new: RunState, t: float, reason: str) -> None:
        if self.writer is not None:
            # a write failure is already a fault of the run (the writer's on_error): the state
            # still moves
            with contextlib.suppress(RecordingError):
                self.writer.event(
                    "state", t_state=t, **{"from": str(old), "to": str(new)}, reason=reason
                )
        self.display.state(str(new), reason)

    def precheck(self, result: pc.CheckResult, shown: str | None = None) -> None:
        """Record and show a precheck (``shown``: its own line instead of the usual one)."""
        assert self.writer is not None
        self.prechecks.append(result.to_dict())
        self.writer.event("precheck", **result.to_dict())
        self.display.message(
            shown or f"precheck {result.name}: {'ok' if result.ok else 'FAILED'} — {result.detail}"
        )
        pc.require(result)
        self.supervisor.check()

    def wait(self, seconds: float) -> None:
        """Wait on the main thread, leaving at once on a fault."""
        if self.supervisor.stop_event.wait(seconds):
            self.supervisor.check()

    def _recording_failed(self, e: RecordingError) -> None:
        """The writer's first failure (disk full…), from whichever thread wrote: a fault."""
        self.supervisor.fault(e, "recording")

    def _stop_loops(self) -> None:
        if self.loop is not None:
            self.loop.stop()
        if self.precision is not None:  # a check still reading the recording: let it finish
            self.precision.join()

    def stats(self) -> dict[str, Any]:
        if self._final_stats is not None:
            return dict(self._final_stats, rows=dict(self.writer.counts) if self.writer else {})
        st: dict[str, Any] = self.loop.stats() if self.loop else {}
        if self.sensor is not None:
            st["instrument_bad_frames"] = self.sensor.stats.bad_total
            st["instrument_bad_by_reason"] = dict(self.sensor.stats.bad)
        if self.writer is not None:
            st["rows"] = dict(self.writer.counts)
        return st

    def _deviations(self) -> list[str]:
        """What departs from the test as specified (``benchctl.run.meta.deviations``)."""
        return deviations(self.prep.meta)


def run_test(
    cfg: BenchConfig,
    profile_path: str | Path,
    opts: RunOptions,
    display: Display | None = None,
    device_factory: DeviceFactory | None = None,
    supervisor: Supervisor | None = None,
    *,
    clock: Clock | None = None,
) -> RunResult:
    """Run one test. Bad input raises ``BenchError`` before anything opens, and so does a stand
    in use by another run (``StandInUse``, naming it: ``benchctl.run.lock``); after that, every
    outcome is a ``RunResult`` (done → exit 0/1/3 by verdict PASS/FAIL/INCONCLUSIVE, aborted →
    exit 2).

    With a ``sim:`` section the simulators run on a free port of the run's own (nothing to lock);
    they start once the recording exists (their output in its ``sim.log``).

    ``supervisor``: the run's, given by the caller, who may end the run through it from another
    thread (``supervisor.fault(SafetyAbort(reason), source)``: the same cleanup path as a signal;
    a fault reported before the run starts ends it as soon as its recording exists). An
    acceptance plan's step timeout does this (``benchctl.plan``).

    ``clock``: the run's (``benchctl.clock``), handed to everything the run builds — the
    supervisor, the recording, the drivers, the loops; default the supervisor's, else the
    real one."""
    if clock is None:
        clock = supervisor.clock if supervisor is not None else REAL
    if cfg.sim is not None and cfg.sim.clock == "virtual" and not clock.virtual:
        if supervisor is not None:
            raise ConfigError(
                f"{cfg.source}: field sim.clock = virtual: this caller's supervisor runs on the "
                "host's time; run it on a VirtualClock (benchctl.clock.virtual)"
            )
        vclock = VirtualClock(epoch=cfg.sim.epoch_utc)
        with vclock.running():
            return run_test(cfg, profile_path, opts, display, device_factory, clock=vclock)
    out_dir = opts.out_dir or cfg.run.output_dir
    set_log_dir(out_dir)  # an unexpected error before the recording exists logs there
    prepared = prepare_motion(cfg, Path(profile_path), opts)
    if device_factory is not None:
        return Session(cfg, prepared, opts, display, device_factory, supervisor=supervisor,
                       run_archive=begin_archive(cfg, Path(out_dir)), clock=clock).run()
    if cfg.sim is not None:
        return Session(cfg, prepared, opts, display, start_simulators=True,
                       supervisor=supervisor,
                       run_archive=begin_archive(cfg, Path(out_dir)), clock=clock).run()
    session = Session(cfg, prepared, opts, display, supervisor=supervisor, clock=clock)
    holder = {
        "command": "benchctl run",
        "serial": opts.serial,
        "operator": opts.operator,
        "start_utc": clock.now_utc().isoformat(timespec="seconds"),
        "config": str(cfg.source) if cfg.source else None,
        "recording": str(session.path),
    }
    # refused here, if in use, before anything connects (the archive's database too)
    with stand_lock(cfg, holder):
        session.run_archive = begin_archive(cfg, Path(out_dir))
        return session.run()


__all__ = [
    "RunOptions",
    "RunResult",
    "Session",
    "describe",
    "run_test",
    "stand_lines",
]
