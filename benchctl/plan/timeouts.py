"""A plan's timeouts: the plan's and each step's ``timeout_s``, on the run's clock.

When one runs out, the running step is ended through its supervisor (``PlanTimeout``, its fault
source ``TIMEOUT_SOURCE``): the run's own abort path ramps the stand to rest and closes the
recording aborted. A plan timeout that ran out between steps ends the next step as it starts.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Iterator
from typing import Any

from benchctl.clock import REAL, Clock, EventLike, ThreadLike
from benchctl.errors import SafetyAbort

# the plan runner's logger: the timeouts' messages keep the name they have always had
log = logging.getLogger("benchctl.plan.runner")

TIMEOUT_SOURCE = "plan timeout"  # the fault source of a step ended by a timeout


class PlanTimeout(SafetyAbort):
    """A step ended because its own or the plan's ``timeout_s`` ran out."""


class _Timer:
    """``threading.Timer`` on a clock: ``fn`` runs in its own thread ``seconds`` after
    ``start`` unless ``cancel`` came first."""

    def __init__(self, clock: Clock, seconds: float, fn: Callable[[], None], name: str) -> None:
        self.seconds, self.fn = seconds, fn
        self._cancelled: EventLike = clock.event()
        self._thread: ThreadLike = clock.thread(self._run, name=name)

    def _run(self) -> None:
        if not self._cancelled.wait(self.seconds):
            self.fn()

    def start(self) -> None:
        self._thread.start()

    def cancel(self) -> None:
        self._cancelled.set()

    def join(self) -> None:
        self._thread.join()


class Timers:
    """The step's and the plan's timeouts: each ends the running step through its supervisor."""

    def __init__(self, clock: Clock = REAL) -> None:
        self.clock = clock
        self._lock = clock.lock()
        self.supervisor: Any = None  # the running step's
        self.plan_expired = False
        self.step_expired = False
        self._plan_timer: _Timer | None = None
        self.plan_timeout_s: float | None = None

    def start_plan(self, seconds: float | None) -> None:
        self.plan_timeout_s = seconds
        if seconds is not None:
            self._plan_timer = _Timer(self.clock, seconds, self._plan_fired, "plan-timeout")
            self._plan_timer.start()

    def _plan_fired(self) -> None:
        with self._lock:
            self.plan_expired = True
            sup = self.supervisor
        log.error("plan timeout: %g s", self.plan_timeout_s or 0)
        if sup is not None:
            sup.fault(PlanTimeout(f"the plan's timeout_s ({self.plan_timeout_s:g} s) ran out"),
                      TIMEOUT_SOURCE)

    @contextlib.contextmanager
    def step(self, supervisor: Any, name: str, seconds: float | None) -> Iterator[None]:
        self.step_expired = False

        def fired() -> None:
            self.step_expired = True
            log.error("step %r timeout: %g s", name, seconds or 0)
            supervisor.fault(PlanTimeout(f"step {name!r}: its timeout_s ({seconds:g} s) ran out"),
                             TIMEOUT_SOURCE)

        timer: _Timer | None = None
        with self._lock:
            self.supervisor = supervisor
            expired = self.plan_expired
        if expired:
            supervisor.fault(PlanTimeout(
                f"the plan's timeout_s ({self.plan_timeout_s:g} s) ran out"), TIMEOUT_SOURCE)
        if seconds is not None:
            timer = _Timer(self.clock, seconds, fired, "step-timeout")
            timer.start()
        try:
            yield
        finally:
            if timer is not None:
                timer.cancel()
                timer.join()
            with self._lock:
                self.supervisor = None

    def stop(self) -> None:
        if self._plan_timer is not None:
            self._plan_timer.cancel()
            self._plan_timer.join()


__all__ = ["TIMEOUT_SOURCE", "PlanTimeout", "Timers"]
