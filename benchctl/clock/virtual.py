"""Simulated time for threads: one runnable thread at a time, time jumping when all wait.

:class:`VirtualClock` is trio's *autojump clock* applied to threads. Every thread of a simulated
run is started by the clock (:meth:`VirtualClock.thread`) or is the thread that entered it
(:meth:`VirtualClock.running`). Exactly one of them holds the *baton* and runs; it gives the
baton up only at one of the clock's waits (``sleep``, ``Event.wait``, ``Lock.acquire``,
``Condition.wait``, ``Queue.get``, ``Thread.join``). The baton then goes to the thread that was
made runnable first (FIFO); when no thread is runnable, time jumps to the earliest deadline and
the thread waiting for it runs. Nothing depends on the host's speed or its scheduler, so a run
with the same inputs makes the same calls in the same order on the same simulated instants.

Hazards, and what the clock does about them:

- A thread that waits *outside* the clock (``time.sleep``, a socket, a plain ``threading``
  lock) keeps the baton and everything stops. A real-time watchdog (``hang_s`` of the host's
  time without one hand-over; a gap in which the whole process was stopped counts as two of
  its steps at most) names the thread and the line it is on, raises
  :class:`~benchctl.errors.SimulationHang` in it (delivered as soon as it runs Python code
  again) and keeps the message in :attr:`VirtualClock.hang`.
- Every thread waiting with no deadline and nobody left to wake it: the thread that entered the
  clock gets :class:`~benchctl.errors.SimulationHang` naming each thread and what it waits on.
- A clock primitive used from a thread the clock did not start raises ``SimulationHang`` at
  once (it would break the one-at-a-time rule).
- When the entering thread leaves :meth:`running`, threads still alive are ended: their pending
  wait raises :class:`ClockClosed` (a ``BaseException``, so ``except Exception`` loops unwind).

One CPU: while a clock runs, its threads are kept on the CPU the entering thread was on
(``pin_cpu``, on Linux; its former CPU set is given back as it leaves). Every two seconds the
watchdog lets the operating system place them anew for 20 ms and keeps them where the thread
holding the baton went, so a CPU shared with another busy process is not kept for a whole run.
Only one of them runs at a time anyway, and a hand-over between threads on two CPUs costs a
cross-CPU wake-up and a contended interpreter lock each time: 50–100 µs against about 9 µs on
one CPU on a 2-core virtual machine, about a quarter of the paper's 15-minute test's host time
(220 000 hand-overs). The schedule, and so every byte a run records, does not depend on it.

Why this module stays whole (about 880 lines): it is one scheduler. The primitives below the
clock (``VEvent``, ``VLock``/``VRLock``, ``VCondition``, ``VQueue``, ``VThread``) are not users
of a public interface but the scheduler's own blocking points: each one takes the clock's mutex
(``_mu``), reads its simulated now (``_now``), parks the calling task and hands the baton on
(``_me``, ``_block``, ``_wake``), and ``VThread`` enters tasks into the run queue and leaves it
(``_tasks``, ``_alive``, ``_ready``, ``_leave``). The one-at-a-time rule holds only if every
hand-over goes through these few lines under one lock; split apart, the rule's invariants (who
holds the baton, who is runnable, when time may jump) would be spread over modules reaching
into each other's private state, and the clock would import its primitives while they import
the clock.
"""

from __future__ import annotations

import contextlib
import ctypes
import heapq
import itertools
import logging
import os
import queue
import sys
import threading
import time
import traceback
import types
from collections import deque
from collections.abc import Callable, Iterator
from datetime import UTC, datetime
from typing import Any

from benchctl.errors import SimulationHang

log = logging.getLogger(__name__)
_get_ident = threading.get_ident

#: the default epoch of a simulated run's wall time: recordings made on simulated time carry
#: stamps from here, never the host's date
DEFAULT_EPOCH = datetime(2026, 1, 1, tzinfo=UTC)


#: every how many watchdog steps (1 s each) the clock's threads may be moved to another CPU,
#: and for how long (s) the operating system may place them anew then (``_repin``)
REPIN_STEPS = 2
REPIN_WINDOW_S = 0.02


def _cpu_of(native_id: int | None = None) -> int | None:
    """The CPU a thread of this process (its operating system id; None: the calling thread)
    last ran on (Linux: field 39 of its ``stat``), or None."""
    path = "/proc/thread-self/stat" if native_id is None else f"/proc/self/task/{native_id}/stat"
    try:
        with open(path, "rb") as f:
            stat = f.read()
        return int(stat[stat.rindex(b")") + 2:].split()[36])
    except (OSError, ValueError, IndexError):
        return None


def pin_to_this_cpu() -> set[int] | None:
    """Keep the calling thread, and the threads it starts from now on, on the CPU it runs on
    (Linux); returns the CPU set it had, to give back, or None where nothing was changed (one
    CPU allowed already, no affinity call on this system, or the call refused). A process
    running beside another busy one is on a CPU of its own at that moment, as a rule, so two
    simulated runs side by side (a test worker each) stay on two CPUs."""
    get = getattr(os, "sched_getaffinity", None)
    set_ = getattr(os, "sched_setaffinity", None)
    if get is None or set_ is None:
        return None
    try:
        allowed = set(get(0))
        cpu = _cpu_of()
        if len(allowed) < 2 or cpu is None or cpu not in allowed:
            return None
        set_(0, {cpu})
    except OSError:
        return None
    return allowed


class ClockClosed(BaseException):
    """Raised in a thread still waiting when the run that entered the clock has left it."""


class _Task:
    __slots__ = (
        "blocked",
        "device",
        "done",
        "error",
        "ident",
        "joiners",
        "kill",
        "name",
        "native",
        "resume_timed_out",
        "sem",
        "timed_out",
        "wait_id",
        "waiting_on",
    )

    def __init__(self, name: str) -> None:
        self.name = name
        #: a simulated device's thread (name ``sim-…``): host stalls do not stop it
        self.device = name.startswith("sim-")
        self.resume_timed_out = False
        self.sem = threading.Lock()
        self.sem.acquire()  # locked: the thread waits on it until it is handed the baton
        self.blocked = False
        self.timed_out = False
        self.wait_id = 0
        self.waiting_on = ""
        self.done = False
        self.kill = False
        self.error: BaseException | None = None
        self.ident: int | None = None
        #: the operating system's id of its thread (its CPU is moved by that id)
        self.native: int | None = None
        self.joiners: list[_Task] = []


class _Callback:
    """A device's work the clock runs itself at a simulated time (:meth:`VirtualClock.call_at`)
    — in the thread giving up the baton, where a device thread waiting for that moment would
    have been handed it: the same order, no thread's hand-over."""

    __slots__ = ("fn", "name")

    def __init__(self, fn: Callable[[], Any], name: str) -> None:
        self.fn = fn
        self.name = name


class VirtualClock:
    """Simulated time (see the module's text).

    ``start_s``: the value of :meth:`monotonic` at the start. ``epoch``: the UTC wall time at
    that moment (:meth:`time`, :meth:`now_utc`). ``hang_s``: host seconds without a hand-over
    after which the watchdog reports the thread holding the baton. ``pin_cpu``: keep the
    clock's threads on one CPU while it runs (see the module's text).
    """

    virtual = True

    def __init__(
        self,
        *,
        start_s: float = 1000.0,
        epoch: datetime = DEFAULT_EPOCH,
        hang_s: float = 120.0,
        pin_cpu: bool = True,
    ) -> None:
        self.pin_cpu = pin_cpu
        self._t0 = float(start_s)
        self._now = float(start_s)
        self._epoch = epoch.timestamp()
        self.hang_s = hang_s
        self._mu = threading.Lock()
        self._ready: deque[_Task | _Callback] = deque()
        #: what signal handlers handed in (from_signal): appended without a lock, run by the
        #: thread holding the baton at its next wait
        self._signalled: deque[Callable[[], None]] = deque()
        self._in_callback = 0
        #: (deadline, seq, task, wait id, resume) of a timed wait, or (when, seq, event, 0,
        #: False) of an event set at a time (set_at), or (when, seq, callback, 0, False)
        self._timers: list[tuple[float, int, _Task | VEvent | _Callback, int, bool]] = []
        #: host stalls: (start, end) on simulated time, sorted; the host's threads (every thread
        #: not named ``sim-…``) do not run inside one — the run's process stopped, as by SIGSTOP
        self._stalls: list[tuple[float, float]] = []
        self._stall_i = 0
        self._seq = itertools.count()
        self._tasks: dict[int, _Task] = {}
        self._alive: list[_Task] = []
        self._current: _Task | None = None
        self._root: _Task | None = None
        self._closing = False
        #: hand-overs of the baton so far (the watchdog's sign of progress)
        self.switches = 0
        #: the watchdog's or the deadlock detector's message, if either fired
        self.hang: str | None = None
        self._watchdog: threading.Thread | None = None
        self._watchdog_stop = threading.Event()
        #: the CPU set the clock's threads had before they were kept on one CPU, or None
        self._pinned: set[int] | None = None

    # -- time -----------------------------------------------------------------------------
    def monotonic(self) -> float:
        return self._now

    def time(self) -> float:
        return self._epoch + (self._now - self._t0)

    def now_utc(self) -> datetime:
        return datetime.fromtimestamp(self.time(), UTC)

    def sleep(self, seconds: float) -> None:
        self._block("sleep", self._now + max(0.0, seconds))

    def compute(self, seconds: float) -> None:
        if seconds > 0:
            self._block("compute", self._now + seconds)

    def set_at(self, event: Any, when: float) -> None:
        """Set ``event`` (a :class:`VEvent` of this clock) at simulated time ``when`` (now if
        ``when`` is not later), by the clock itself: no thread wakes before then."""
        if not isinstance(event, VEvent) or event._c is not self:
            raise TypeError(f"set_at: {event!r} is not an event of this clock")
        if when <= self._now:
            event.set()
            return
        with self._mu:
            heapq.heappush(self._timers, (when, next(self._seq), event, 0, False))

    def from_signal(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` for a signal handler: the handler runs in the main thread between two of
        its bytecodes — maybe inside this clock, holding its mutex, where a clock primitive
        taken in the handler deadlocked the run (a real Ctrl-C on simulated time) — so nothing
        is taken here; the thread holding the baton runs ``fn`` at its next wait, before it
        gives the baton up (``fn`` may use the clock as that thread could)."""
        self._signalled.append(fn)  # a deque's append: atomic, no lock

    def call_at(self, when: float, fn: Callable[[], Any], name: str) -> None:
        """Run ``fn`` at simulated time ``when`` (a time already passed: as soon as the threads
        runnable now have run), by the clock itself, in whichever of its threads gives up the
        baton then — exactly where a device thread (``name``, ``sim-…``) woken at ``when``
        would run, without a thread. ``fn`` may use the clock (set events, write to links,
        take an uncontended lock) but never wait (that raises ``SimulationHang``). An exception
        in it is reported as one escaping a thread ``name``."""
        cb = _Callback(fn, name)
        with self._mu:
            if when <= self._now:
                self._ready.append(cb)
            else:
                heapq.heappush(self._timers, (when, next(self._seq), cb, 0, False))

    def _run_callback(self, cb: _Callback) -> None:
        """Run a callback (with ``_mu`` held on entry and on return, released meanwhile)."""
        self._mu.release()
        self._in_callback += 1
        try:
            cb.fn()
        except BaseException:
            exc_type, exc, tb = sys.exc_info()
            threading.excepthook(threading.ExceptHookArgs(
                (exc_type, exc, tb, types.SimpleNamespace(name=cb.name))))
        finally:
            self._in_callback -= 1
            self._mu.acquire()

    def stall_host(self, start_s: float, duration_s: float) -> None:
        """Stop the host's threads from simulated time ``start_s`` (``monotonic()``'s scale) for
        ``duration_s``: a thread due to run inside it runs at its end (its wait's outcome kept)."""
        if duration_s <= 0:
            return
        with self._mu:
            self._stalls.append((start_s, start_s + duration_s))
            self._stalls.sort()
            self._stall_i = 0

    def _stalled_until(self, now: float) -> float | None:
        """The end of the host stall ``now`` falls in, or None (with ``_mu`` held)."""
        st = self._stalls
        i = self._stall_i
        while i < len(st) and st[i][1] <= now:
            i += 1
        self._stall_i = i
        if i < len(st) and st[i][0] <= now:
            return st[i][1]
        return None

    # -- primitives -----------------------------------------------------------------------
    def event(self) -> VEvent:
        return VEvent(self)

    def lock(self) -> VLock:
        return VLock(self)

    def rlock(self) -> VRLock:
        return VRLock(self)

    def condition(self, lock: Any = None) -> VCondition:
        return VCondition(self, lock if lock is not None else VRLock(self))

    def queue(self, maxsize: int = 0) -> VQueue:
        return VQueue(self, maxsize)

    def thread(
        self,
        target: Callable[..., Any],
        *,
        name: str,
        args: tuple[Any, ...] = (),
        daemon: bool = True,
    ) -> VThread:
        return VThread(self, target, name=name, args=args)

    # -- entering ---------------------------------------------------------------------------
    @contextlib.contextmanager
    def running(self) -> Iterator[VirtualClock]:
        """Make the calling thread the clock's first thread for the ``with`` block."""
        me = threading.get_ident()
        with self._mu:
            if self._root is not None:
                raise SimulationHang("the virtual clock is already running")
            task = _Task(threading.current_thread().name)
            task.ident = me
            task.native = threading.get_native_id()
            self._tasks[me] = task
            self._alive.append(task)
            self._root = task
            self._current = task
        # before any clock thread starts: they inherit the entering thread's CPU set
        restore = self._pinned = pin_to_this_cpu() if self.pin_cpu else None
        self._watchdog_stop.clear()
        self._watchdog = threading.Thread(
            target=self._watch, name="virtual-clock-watchdog", daemon=True
        )
        self._watchdog.start()
        try:
            yield self
        finally:
            self._end_others(task)
            self._watchdog_stop.set()
            with self._mu:
                task.done = True
                self._alive.remove(task)
                del self._tasks[me]
                self._root = None
                self._current = None
                self._closing = False
            if restore is not None:
                self._pinned = None
                self._watchdog.join(timeout=1.0)  # not moving threads any more (a host wait)
                with contextlib.suppress(OSError):
                    os.sched_setaffinity(0, restore)

    def _end_others(self, root: _Task) -> None:
        """End every thread still alive: their waits raise ClockClosed, one after another."""
        with self._mu:
            self._closing = True
            for t in self._alive:
                if t is not root:
                    t.kill = True
                    self._wake(t)
        while True:
            with self._mu:
                others = [t for t in self._alive if t is not root]
            if not others:
                return
            try:
                self._block("ending the clock's threads", None, closing_ok=True)
            except ClockClosed:  # pragma: no cover - the root is never killed
                return

    # -- the scheduler ------------------------------------------------------------------------
    def _me(self) -> _Task:
        cur = self._current
        if cur is not None and cur.ident == _get_ident():
            return cur
        task = self._tasks.get(_get_ident())
        if task is None:
            raise SimulationHang(
                f"thread {threading.current_thread().name!r} used the virtual clock but was not "
                "started by it (start threads of a simulated run with clock.thread())"
            )
        return task

    def _wake(self, task: _Task) -> None:
        """Make a blocked task runnable (with ``_mu`` held)."""
        if task.blocked:
            task.blocked = False
            task.timed_out = False
            task.wait_id += 1
            self._ready.append(task)

    def _next(self) -> _Task:
        """The task to run next (with ``_mu`` held): the first runnable, else time jumps. A host
        thread due inside a host stall is put off to the stall's end."""
        while True:
            task = self._pick()
            if task.device or not self._stalls or task.error is not None or task.kill:
                return task
            end = self._stalled_until(self._now)
            if end is None:
                return task
            task.resume_timed_out = task.timed_out
            task.blocked = True
            task.wait_id += 1
            heapq.heappush(self._timers, (end, next(self._seq), task, task.wait_id, True))

    def _pick(self) -> _Task:
        while True:
            if self._ready:
                item = self._ready.popleft()
                if isinstance(item, _Callback):
                    self._run_callback(item)
                    continue
                return item
            if not self._timers:
                return self._deadlock()
            deadline, _, task, wid, resume = heapq.heappop(self._timers)
            if isinstance(task, _Task):
                if task.blocked and task.wait_id == wid:
                    if deadline > self._now:
                        self._now = deadline
                    task.blocked = False
                    task.timed_out = task.resume_timed_out if resume else True
                    task.wait_id += 1
                    return task
                continue
            if deadline > self._now:
                self._now = deadline
            if isinstance(task, VEvent):  # an event set at its time: its waiters run
                task._set_locked()
            else:  # a callback at its time
                self._run_callback(task)

    def _deadlock(self) -> _Task:
        lines = [f"  {t.name}: waits on {t.waiting_on or '?'}" for t in self._alive if t.blocked]
        msg = (
            f"simulated time {self._now - self._t0:.3f} s: every thread waits with no deadline "
            "and nothing left to wake it:\n" + "\n".join(lines)
        )
        self.hang = msg
        victim = self._root if self._root is not None and self._root.blocked else None
        if victim is None:
            victim = next(t for t in self._alive if t.blocked)
        victim.blocked = False
        victim.wait_id += 1
        victim.error = SimulationHang(msg)
        return victim

    def _block(self, what: str, deadline: float | None, *, closing_ok: bool = False) -> bool:
        """Give the baton up until woken (True) or ``deadline`` passes (False)."""
        if self._in_callback:
            raise SimulationHang(f"a clock callback waited ({what}): callbacks never wait")
        while self._signalled:  # only the baton holder comes here: none taken meanwhile
            self._signalled.popleft()()
        task = self._me()
        with self._mu:
            if task.kill and not closing_ok:
                raise ClockClosed
            task.blocked = True
            task.timed_out = False
            task.waiting_on = what
            if deadline is not None:
                heapq.heappush(
                    self._timers, (deadline, next(self._seq), task, task.wait_id, False)
                )
            elif closing_ok:
                self._ready.append(task)  # the root yields while the others end
                task.blocked = False
            nxt = self._next()
            self._current = nxt
            self.switches += 1
            if nxt is not task:
                nxt.sem.release()
        if nxt is not task:
            task.sem.acquire()
        if task.error is not None:
            err, task.error = task.error, None
            raise err
        if task.kill and not closing_ok:
            raise ClockClosed
        return not task.timed_out

    def _leave(self, task: _Task) -> None:
        """A clock thread ends: wake its joiners and hand the baton on."""
        with self._mu:
            task.done = True
            self._alive.remove(task)
            self._tasks.pop(task.ident or 0, None)
            for j in task.joiners:
                self._wake(j)
            task.joiners.clear()
            nxt = self._next()
            self._current = nxt
            self.switches += 1
            nxt.sem.release()

    # -- the watchdog -------------------------------------------------------------------------
    def _repin(self, allowed: set[int]) -> None:
        """Let the operating system place the clock's threads anew for a moment, then keep them
        on the CPU the one holding the baton went to: a CPU shared with another busy process
        when the clock was entered (another run kept on it, a child process that has ended
        since) is not kept for the whole run while another CPU stands idle."""

        def place(cpus: set[int]) -> None:  # the clock's threads and this watchdog
            with self._mu:
                tids = [t.native for t in self._alive if t.native is not None]
            for tid in [*tids, threading.get_native_id()]:
                with contextlib.suppress(OSError):
                    os.sched_setaffinity(tid, cpus)

        place(allowed)
        if self._watchdog_stop.wait(REPIN_WINDOW_S):
            return  # the clock is being left: its entering thread gives the set back
        cur = self._current
        cpu = None if cur is None or cur.native is None else _cpu_of(cur.native)
        if cpu is None or cpu not in allowed:
            return
        place({cpu})

    def _watch(self) -> None:
        # host time without a hand-over, counted in the watchdog's own steps: a step longer
        # than two of them means the whole process was stopped (SIGSTOP, a suspended machine)
        # and the thread holding the clock was not stuck, so it counts as two at most
        interval = min(1.0, self.hang_s / 4)
        last = self.switches
        quiet = 0.0
        prev = time.monotonic()
        steps = 0
        while not self._watchdog_stop.wait(interval):
            steps += 1
            if self._pinned is not None and steps % REPIN_STEPS == 0:
                self._repin(self._pinned)
            now = time.monotonic()
            step, prev = min(now - prev, 2.0 * interval), now
            if self.switches != last:
                last = self.switches
                quiet = 0.0
                continue
            quiet += step
            if quiet < self.hang_s:
                continue
            cur = self._current
            if cur is None or cur.ident is None:
                continue
            frame = sys._current_frames().get(cur.ident)
            where = "".join(traceback.format_stack(frame, limit=6)) if frame else "?"
            self.hang = (
                f"simulated time {self._now - self._t0:.3f} s: thread {cur.name!r} has held "
                f"the clock for {self.hang_s:g} s of host time without waiting on it (a wait "
                f"outside the clock, or a loop that never waits); it is at:\n{where}"
            )
            log.error("%s", self.hang)
            ctypes.pythonapi.PyThreadState_SetAsyncExc(
                ctypes.c_ulong(cur.ident), ctypes.py_object(SimulationHang)
            )
            quiet = 0.0


class VEvent:
    """``threading.Event`` on a :class:`VirtualClock`."""

    def __init__(self, clock: VirtualClock) -> None:
        self._c = clock
        self._flag = False
        self._waiters: list[_Task] = []

    def is_set(self) -> bool:
        return self._flag

    def set(self) -> None:
        with self._c._mu:
            self._set_locked()

    def _set_locked(self) -> None:
        self._flag = True
        for t in self._waiters:
            self._c._wake(t)
        self._waiters.clear()

    def clear(self) -> None:
        self._flag = False

    def wait(self, timeout: float | None = None) -> bool:
        if self._flag:
            return True
        if timeout is not None and timeout <= 0:
            return False
        c = self._c
        task = c._me()
        self._waiters.append(task)
        deadline = None if timeout is None else c._now + timeout
        if not c._block("Event.wait", deadline):
            with c._mu:
                if task in self._waiters:
                    self._waiters.remove(task)
        return self._flag


class VLock:
    """``threading.Lock`` on a :class:`VirtualClock` (FIFO hand-over on release)."""

    def __init__(self, clock: VirtualClock) -> None:
        self._c = clock
        self._owner: _Task | None = None
        self._waiters: deque[_Task] = deque()

    def locked(self) -> bool:
        return self._owner is not None

    def acquire(self, blocking: bool = True, timeout: float = -1) -> bool:
        c = self._c
        task = c._me()
        if self._owner is None:  # uncontended (only the baton holder runs: no race)
            self._owner = task
            return True
        with c._mu:
            if self._owner is None:
                self._owner = task
                return True
            if not blocking or timeout == 0:
                return False
            self._waiters.append(task)
        deadline = None if timeout is None or timeout < 0 else c._now + timeout
        if c._block(f"{type(self).__name__}.acquire", deadline):
            return True
        with c._mu:
            if self._owner is task:  # handed over as the timeout fell
                return True
            if task in self._waiters:
                self._waiters.remove(task)
        return False

    def release(self) -> None:
        if not self._waiters:
            self._owner = None
            return
        c = self._c
        with c._mu:
            if self._waiters:
                nxt = self._waiters.popleft()
                self._owner = nxt
                c._wake(nxt)
            else:
                self._owner = None

    def _release_save(self) -> Any:
        self.release()
        return None

    def _acquire_restore(self, saved: Any) -> None:
        self.acquire()

    def __enter__(self) -> bool:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


class VRLock(VLock):
    """``threading.RLock`` on a :class:`VirtualClock`."""

    def __init__(self, clock: VirtualClock) -> None:
        super().__init__(clock)
        self._count = 0

    def acquire(self, blocking: bool = True, timeout: float = -1) -> bool:
        task = self._c._me()
        owner = self._owner
        if owner is task:
            self._count += 1
            return True
        if owner is None:  # uncontended: VLock.acquire's own first step
            self._owner = task
            self._count = 1
            return True
        if super().acquire(blocking, timeout):
            self._count = 1
            return True
        return False

    def release(self) -> None:
        if self._owner is not self._c._me():
            raise RuntimeError("cannot release un-acquired lock")
        self._count -= 1
        if self._count == 0:
            if not self._waiters:  # VLock.release's own first step
                self._owner = None
                return
            super().release()

    def _release_save(self) -> Any:
        n = self._count
        self._count = 1
        self.release()
        return n

    def _acquire_restore(self, saved: Any) -> None:
        self.acquire()
        self._count = int(saved)


class VCondition:
    """``threading.Condition`` on a :class:`VirtualClock`."""

    def __init__(self, clock: VirtualClock, lock: Any) -> None:
        self._c = clock
        self._lock = lock
        self._waiters: deque[_Task] = deque()

    def acquire(self, blocking: bool = True, timeout: float = -1) -> bool:
        return bool(self._lock.acquire(blocking, timeout))

    def release(self) -> None:
        self._lock.release()

    def __enter__(self) -> bool:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()

    def wait(self, timeout: float | None = None) -> bool:
        c = self._c
        task = c._me()
        self._waiters.append(task)
        saved = self._lock._release_save()
        deadline = None if timeout is None else c._now + max(0.0, timeout)
        ok = c._block("Condition.wait", deadline)
        if not ok:
            with c._mu:
                if task in self._waiters:
                    self._waiters.remove(task)
        self._lock._acquire_restore(saved)
        return ok

    def wait_for(self, predicate: Callable[[], Any], timeout: float | None = None) -> Any:
        end = None if timeout is None else self._c._now + timeout
        result = predicate()
        while not result:
            left = None if end is None else end - self._c._now
            if left is not None and left <= 0:
                break
            self.wait(left)
            result = predicate()
        return result

    def notify(self, n: int = 1) -> None:
        with self._c._mu:
            for _ in range(min(n, len(self._waiters))):
                self._c._wake(self._waiters.popleft())

    def notify_all(self) -> None:
        self.notify(len(self._waiters))


class VQueue:
    """``queue.Queue`` on a :class:`VirtualClock` (raises ``queue.Empty``/``queue.Full``)."""

    def __init__(self, clock: VirtualClock, maxsize: int = 0) -> None:
        self._c = clock
        self.maxsize = maxsize
        self._items: deque[Any] = deque()
        self._getters: deque[_Task] = deque()
        self._putters: deque[_Task] = deque()

    def qsize(self) -> int:
        return len(self._items)

    def empty(self) -> bool:
        return not self._items

    def full(self) -> bool:
        return 0 < self.maxsize <= len(self._items)

    def _wait(self, waiters: deque[_Task], what: str, end: float | None) -> bool:
        c = self._c
        task = c._me()
        waiters.append(task)
        if not c._block(what, end):
            with c._mu:
                if task in waiters:
                    waiters.remove(task)
            return False
        return True

    def put(self, item: Any, block: bool = True, timeout: float | None = None) -> None:
        end = None if timeout is None else self._c._now + timeout
        while self.full():
            waited = block and self._wait(self._putters, "Queue.put", end)
            if not waited and self.full():
                raise queue.Full
        self._items.append(item)
        with self._c._mu:
            if self._getters:
                self._c._wake(self._getters.popleft())

    def put_nowait(self, item: Any) -> None:
        self.put(item, block=False)

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        end = None if timeout is None else self._c._now + timeout
        while not self._items:
            if not block or (end is not None and end <= self._c._now):
                raise queue.Empty
            if not self._wait(self._getters, "Queue.get", end) and not self._items:
                raise queue.Empty
        item = self._items.popleft()
        with self._c._mu:
            if self._putters:
                self._c._wake(self._putters.popleft())
        return item

    def get_nowait(self) -> Any:
        return self.get(block=False)


class VThread:
    """``threading.Thread`` on a :class:`VirtualClock`: runs only while it holds the baton."""

    def __init__(
        self,
        clock: VirtualClock,
        target: Callable[..., Any],
        *,
        name: str,
        args: tuple[Any, ...] = (),
    ) -> None:
        self._c = clock
        self._target = target
        self._args = args
        self.name = name
        self.daemon = True
        self._task: _Task | None = None

    def start(self) -> None:
        c = self._c
        c._me()  # only a clock thread may start one
        task = _Task(self.name)
        self._task = task
        registered = threading.Event()

        def body() -> None:
            task.ident = threading.get_ident()
            task.native = threading.get_native_id()
            with c._mu:
                c._tasks[task.ident] = task
            registered.set()
            task.sem.acquire()  # wait for the baton
            try:
                if not task.kill:
                    self._target(*self._args)
            except ClockClosed:
                pass
            except BaseException:
                exc_type, exc, tb = sys.exc_info()
                threading.excepthook(
                    threading.ExceptHookArgs((exc_type, exc, tb, threading.current_thread()))
                )
            finally:
                c._leave(task)

        real = threading.Thread(target=body, name=self.name, daemon=True)
        with c._mu:
            c._alive.append(task)
            c._ready.append(task)
        real.start()
        registered.wait()  # a host wait of microseconds: the ident must be known before it runs

    def join(self, timeout: float | None = None) -> None:
        task = self._task
        if task is None or task.done:
            return
        c = self._c
        me = c._me()
        task.joiners.append(me)
        deadline = None if timeout is None else c._now + timeout
        if not c._block(f"join {self.name}", deadline):
            with c._mu:
                if me in task.joiners:
                    task.joiners.remove(me)

    def is_alive(self) -> bool:
        return self._task is not None and not self._task.done
