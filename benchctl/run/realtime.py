"""Real-time scheduling for a thread of the run (``run.realtime_priority``).

On Linux ``os.sched_setscheduler(0, SCHED_FIFO, priority)`` called *from* a thread applies to
that thread alone (pid 0 is the calling thread: Linux schedules threads, not processes). An
ordinary user is refused (EPERM) unless it has ``CAP_SYS_NICE`` or an ``rtprio`` limit at
least the priority asked for (``/etc/security/limits.conf``: ``benchuser - rtprio 50``). A
refusal is reported, never an error: the run goes on at normal priority.
"""

from __future__ import annotations

import errno
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

#: sets the calling thread's SCHED_FIFO priority; raises OSError when refused
PrioritySetter = Callable[[int], None]



def grant_hint(priority: int) -> str:
    """How an administrator grants it (Linux)."""
    return (f"run as a user with CAP_SYS_NICE, or with rtprio {priority} or more in "
            "/etc/security/limits.conf")


@dataclass(frozen=True)
class RealtimeResult:
    requested: int | None  # the priority asked for (None: not asked)
    granted: bool
    detail: str  # "real-time priority 50: granted (SCHED_FIFO)" …

    def to_dict(self) -> dict[str, Any]:
        return {"requested": self.requested, "granted": self.granted, "detail": self.detail}


def os_setter() -> PrioritySetter | None:
    """The operating system's SCHED_FIFO setter for the calling thread; None where there is
    none (not Linux/POSIX with real-time scheduling)."""
    set_sched = getattr(os, "sched_setscheduler", None)
    fifo = getattr(os, "SCHED_FIFO", None)
    param = getattr(os, "sched_param", None)
    if set_sched is None or fifo is None or param is None:
        return None

    def setter(priority: int) -> None:
        set_sched(0, fifo, param(priority))

    return setter


def not_requested(why: str) -> RealtimeResult:
    return RealtimeResult(None, False, f"real-time priority not requested: {why}")


def request_realtime(priority: int, setter: PrioritySetter | None = None) -> RealtimeResult:
    """Ask for SCHED_FIFO ``priority`` for the calling thread (``setter``: the OS's by
    default); never raises."""
    if setter is None:
        setter = os_setter()
    if setter is None:
        return RealtimeResult(priority, False,
                              f"real-time priority {priority}: not granted: this operating "
                              "system has no SCHED_FIFO scheduling")
    try:
        setter(priority)
    except OSError as e:
        why = e.strerror or os.strerror(e.errno or 0) or str(e)
        hint = f" ({grant_hint(priority)})" if e.errno in (errno.EPERM, errno.EACCES) else ""
        return RealtimeResult(priority, False,
                              f"real-time priority {priority}: not granted: {why}{hint}")
    return RealtimeResult(priority, True, f"real-time priority {priority}: granted (SCHED_FIFO)")
