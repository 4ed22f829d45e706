"""The one clock every time read and every wait of the run goes through.

Run, plan, recording, device and simulator code never calls ``time.monotonic``, ``time.time``,
``time.sleep`` nor builds its own ``threading.Event``/``Lock``/``Condition``/``Thread`` or
``queue.Queue``: it asks the clock it was handed. Two clocks:

- :data:`REAL` (:class:`RealClock`): the operating system's clocks and ``threading`` — what a run
  on hardware uses, and the default everywhere; behaviour is exactly what it was before the clock
  was injected.
- :class:`benchctl.clock.virtual.VirtualClock`: simulated time. The threads it starts run one at a
  time, control passing only at the clock's waits; when every thread waits, time jumps to the
  next deadline. A 15-minute simulated test then takes as long as its computation, and two runs
  with the same seed do the same thing in the same order, bit for bit.

ruff's banned-API rule (``pyproject.toml``) refuses the raw calls outside this package.

The primitives' interfaces are the standard library's (``Event.wait(timeout) -> bool``,
``Lock.acquire(blocking, timeout)``, ``Queue.get(block, timeout)`` raising ``queue.Empty``,
``Thread.join(timeout)``), so code written against :data:`REAL` runs unchanged on either clock.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime
from types import TracebackType
from typing import Any, Protocol

__all__ = [
    "REAL",
    "Clock",
    "EventLike",
    "LockLike",
    "QueueLike",
    "RealClock",
    "ThreadLike",
]


class EventLike(Protocol):
    def set(self) -> None: ...
    def clear(self) -> None: ...
    def is_set(self) -> bool: ...
    def wait(self, timeout: float | None = None) -> bool: ...


class LockLike(Protocol):
    def acquire(self, blocking: bool = True, timeout: float = -1) -> bool: ...
    def release(self) -> None: ...
    def __enter__(self) -> Any: ...
    def __exit__(
        self, t: type[BaseException] | None, v: BaseException | None, tb: TracebackType | None, /
    ) -> Any: ...


class ConditionLike(LockLike, Protocol):
    def wait(self, timeout: float | None = None) -> bool: ...
    def wait_for(self, predicate: Callable[[], Any], timeout: float | None = None) -> Any: ...
    def notify(self, n: int = 1) -> None: ...
    def notify_all(self) -> None: ...


class QueueLike(Protocol):
    def put(self, item: Any, block: bool = True, timeout: float | None = None) -> None: ...
    def put_nowait(self, item: Any) -> None: ...
    def get(self, block: bool = True, timeout: float | None = None) -> Any: ...
    def get_nowait(self) -> Any: ...
    def qsize(self) -> int: ...
    def empty(self) -> bool: ...


class ThreadLike(Protocol):
    name: str

    def start(self) -> None: ...
    def join(self, timeout: float | None = None) -> None: ...
    def is_alive(self) -> bool: ...


class Clock(Protocol):
    """What the run's code asks of time."""

    #: True on simulated time: nothing of the host's clocks may reach a recording
    virtual: bool

    def monotonic(self) -> float:
        """Seconds on a clock that never goes back (the run's time axis)."""
        ...

    def time(self) -> float:
        """UTC wall time, seconds since the Unix epoch (stamps for people and files)."""
        ...

    def now_utc(self) -> datetime:
        """UTC wall time as an aware datetime."""
        ...

    def sleep(self, seconds: float) -> None: ...

    def event(self) -> EventLike: ...

    def lock(self) -> LockLike: ...

    def rlock(self) -> LockLike: ...

    def condition(self, lock: LockLike | None = None) -> ConditionLike: ...

    def queue(self, maxsize: int = 0) -> QueueLike: ...

    def thread(
        self,
        target: Callable[..., Any],
        *,
        name: str,
        args: tuple[Any, ...] = (),
        daemon: bool = True,
    ) -> ThreadLike: ...

    def compute(self, seconds: float) -> None:
        """Host computation of ``seconds`` the model charges (the real clock: nothing — the
        computation itself takes the time)."""
        ...

    def set_at(self, event: EventLike, when: float) -> None:
        """Set ``event`` (one of this clock's) at ``monotonic()`` time ``when``, or earlier: its
        waiters must check what they wait for when they wake. The real clock sets it now; the
        virtual clock at ``when`` (a wait for bytes in flight then wakes once, on their
        arrival, not also when they were sent)."""
        ...

    def from_signal(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` for a signal handler (which runs in the main thread between two of its
        bytecodes, wherever it was). The real clock runs it now; the virtual clock, whose own
        mutex the interrupted thread may hold, takes no lock there and then: the thread holding
        its baton runs ``fn`` at its next wait."""
        ...


class RealClock:
    """The operating system's clocks and ``threading``: a run on hardware."""

    virtual = False

    def monotonic(self) -> float:
        return time.monotonic()

    def time(self) -> float:
        return time.time()

    def now_utc(self) -> datetime:
        return datetime.now(UTC)

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))

    def event(self) -> EventLike:
        return threading.Event()

    def lock(self) -> LockLike:
        return threading.Lock()

    def rlock(self) -> LockLike:
        return threading.RLock()

    def condition(self, lock: LockLike | None = None) -> ConditionLike:
        return threading.Condition(lock)  # type: ignore[arg-type]  # a threading lock here

    def queue(self, maxsize: int = 0) -> QueueLike:
        return queue.Queue(maxsize)

    def thread(
        self,
        target: Callable[..., Any],
        *,
        name: str,
        args: tuple[Any, ...] = (),
        daemon: bool = True,
    ) -> ThreadLike:
        return threading.Thread(target=target, name=name, args=args, daemon=daemon)

    def compute(self, seconds: float) -> None:
        return None

    def set_at(self, event: EventLike, when: float) -> None:
        event.set()

    def from_signal(self, fn: Callable[[], None]) -> None:
        fn()

    def __repr__(self) -> str:
        return "RealClock()"


#: the real clock: the default wherever a clock is handed in
REAL: Clock = RealClock()
