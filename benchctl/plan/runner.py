"""Running an acceptance plan: ``run_plan(plan, serial=…) -> PlanResult``.

Order of things:

1. **before anything opens**: the plan is read and validated (``benchctl.plan.schema``), the
   bench config loaded, and every step prepared as its run will be (the profile loaded,
   synthesised and checked against the stand limits, the step's limits merged into the
   config and validated). A plan with operator prompts and no way to answer them (no
   terminal, no ``yes``) is refused here. Any of these: ``BenchError``, nothing moved.
2. with a ``sim:`` section in the bench config, the simulators start once for the whole plan
   (their output in the plan folder's ``sim.log``), so the setup and cleanup checks and every
   step talk to the same simulated stand;
3. **setup** actions in order: a prompt answered no, not answered (its input ended, or
   ``prompt_timeout_s`` ran out) or interrupted by a signal (SIGINT, SIGTERM, SIGHUP) ends the
   plan (ABORTED) before anything moves; a check that fails ends it (ABORTED, equipment);
4. **steps** in order, each a real run (``benchctl.run.run_test``) on the bench config with the
   step's limits, its recording and ``record.json`` in the output folder as any run's. A
   step's ``timeout_s`` and the plan's ``timeout_s`` end a running step through the run's own
   abort path (its supervisor is faulted: the stand ramps to rest, the recording is closed
   aborted, the record stored ABORTED). A FAIL or INCONCLUSIVE step with ``on_fail: stop``
   skips the rest; an aborted step (a fault, a timeout, Ctrl-C) or a step that could not start
   always does;
5. **cleanup** actions, always: after a pass, a fail, an abort, a timeout, Ctrl-C. Each action
   runs whatever the one before did (a failure is noted and the next one runs). After a signal
   or an unanswered prompt no further prompt is asked (the plan ends at once);
6. the plan's outcome and exit code, its record ``plan.json`` (in
   ``<output_dir>/plan_<stamp>_<serial>/``), JUnit XML when asked.

**Consent before motion.** The only check that moves the stand is ``ramp_to_zero`` (it enables
the servo, ramps, disables). It runs only when its own prompt, if the action has one, was
answered yes, and either this plan has already moved the stand itself (a step started, or an
earlier ramp) or no prompt so far was refused — answered no, unanswered or interrupted — and
no signal came. So a declined, unanswered or interrupted setup prompt ends the plan with the
stand untouched (not enabled, not moved), wherever it rests.

Exit codes: 0 every step PASS; 1 a step FAILed (a measured fail) and nothing aborted;
2 an abort or an error (a step aborted or could not start, a setup action refused or failed,
a cleanup action failed, a timeout, a signal — at a prompt too); 3 INCONCLUSIVE (guarded rule)
with no FAIL.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from benchctl.clock import REAL, Clock
from benchctl.clock.virtual import VirtualClock
from benchctl.config import BenchConfig, RunConfig, load_config
from benchctl.devices.modbus import open_stand
from benchctl.errors import BenchError, ConfigError, InputError, SafetyAbort
from benchctl.jsonout import dumps
from benchctl.outcomes import ExitCode, Outcome
from benchctl.plan.junit import write_junit
from benchctl.plan.prompts import Asker, terminal_asker
from benchctl.plan.record import validate_plan_record
from benchctl.plan.result import PLAN_SCHEMA_ID, ActionResult, PlanResult, StepResult
from benchctl.plan.schema import Action, Plan, Step, load_plan
from benchctl.plan.timeouts import PlanTimeout, Timers
from benchctl.results.record import load_record
from benchctl.run import RunOptions, run_test
from benchctl.run import prechecks as pc
from benchctl.run.devices import recording_dir, simulators
from benchctl.run.lock import stand_lock
from benchctl.run.prepare import prepare_motion
from benchctl.run.supervisor import Supervisor
from benchctl.text import check_operator, check_serial

log = logging.getLogger(__name__)

PLAN_JSON = "plan.json"
RAMP_TIMEOUT_S = 60.0  # a cleanup/setup ramp_to_zero: at rest at zero within this


# ------------------------------------------------------------------------------- prompts
def _yes(text: str) -> bool:
    log.info("plan prompt answered yes (--yes): %s", text)
    return True


# ------------------------------------------------------------------------------- config
def step_config(cfg: BenchConfig, step: Step, where: str = "") -> BenchConfig:
    """The bench config with the step's limits in its ``run`` section (validated as the
    config's own: a gain_min of the step at or over the config's gain_max is refused)."""
    lim = step.limits
    run = cfg.run
    data = run.model_dump()
    extra = {k: getattr(lim, k) for k in ("gain_min", "gain_max", "phase_deg", "delay_s",
                                          "mean_error_deg") if getattr(lim, k) is not None}
    data["limits"] = {**data["limits"], **extra}
    if lim.sigma_deg is not None:
        data["limit_sigma_deg"] = lim.sigma_deg
    if lim.linearity_spread is not None:
        data["linearity_spread_limit"] = lim.linearity_spread
    if lim.excitation_db is not None:
        data["excitation"] = {**data["excitation"], "alarm_db": lim.excitation_db}
    try:
        new_run = RunConfig.model_validate(data)
    except ValidationError as e:
        msgs = "; ".join(f"{'.'.join(str(p) for p in x['loc'])}: {x['msg']}" for x in e.errors())
        raise ConfigError(
            f"{where}step {step.name!r}: its limits do not fit the bench config's run section: "
            f"{msgs}"
        ) from None
    return cfg.model_copy(update={"run": new_run})


def _now(clock: Clock = REAL) -> str:
    return clock.now_utc().isoformat(timespec="milliseconds")


# ------------------------------------------------------------------------------- the stand
def stand_action(
    cfg: BenchConfig, check: str, holder: dict[str, Any], *, clock: Clock = REAL
) -> str:
    """One stand check of a setup or cleanup (the stand's lock held, the real driver): returns
    its detail, raises ``BenchError`` when it fails.

    - ``stand_at_rest``: the stand ready (no fault, no E-stop, no limit switch), not moving,
      every axis at zero within ``stand.zero_tolerance_deg`` (the run's own prechecks);
    - ``ramp_to_zero``: from wherever it is, a ramp to zero within the limits, at rest, then
      disabled."""

    with stand_lock(cfg, holder):
        stand = open_stand(cfg.stand, clock=clock)
        try:
            stand.connect()
            status = stand.read_status()
            if status.fault or status.estop:  # latched: nothing moves; say how to clear it
                ready = pc.check_stand_ready(status, None, cfg.stand.axes, cfg.source)
                raise SafetyAbort(f"stand not ready: {ready.detail}")
            if check == "ramp_to_zero":
                try:
                    stand.ramp_to_zero(RAMP_TIMEOUT_S)
                finally:
                    with contextlib.suppress(BenchError, OSError):
                        stand.disable()
            status = stand.read_status()
            sample = stand.read_sample()
            ready = pc.check_stand_ready(status, sample, list(sample.angle_deg))
            zero = pc.check_stand_at_zero(sample, cfg.stand.zero_tolerance_deg)
            detail = f"{ready.detail}; {zero.detail}"
            if not (ready.ok and zero.ok):
                raise SafetyAbort(f"stand not at rest at zero: {detail}")
            return detail
        finally:
            with contextlib.suppress(BenchError, OSError):
                stand.close()


# ------------------------------------------------------------------------------- consent
@dataclass
class Consent:
    """What the plan may still do to the stand (see the module notes, *Consent before motion*).

    ``moved``: the plan has moved the stand itself (a step started, a ramp began).
    ``refused``: why the operator's consent is gone (a prompt answered no, unanswered or
    interrupted, a signal), "" while it stands. ``stopped``: why no further prompt is asked
    (a signal, an unanswered prompt), "" while prompts may be asked."""

    moved: bool = False
    refused: str = ""
    stopped: str = ""
    signal: str = ""  # the signal that interrupted the plan ("interrupted by SIGTERM")

    def may_move(self) -> bool:
        return self.moved or not self.refused

    def refuse(self, why: str, *, stop: bool = False) -> None:
        self.refused = self.refused or why
        if stop:
            self.stopped = self.stopped or why

    def interrupt(self, e: BaseException, where: str) -> str:
        """A signal (``KeyboardInterrupt``) at ``where``: no prompt, no motion not already ours."""
        sig = str(e) if str(e) else "interrupted by SIGINT"
        self.signal = self.signal or sig
        why = f"{sig} {where}"
        self.refuse(why, stop=True)
        return why


# ------------------------------------------------------------------------------- runner
def _prepare(plan: Plan, cfg: BenchConfig, serial: str, operator: str,
             out_dir: Path | None) -> list[BenchConfig]:
    """Every step's config and motion checked before anything opens (bad input never moves
    the stand): ``ConfigError`` naming the plan, the step and the problem."""

    where = f"{plan.source}: " if plan.source is not None else ""
    cfgs = []
    for step in plan.steps:
        scfg = step_config(cfg, step, where)
        opts = RunOptions(serial=serial, operator=operator, duration_s=step.duration_s,
                          out_dir=out_dir, decision_rule=step.decision_rule)
        try:
            prepare_motion(scfg, step.profile, opts)
        except InputError as e:  # ConfigError, LimitError, DataError: named by the step
            raise type(e)(f"{where}step {step.name!r}: {e}") from None
        cfgs.append(scfg)
    return cfgs


def run_plan(
    plan: Plan | str | Path,
    *,
    serial: str,
    config: BenchConfig | str | Path | None = None,
    operator: str | None = None,
    yes: bool = False,
    ask: Asker | None = None,
    out_dir: str | Path | None = None,
    junit: str | Path | None = None,
    display: Callable[[], Any] | None = None,
    say: Callable[[str], None] | None = None,
    clock: Clock = REAL,
) -> PlanResult:
    """Run an acceptance plan on the bench and return its ``PlanResult`` (``exit_code``: 0 all
    PASS, 1 a measured FAIL, 2 an abort or error, 3 INCONCLUSIVE).

    ``plan``: a ``Plan`` or a plan YAML file. ``serial``: the unit under test. ``config``: the
    bench config (a ``BenchConfig`` or a file), else the plan's ``config``. ``operator``: else
    the plan's. ``yes``: answer every operator prompt yes (unattended); else ``ask`` answers
    them (text → bool; it may raise ``EOFError``, ``TimeoutError`` or ``KeyboardInterrupt``:
    unanswered, interrupted), else the terminal (y/N, within the plan's ``prompt_timeout_s``);
    with prompts and none of these the plan is refused (``InputError``) before anything opens.
    ``out_dir``: where the recordings and the plan folder go (default ``run.output_dir``).
    ``junit``: write JUnit XML there.
    ``display``: a factory of each step's run display (default none). ``say``: a line of
    progress (default: logged). ``clock``: the run's clock (``benchctl.clock``) for every step,
    stand check, timeout and stamp (default the real one; a config with ``sim.clock: virtual``
    runs the plan on a ``VirtualClock`` from its ``sim.epoch_utc``, as ``run_test`` does).

    Raises ``BenchError`` only for bad input found before anything opens (the plan, the
    config, a step's profile or limits, prompts that cannot be answered); every later outcome
    is in the result."""

    p = plan if isinstance(plan, Plan) else load_plan(plan)
    where = f"{p.source}: " if p.source is not None else ""
    if not isinstance(serial, str) or not serial.strip():
        raise InputError("a plan needs the serial number of the unit under test (--serial)")
    serial = check_serial(serial, "serial")
    if isinstance(config, BenchConfig):
        cfg = config
    else:
        path = Path(config) if config is not None else p.config
        if path is None:
            raise ConfigError(f"{where}no bench config: the plan names none (config:) and none "
                              "was given (--config)")
        cfg = load_config(path)
    if cfg.unit.serial_pattern is not None:  # the config's form of a serial
        check_serial(serial, "serial", cfg.unit.serial_pattern,
                     f"unit.serial_pattern of {cfg.source or 'the config'}")
    if cfg.sim is not None and cfg.sim.clock == "virtual" and not clock.virtual:
        # a simulated bench on simulated time (as run_test): the whole plan -- its steps, stand
        # checks, timeouts and stamps -- on one VirtualClock from the config's epoch. An
        # operator prompt is a wait on the terminal (the host's time): the clock's hang watchdog
        # gives it the prompt's timeout and a minute more
        hang_s = max(120.0, p.prompt_timeout_s + 60.0)
        vclock = VirtualClock(epoch=cfg.sim.epoch_utc, hang_s=hang_s)
        with vclock.running():
            return run_plan(p, serial=serial, config=cfg, operator=operator, yes=yes, ask=ask,
                            out_dir=out_dir, junit=junit, display=display, say=say,
                            clock=vclock)
    op = operator or p.operator
    if not op:
        raise InputError(f"{where}no operator: the plan names none (operator:) and none was "
                         "given (--operator)")
    op = check_operator(op, "operator")
    if yes:
        asker: Asker | None = _yes
    else:
        asker = ask if ask is not None else terminal_asker(timeout_s=p.prompt_timeout_s)
    if p.prompts and asker is None:
        raise InputError(
            f"{where}the plan has {len(p.prompts)} operator prompt(s) and there is no terminal "
            "to answer them on: answer them with --yes (yes=True) for an unattended run"
        )
    out = Path(out_dir) if out_dir is not None else cfg.run.output_dir
    cfgs = _prepare(p, cfg, serial, op, out)
    tell = say or (lambda s: log.info("%s", s))

    result = PlanResult(p.name, p.source, serial, op, cfg.source, start_utc=_now(clock))
    t0 = clock.monotonic()
    folder = recording_dir(out, serial, prefix="plan_", clock=clock)
    try:
        folder.mkdir(parents=True)
    except OSError as e:
        raise ConfigError(f"{folder}: cannot create the plan folder: {e.strerror}") from None
    result.folder = folder
    timers = Timers(clock)
    holder = {"command": "benchctl plan", "plan": p.name, "serial": serial, "operator": op,
              "start_utc": result.start_utc}
    consent = Consent()
    stop_reason = ""
    try:
        with contextlib.ExitStack() as stack:
            live = cfg
            if cfg.sim is not None:
                tell("starting the simulators for the plan")
                live = stack.enter_context(simulators(cfg, folder / "sim.log", clock=clock))
                live = live.model_copy(update={"sim": None})
            live_cfgs = [c.model_copy(update={"stand": live.stand, "instrument": live.instrument,
                                              "sim": None}) for c in cfgs]
            timers.start_plan(p.timeout_s)
            try:
                # ---- setup
                for i, a in enumerate(p.setup):
                    ar = _action("setup", i, a, live, asker, holder, tell, consent, clock)
                    result.setup.append(ar)
                    if ar.status == "declined":
                        stop_reason = f"setup: the operator answered no to {a.prompt!r}"
                        break
                    if ar.status != "ok":
                        stop_reason = f"setup: {ar.detail}"
                        break
                    if timers.plan_expired:
                        stop_reason = "the plan's timeout_s ran out during the setup"
                        result.timed_out = True
                        break
                if stop_reason:
                    result.outcome, result.reason = Outcome.ABORTED, stop_reason
                # ---- steps
                for step, scfg in zip(p.steps, live_cfgs, strict=True):
                    if stop_reason:
                        result.steps.append(StepResult(step.name, str(step.profile),
                                                       Outcome.SKIPPED, f"not run: {stop_reason}",
                                                       step.on_fail))
                        continue
                    if timers.plan_expired:
                        result.timed_out = True
                        stop_reason = "the plan's timeout_s ran out"
                        result.steps.append(StepResult(step.name, str(step.profile),
                                                       Outcome.SKIPPED,
                                                       f"not run: {stop_reason}", step.on_fail))
                        continue
                    tell(f"step {step.name}: {step.profile.name}")
                    consent.moved = True
                    sr = _run_step(step, scfg, serial, op, out, timers, display, run_test,
                                   RunOptions, Supervisor, clock)
                    result.steps.append(sr)
                    tell(f"step {step.name}: {sr.status}" + (f" ({sr.reason})" if sr.reason
                                                              and sr.status != Outcome.PASS
                                                              else ""))
                    if sr.timed_out and timers.plan_expired:
                        result.timed_out = True
                    if sr.status in (Outcome.ABORTED, Outcome.ERROR):
                        stop_reason = f"step {step.name!r} {sr.status.lower()}: {sr.reason}"
                        if sr.abort is not None and sr.abort.get("source") == "signal":
                            # the run took the signal (the stand at rest): no prompt after it
                            consent.interrupt(KeyboardInterrupt(sr.reason),
                                              f"during step {step.name!r}")
                    elif (sr.status in (Outcome.FAIL, Outcome.INCONCLUSIVE)
                          and step.on_fail == "stop"):
                        stop_reason = f"step {step.name!r} {sr.status} (on_fail: stop)"
            except KeyboardInterrupt as e:  # a signal between the actions or the steps
                stop_reason = consent.interrupt(e, "between the plan's actions and steps")
                tell(f"plan {stop_reason}; cleanup follows")
                done = {s.name for s in result.steps}
                for step in p.steps:
                    if step.name not in done:
                        result.steps.append(StepResult(step.name, str(step.profile),
                                                       Outcome.SKIPPED, f"not run: {stop_reason}",
                                                       step.on_fail))
            finally:
                timers.stop()
                # ---- cleanup: always
                for i, a in enumerate(p.cleanup):
                    try:
                        ar = _action("cleanup", i, a, live, asker, holder, tell, consent, clock)
                    except KeyboardInterrupt as e:  # a signal between two actions
                        ar = ActionResult("cleanup", i, a.prompt, a.check, "skipped",
                                          f"not run: {consent.interrupt(e, 'in the cleanup')}")
                    result.cleanup.append(ar)
                if consent.signal:
                    result.interrupted = True
                    if not stop_reason:
                        stop_reason = consent.refused
            if result.interrupted and not result.reason:
                result.reason = stop_reason
    finally:
        result.end_utc = _now(clock)
        result.duration_s = clock.monotonic() - t0
        _conclude(result, stop_reason)
        _write_outputs(result, folder, junit)
    return result


def _action(phase: str, index: int, a: Action, cfg: BenchConfig, asker: Asker | None,
            holder: dict[str, Any], tell: Callable[[str], None], consent: Consent,
            clock: Clock = REAL) -> ActionResult:
    """One setup or cleanup action; never raises for a prompt's answer, a failed check or a
    signal (each is the action's status, and ``consent`` learns of it)."""
    ar = ActionResult(phase, index, a.prompt, a.check, "ok")
    t0 = clock.monotonic()
    try:
        return _act(ar, phase, index, a, cfg, asker, holder, tell, consent, clock)
    finally:
        ar.duration_s = clock.monotonic() - t0


def _act(ar: ActionResult, phase: str, index: int, a: Action, cfg: BenchConfig,
         asker: Asker | None, holder: dict[str, Any], tell: Callable[[str], None],
         consent: Consent, clock: Clock) -> ActionResult:
    if a.prompt is not None:
        answered = _ask(ar, a.prompt, asker, consent)
        if not answered:
            if a.check is not None:
                ar.detail += f"; {a.check} not run"
            tell(f"{phase} {index + 1}: {ar.status} — {ar.detail}")
            return ar
    if a.check is not None:
        try:
            if a.check == "ramp_to_zero" and not consent.may_move():
                ar.status = "skipped"
                ar.detail = (f"ramp_to_zero skipped: {consent.refused}, and this plan has not "
                             "moved the stand (it is left untouched)")
            else:
                if a.check == "ramp_to_zero":
                    consent.moved = True  # from the first enable on, the motion is this plan's
                ar.detail = f"{a.check}: {stand_action(cfg, a.check, holder, clock=clock)}"
        except BenchError as e:
            ar.status, ar.detail = "failed", f"{a.check}: {e}"
        except KeyboardInterrupt as e:
            ar.status = "failed"
            ar.detail = f"{a.check}: {consent.interrupt(e, f'during {a.check}')}"
        except Exception as e:  # a bug in one action must not skip the cleanup
            if phase == "setup":
                raise
            ar.status, ar.detail = "failed", f"unexpected {type(e).__name__}: {e}"
            log.error("cleanup action failed", exc_info=e)
    tell(f"{phase} {index + 1}: {ar.status}" + (f" — {ar.detail}" if ar.detail else ""))
    return ar


def _ask(ar: ActionResult, prompt: str, asker: Asker | None, consent: Consent) -> bool:
    """Ask ``prompt``: True for a yes; otherwise ``ar`` says why not (declined, unanswered,
    interrupted, or skipped: not asked after a signal or an unanswered prompt)."""
    if consent.stopped:
        ar.status, ar.detail = "skipped", f"not asked: {consent.stopped}"
        return False
    assert asker is not None  # refused before the plan started otherwise
    try:
        yes = asker(prompt)
    except KeyboardInterrupt as e:
        ar.status, ar.detail = "interrupted", consent.interrupt(e, f"at the prompt {prompt!r}")
        return False
    except EOFError:
        ar.status, ar.detail = "unanswered", f"no answer to {prompt!r}: the input ended"
        consent.refuse(ar.detail, stop=True)
        return False
    except TimeoutError as e:
        ar.status, ar.detail = "unanswered", f"no answer to {prompt!r}: {e or 'timed out'}"
        consent.refuse(ar.detail, stop=True)
        return False
    if not yes:
        ar.status, ar.detail = "declined", f"answered no: {prompt}"
        consent.refuse(f"the operator answered no to {prompt!r}")
        return False
    return True


def _run_step(step: Step, cfg: BenchConfig, serial: str, operator: str, out: Path,
              timers: Timers, display: Callable[[], Any] | None, run_test: Any,
              RunOptions: Any, Supervisor: Any, clock: Clock = REAL) -> StepResult:
    sr = StepResult(step.name, str(step.profile), Outcome.ERROR, on_fail=step.on_fail,
                    start_utc=_now(clock))
    t0 = clock.monotonic()
    sup = Supervisor(clock=clock)
    opts = RunOptions(serial=serial, operator=operator, duration_s=step.duration_s,
                      out_dir=out, decision_rule=step.decision_rule)
    try:
        with timers.step(sup, step.name, step.timeout_s):
            res = run_test(cfg, step.profile, opts, display=None if display is None else display(),
                           supervisor=sup, clock=clock)
    except BenchError as e:  # could not start: bad input found late, a stand in use
        sr.reason = f"could not start: {e}"
        sr.exit_code = Outcome.ERROR.exit_code
        sr.duration_s = clock.monotonic() - t0
        return sr
    sr.duration_s = clock.monotonic() - t0
    sr.exit_code = ExitCode(res.exit_code)
    sr.recording = res.recording
    sr.record_path = res.record
    sr.abort = res.abort
    if res.record is not None:
        try:
            sr.record = load_record(res.record)
        except BenchError as e:
            log.warning("step %s: record not readable: %s", step.name, e)
    if res.state == "aborted":
        sr.status = Outcome.ABORTED
        sr.reason = res.reason
        f = sup.first
        sr.timed_out = f is not None and isinstance(f.error, PlanTimeout)
    else:
        sr.status = Outcome(sr.record["outcome"] if sr.record is not None else res.reason)
        sr.reason = _fail_reason(sr)
    return sr


def _fail_reason(sr: StepResult) -> str:
    bad = [m for m in sr.measurements
           if m.get("decisive") and m.get("outcome") in (Outcome.FAIL, Outcome.INCONCLUSIVE)]
    return "; ".join(f"{_mname(m)} {m['outcome']}" for m in bad[:5])


def _mname(m: dict[str, Any]) -> str:
    return f"{m['axis']} {m['name']}" if m.get("axis") else str(m["name"])


def _conclude(result: PlanResult, stop_reason: str) -> None:
    """The plan's outcome and exit code from its steps and actions."""
    statuses = [s.status for s in result.steps]
    aborted = (result.interrupted or result.timed_out
               or any(s in (Outcome.ABORTED, Outcome.ERROR) for s in statuses)
               or any(a.status in ("declined", "unanswered", "interrupted", "failed")
                      for a in result.setup)
               or any(a.status in ("interrupted", "failed") for a in result.cleanup))
    if aborted:
        result.outcome = Outcome.ABORTED
        reasons = [stop_reason] if stop_reason else []
        reasons += [f"cleanup: {a.detail}" for a in result.cleanup if a.status == "failed"]
        if result.timed_out and not any("timeout" in r for r in reasons):
            reasons.append("the plan's timeout_s ran out")
        result.reason = "; ".join(reasons) or result.reason or "aborted"
    elif Outcome.FAIL in statuses:
        result.outcome = Outcome.FAIL
        result.reason = stop_reason or "; ".join(
            f"{s.name}: {s.reason}" for s in result.steps if s.status == Outcome.FAIL)
    elif Outcome.INCONCLUSIVE in statuses:
        result.outcome = Outcome.INCONCLUSIVE
        result.reason = stop_reason
    elif statuses and all(s == Outcome.PASS for s in statuses):
        result.outcome, result.reason = Outcome.PASS, ""
    else:  # nothing ran (cannot happen: a plan has steps and nothing stopped it)
        result.outcome = Outcome.ABORTED
        result.reason = stop_reason or "no step ran"
    result.exit_code = result.outcome.exit_code


def _write_outputs(result: PlanResult, folder: Path, junit: str | Path | None) -> None:
    """plan.json (validated) and the JUnit XML; a file that cannot be written is an error
    line in the log and leaves its path None (the steps' records stand without it)."""

    if junit is not None:
        try:
            result.junit = write_junit(result, Path(junit))
        except OSError as e:  # asked for and not written: an error of the plan (exit 2)
            log.error("JUnit XML not written: %s: %s", junit, e.strerror)
            result.exit_code = ExitCode.ERROR
            result.reason = "; ".join(
                r for r in (result.reason, f"JUnit XML not written: {junit}: {e.strerror}") if r)
    rec = result.to_dict()
    validate_plan_record(rec)
    path = folder / PLAN_JSON
    try:
        path.write_text(dumps(rec, indent=2) + "\n", encoding="utf-8")
        result.record_path = path
    except OSError as e:
        log.error("plan record not written: %s: %s", path, e.strerror)


__all__ = [
    "PLAN_JSON",
    "PLAN_SCHEMA_ID",
    "ActionResult",
    "Consent",
    "PlanResult",
    "StepResult",
    "run_plan",
    "step_config",
]
