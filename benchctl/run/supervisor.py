"""Safety supervision: the first fault wins, and ONE cleanup path serves every way out.

Ways out: Ctrl-C (SIGINT), SIGTERM, SIGHUP (the terminal closed), SIGQUIT, a lost link, a stand
fault or E-stop, a silent instrument, a limit or tracking-error breach, a recording that cannot
be written (disk full), an exception in any thread. Each calls
``Supervisor.fault(error, source)``; the first one is kept, later ones are logged as
secondary. The run's threads watch ``Supervisor.stop_event`` and leave; the main thread then
calls ``shutdown`` (stop loops → stop table → ramp to zero within limits if the stand answers →
disable → stop heartbeat → stop instrument → close the recording ``aborted`` with the reason),
each step guarded on its own: one that fails is noted and the next one still runs.
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from types import FrameType
from typing import Any

from benchctl.clock import REAL, Clock, ThreadLike
from benchctl.devices.base import AngleSensor, Stand
from benchctl.errors import (
    AnalysisError,
    BenchError,
    DataError,
    RecordingError,
    SafetyAbort,
    is_disk_full,
)
from benchctl.exits import EXIT_SIGNALS, ignored
from benchctl.recording import RecordingWriter

log = logging.getLogger(__name__)


def describe(exc: BaseException) -> str:
    """A one-line reason for an exception: the message, with the type when it is not ours."""
    if isinstance(exc, SafetyAbort):
        return exc.reason
    if isinstance(exc, RecordingError):  # "disk full: cannot write …/stand.csv (ENOSPC, …)"
        return str(exc)
    if isinstance(exc, BenchError):
        return f"{type(exc).__name__}: {exc}"
    return f"unexpected {type(exc).__name__}: {exc}"


@dataclass
class Fault:
    error: BaseException
    source: str
    t_host: float

    @property
    def reason(self) -> str:
        return f"{self.source}: {describe(self.error)}"


class Supervisor:
    """Collects faults from every thread; the first one decides the reason of the abort."""

    def __init__(
        self, on_fault: Callable[[Fault], None] | None = None, *, clock: Clock = REAL
    ) -> None:
        self.clock = clock
        self._lock = clock.lock()
        self.first: Fault | None = None
        self.later: list[Fault] = []
        self.stop_event = clock.event()
        self._on_fault = on_fault

    @property
    def faulted(self) -> bool:
        return self.first is not None

    def fault(self, error: BaseException, source: str) -> None:
        """Report a fault; thread-safe, never raises. The first one wins. A disk-full
        ``OSError`` (ENOSPC, EDQUOT, EFBIG), from whichever thread or library, is kept as the
        ``RecordingError`` it is ("disk full: cannot write …"), not as an unexpected error."""
        error = RecordingError.disk_full(error) or error
        f = Fault(error, source, self.clock.monotonic())
        with self._lock:
            if self.first is None:
                self.first = f
                first = True
            else:
                self.later.append(f)
                first = False
        if first:
            # an unexpected exception's traceback goes to the log file, never to the console
            tb = error if not isinstance(error, BenchError | KeyboardInterrupt) else None
            log.error("run fault from %s: %s", source, describe(error), exc_info=tb)
        else:
            log.warning("further fault from %s (after the first): %s", source, describe(error))
        self.stop_event.set()
        if self._on_fault is not None:
            try:
                self._on_fault(f)
            except Exception:  # a broken listener must not hide the fault
                log.exception("fault listener failed")

    def check(self) -> None:
        """Raise the first fault as a ``SafetyAbort`` if there is one (for blocking phases)."""
        f = self.first
        if f is not None:
            raise SafetyAbort(f.reason)

    def guard(self, source: str, target: Callable[[], None]) -> Callable[[], None]:
        """Wrap a thread's body: any exception becomes a fault of ``source``; never dies quietly."""

        def run() -> None:
            try:
                target()
            except BaseException as e:
                self.fault(e, source)

        return run

    def thread(self, name: str, target: Callable[[], None]) -> ThreadLike:
        return self.clock.thread(self.guard(name, target), name=name, daemon=True)

    def interrupt_after(self, seconds: float, signame: str = "SIGINT") -> None:
        """``seconds`` from now, take the path a signal takes (the operator's Ctrl-C on
        simulated time, at a seeded moment): the same fault the signal handler reports."""
        clock = self.clock
        at = clock.monotonic() + seconds

        def operator() -> None:
            clock.sleep(max(0.0, at - clock.monotonic()))
            self.fault(SafetyAbort(f"interrupted by {signame}"), "signal")

        clock.thread(operator, name="operator-stop").start()

    @contextmanager
    def signals(self) -> Iterator[None]:
        """Turn SIGINT, SIGTERM, SIGHUP and SIGQUIT into faults while the run lasts (main thread
        only); the handlers there before (``benchctl.exits``: a clean exit 2) come back after. A
        SIGHUP the process was started with ignored stays ignored (``nohup``; ``exits.ignored``)."""
        if threading.current_thread() is not threading.main_thread():
            yield
            return

        def handler(signum: int, frame: FrameType | None) -> None:
            name = signal.Signals(signum).name
            # through the clock: on simulated time the interrupted main thread may hold the
            # clock's mutex, which the fault's stop event takes (a run hung there for good)
            self.clock.from_signal(
                lambda: self.fault(SafetyAbort(f"interrupted by {name}"), "signal"))

        old = {s: signal.signal(s, handler) for s in EXIT_SIGNALS if not ignored(s)}
        try:
            yield
        finally:
            for s, h in old.items():
                signal.signal(s, h)


@dataclass
class ShutdownReport:
    """What the cleanup did, step by step (recorded in end.json and printed)."""

    steps: list[dict[str, Any]] = field(default_factory=list)
    stand_at_rest: bool | None = None
    #: where the stand was left, when it answered: {angle_deg, rate_deg_s, enabled, fault_code,
    #: fault_text, estop, moving} (a faulted stand's too: its state is read without raising on
    #: the fault; ``fault_text`` the register map's text for the code, "" without a fault)
    final_state: dict[str, Any] | None = None

    def add(self, step: str, ok: bool, detail: str = "") -> None:
        self.steps.append({"step": step, "ok": ok, "detail": detail})


def _try(report: ShutdownReport, step: str, fn: Callable[[], object]) -> bool:
    try:
        fn()
    except BaseException as e:  # cleanup goes on whatever one step does
        report.add(step, False, describe(e))
        log.warning("cleanup step %s failed: %s", step, describe(e))
        return False
    report.add(step, True)
    return True


def shutdown(
    *,
    stop_loops: Callable[[], None],
    stand: Stand | None,
    sensor: AngleSensor | None,
    writer: RecordingWriter | None,
    state: str,
    reason: str,
    table_mode: bool = False,
    moved: bool = True,
    ramp_timeout_s: float = 30.0,
    extra: dict[str, Any] | None = None,
) -> ShutdownReport:
    """The one cleanup path, for a normal end and for every abort alike.

    Each step is attempted whatever the previous one did (a full disk, a dead link, a bug in one
    step never skips the next); nothing here raises. ``moved`` says
    whether the stand may be away from rest (False before the motion began: no ramp needed).
    """
    rep = ShutdownReport()
    _try(rep, "stop loops", stop_loops)
    if stand is not None:
        if table_mode:
            _try(rep, "stop table", stand.stop_table)
        if moved:
            _try(rep, "ramp to zero", lambda: stand.ramp_to_zero(ramp_timeout_s))
        _try(rep, "disable", stand.disable)

        def at_rest() -> None:
            # a faulted stand's state too: where it is matters most then
            read = getattr(stand, "read_state", None) or stand.read_sample
            s = read()
            st = s.status
            rep.stand_at_rest = (
                all(abs(v) <= 1.0 for v in s.rate_deg_s.values()) and not st.moving
            )
            # the register map's text for the code; none without a map (a stand of its own)
            codes = getattr(getattr(stand, "map", None), "fault_codes", None)
            rep.final_state = {
                "angle_deg": dict(s.angle_deg),
                "rate_deg_s": dict(s.rate_deg_s),
                "enabled": st.enabled,
                "fault_code": st.fault_code,
                "fault_text": str(codes.get(st.fault_code, "unknown fault"))
                if st.fault_code and codes is not None else "",
                "estop": st.estop,
                "moving": bool(st.moving),
            }
            where = ", ".join(f"{a}={v:.3f}°" for a, v in s.angle_deg.items())
            flags = ["servo on" if st.enabled else "servo off"]
            if st.fault or st.fault_code:
                text = rep.final_state["fault_text"]
                flags.append(f"fault {st.fault_code}" + (f" ({text})" if text else ""))
            if st.estop:
                flags.append("E-stop")
            rep.add("final angle", True, f"{where} ({', '.join(flags)})")

        _try(rep, "read final state", at_rest)
    if sensor is not None:
        _try(rep, "stop instrument", sensor.stop)
    if writer is not None:
        _try(
            rep,
            "record shutdown",
            lambda: writer.event("shutdown", state=state, reason=reason, steps=list(rep.steps)),
        )
        _try(
            rep,
            "close recording",
            lambda: writer.close(state, reason, shutdown=rep.steps, **(extra or {})),
        )
    for name, dev in (("stand", stand), ("instrument", sensor)):
        if dev is not None:
            _try(rep, f"close {name}", dev.close)
    return rep


def fault_source(e: BaseException) -> str:
    """The source a fault raised on the run's main thread is reported with."""
    if isinstance(e, KeyboardInterrupt):
        return "signal"
    if isinstance(e, RecordingError) or is_disk_full(e):
        return "recording"
    if isinstance(e, AnalysisError | DataError):
        return "analysis"
    if isinstance(e, BenchError):
        return "run"
    return "run (exception)"
