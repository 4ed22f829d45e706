"""The simulated instrument on an in-process link, for simulated time: its port and its loop.

``_ChannelPort`` is the simulator's end of a ``benchctl.channels`` link with the calls a
``PtyPort`` offers. ``_Loop`` is ``SimInstrument``'s channel loop without a thread: the virtual
clock runs it by callbacks (``VirtualClock.call_at``) from each point where the thread would
have been woken to the point where it would wait again — the same outputs at the same instants
in the same order, without handing the clock's baton over for each.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, Protocol

from benchctl.channels import link as channel_link
from benchctl.channels import register as register_channel
from benchctl.clock import Clock, EventLike
from benchctl.sim.instrument_model import InstrumentModel


class _LoopHost(Protocol):
    """What ``_Loop`` runs of ``benchctl.sim.instrument.SimInstrument`` (its loop's steps)."""

    clock: Clock
    model: InstrumentModel
    _port: Any
    _faults: dict[str, dict[str, Any]]
    _stop: EventLike
    _ready: EventLike
    _start_error: BaseException | None

    def _serve_host(self, port: Any) -> None: ...

    def _send_raw(self, port: Any) -> None: ...

    def _tick_due(self, k: int, t0: float, period: float, now: float) -> int: ...


class _Loop:
    """:meth:`SimInstrument._run_channel` without its thread, on a virtual clock: the clock
    runs the loop (``VirtualClock.call_at``) from each point where the thread would have been
    woken — its output instant or the arrival of the host's bytes (``Endpoint.serve``) — to
    the point where it would wait again, with the same waits' arithmetic
    (``Endpoint.wait_readable``, ``VEvent.wait``): the same outputs at the same instants in the
    same order, without a hand-over of the baton for each. ``start``/``join`` as the thread's
    (the first pass runs after the threads already runnable; ``join`` waits for the pass that
    sees the stop)."""

    def __init__(self, sim: _LoopHost, name: str) -> None:
        self.sim = sim
        self.name = name
        port = sim._port
        assert isinstance(port, _ChannelPort)
        self.port = port
        self.clock: Any = sim.clock
        self.gen = 0  # the current wait's number: a deadline set for an earlier one is stale
        self.end = 0.0  # the current wait's end (the next output instant)
        self.t0 = 0.0
        self.k = 1
        self.done = False
        self.exited = sim.clock.event()

    def start(self) -> None:
        self.port._ep.serve(lambda: self._wake(None), self.name)
        self.clock.call_at(self.clock.monotonic(), self._first, self.name)

    def join(self, timeout: float | None = None) -> None:
        if self.done or getattr(self.clock, "_root", None) is None:
            return  # ended, or the clock has closed (as it ends its threads)
        self.exited.wait(timeout)

    def is_alive(self) -> bool:
        return not self.done

    def _first(self) -> None:
        sim = self.sim
        self.t0 = self.clock.monotonic()
        self.k = 1
        sim._ready.set()
        self._run(self._top)

    def _wake(self, gen: int | None) -> None:
        """Woken: by the host's bytes arriving (``gen`` None) or by the wait's deadline."""
        if self.done or (gen is not None and gen != self.gen):
            return
        self._run(self._waiting)

    def _run(self, phase: Callable[[], bool]) -> None:
        """From ``phase`` (the loop's head, or its wait's), go on with the loop until it waits
        again or ends."""
        sim = self.sim
        try:
            blocked = phase()
            while not blocked:
                sim._serve_host(self.port)
                sim._send_raw(self.port)
                self.k = sim._tick_due(self.k, self.t0, sim.model.period_s,
                                       self.clock.monotonic())
                blocked = self._top()
        except Exception as e:  # a simulator bug must not pass for a silent instrument
            sim._start_error = e
            self.port.close()
            self._exit()
            raise
        except BaseException:
            self._exit()
            raise

    def _exit(self) -> None:
        self.done = True
        self.gen += 1
        self.exited.set()

    def _top(self) -> bool:
        """The loop's head, up to its wait: True when it waits, False when the wait is over
        at once; the loop ended: True (nothing more to do)."""
        sim = self.sim
        if sim._stop.is_set():
            self._exit()
            return True
        if "drop" in sim._faults:
            self.port.close()
            self._exit()
            return True
        next_t = self.t0 + self.k * sim.model.period_s
        clock = self.clock
        # port.wait(timeout) → Endpoint._wait_arrival(timeout), as the thread computes it
        timeout = max(0.0, next_t - clock.monotonic())
        self.end = clock.monotonic() + max(0.0, timeout)
        return self._waiting()

    def _waiting(self) -> bool:
        """``Endpoint._wait_arrival``'s loop from its head: False when the wait is over (the
        loop goes on), True when it waits (a deadline set; the host's bytes wake it too)."""
        rx = self.port._ep._rx
        clock = self.clock
        self.gen += 1  # whatever deadline was set for the wait before is stale now
        while True:
            rx.changed.clear()
            now = clock.monotonic()
            if rx.arrived(now):
                return False
            nxt = rx.next_arrival()
            end = self.end
            if (nxt is None and rx.closed) or now >= end:
                return False
            deadline = end if nxt is None else min(nxt, end)
            timeout = max(0.0, deadline - now)
            if timeout <= 0:  # VEvent.wait returns at once
                continue
            clock.call_at(now + timeout, functools.partial(self._wake, self.gen), self.name)
            return True


class _ChannelPort:
    """The simulator's side of an in-process link, with the calls ``PtyPort`` offers."""

    def __init__(self, clock: Clock, name: str, baudrate: int) -> None:
        host, self._ep = channel_link(clock, name, byte_time_s=10.0 / baudrate)
        self.path = register_channel(name, host)
        self._host = host
        self.has_pending = False
        self.master_fd = None

    @property
    def closed(self) -> bool:
        return self._ep.closed

    def wait(self, timeout: float) -> None:
        self._ep.wait_readable(timeout)

    def read(self) -> bytes:
        return self._ep.read(1 << 16, 0.0) if not self._ep.closed else b""

    def write(self, data: bytes) -> bool:
        if self._ep.closed:
            return False
        self._ep.write(data)
        return True

    def flush(self) -> None:
        return None

    def close(self) -> None:
        self._ep.close()
