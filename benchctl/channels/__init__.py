"""In-process byte links on a clock: the TCP socket and the pseudo-terminals of a simulated run.

A :func:`link` is two :class:`Endpoint` objects joined by two one-way pipes. What one end writes
the other reads — after the modelled ``latency_s`` and, on a serial line, ``byte_time_s`` per
byte: a write arrives whole when its last byte is in. A line sends one write after another: a
write waits for the one before to be on the wire. Waits go through the clock the link was made
on, so on a :class:`~benchctl.clock.virtual.VirtualClock` a read that waits lets simulated time
run to the next write's arrival.

The real drivers reach an endpoint the way they reach hardware:

- through pyserial: ``serial.serial_for_url("simchan://NAME")`` opens the endpoint registered as
  ``NAME`` (:func:`register`) — python-can's slcan bus and the NMEA 0183 reader open their port
  this way, unchanged;
- through :mod:`benchctl.devices.modbus.channel_client` (pymodbus's TCP and RTU clients with the
  socket or the serial port replaced by an endpoint).

Closing an endpoint closes the link both ways: the peer's reads return what was still in flight,
then ``b""`` at once (a dropped connection, a hung-up line), and writes raise ``OSError``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Any

import serial

from benchctl.clock import Clock

__all__ = ["Endpoint", "free_name", "link", "lookup", "register", "unregister"]

#: pyserial finds ``protocol_simchan`` in this package for ``simchan://`` URLs
if "benchctl.channels" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("benchctl.channels")

#: a write counts as arrived this early: a sum of float times never leaves a reader waking at
#: its arrival one rounding short of it
_EPS = 1e-9


class _Pipe:
    """One direction: the writes in flight, each with the time it arrives whole."""

    def __init__(self, clock: Clock) -> None:
        self.chunks: deque[list[Any]] = deque()  # [t_arrival, data, bytes already taken]
        self.busy_until = -math.inf  # the line is sending until then
        self.changed = clock.event()
        self.closed = False
        #: the reading end's handler run by the clock at each write's arrival (``serve``)
        self.handler: tuple[Callable[[], Any], str] | None = None

    def arrived(self, now: float) -> int:
        """Bytes arrived and not yet taken."""
        n = 0
        for t, data, taken in self.chunks:
            if now + _EPS < t:
                break
            n += len(data) - taken
        return n

    def next_arrival(self) -> float | None:
        """When the first write not yet taken arrives (None: nothing in flight)."""
        return float(self.chunks[0][0]) if self.chunks else None

    def take(self, now: float, size: int) -> bytes:
        out = bytearray()
        while self.chunks and len(out) < size:
            c = self.chunks[0]
            t, data, taken = c
            if now + _EPS < t:
                break
            k = min(len(data) - taken, size - len(out))
            out += data[taken : taken + k]
            c[2] = taken + k
            if c[2] == len(data):
                self.chunks.popleft()
        return bytes(out)


class Endpoint:
    """One end of an in-process byte link (see the module's text)."""

    def __init__(
        self,
        clock: Clock,
        rx: _Pipe,
        tx: _Pipe,
        name: str,
        *,
        byte_time_s: float = 0.0,
        latency_s: float = 0.0,
    ) -> None:
        self.clock = clock
        self._rx = rx
        self._tx = tx
        self.name = name
        self.byte_time_s = byte_time_s
        self.latency_s = latency_s
        #: each write's extra delay in seconds, or None: the write is lost (seeded faults)
        self.delay: Callable[[bytes], float | None] | None = None
        #: each write as it arrives (changed), or None: lost (seeded faults)
        self.damage: Callable[[bytes], bytes | None] | None = None

    @property
    def closed(self) -> bool:
        return self._tx.closed

    def write(self, data: bytes) -> int:
        if self._tx.closed:
            raise OSError(f"{self.name}: link closed")
        n = len(data)
        if n == 0:
            return n
        extra = 0.0
        if self.delay is not None:
            d = self.delay(data)
            if d is None:
                return n
            extra = d
        if self.damage is not None:
            got = self.damage(data)
            if got is None:
                return n
            data = got
        start = max(self.clock.monotonic() + self.latency_s + extra, self._tx.busy_until)
        self._tx.busy_until = start + n * self.byte_time_s
        self._tx.chunks.append([self._tx.busy_until, bytes(data), 0])  # whole, its last byte in
        # the reader wakes when the write has arrived (a reader waiting for it has nothing to
        # read before then), or the clock runs its handler then
        if self._tx.handler is not None:
            fn, name = self._tx.handler
            self.clock.call_at(self._tx.busy_until, fn, name)  # type: ignore[attr-defined]
        else:
            self.clock.set_at(self._tx.changed, self._tx.busy_until)
        return n

    @property
    def in_waiting(self) -> int:
        return self._rx.arrived(self.clock.monotonic())

    def _wait_arrival(self, timeout: float | None) -> bool:
        """Wait up to ``timeout`` (None: for ever) until a byte has arrived: True; False on the
        timeout, or at once when the link is closed with nothing left in flight."""
        clock, rx = self.clock, self._rx
        end = None if timeout is None else clock.monotonic() + max(0.0, timeout)
        while True:
            rx.changed.clear()
            now = clock.monotonic()
            if rx.arrived(now):
                return True
            nxt = rx.next_arrival()
            if (nxt is None and rx.closed) or (end is not None and now >= end):
                return False
            deadline = nxt if end is None else end if nxt is None else min(nxt, end)
            rx.changed.wait(None if deadline is None else max(0.0, deadline - now))

    def read(self, size: int = 1, timeout: float | None = None) -> bytes:
        """Up to ``size`` bytes that have arrived; waits up to ``timeout`` (None: for ever) for
        the first one. ``b""`` on a timeout, and at once once the link is closed and empty."""
        if not self._wait_arrival(timeout):
            return b""
        return self._rx.take(self.clock.monotonic(), size)

    def wait_readable(self, timeout: float | None = None) -> bool:
        """Wait up to ``timeout`` until a byte has arrived (or the link closed); True if one
        has."""
        return self._wait_arrival(timeout)

    def serve(self, handler: Callable[[], Any], name: str) -> None:
        """On a virtual clock: the clock runs ``handler`` (in the place of a device thread
        ``name`` waiting in :meth:`read`) at each write's arrival at this end, instead of waking
        a reader (:meth:`~benchctl.clock.virtual.VirtualClock.call_at`); it reads what has
        arrived with ``read(size, 0.0)``, never waiting."""
        if not getattr(self.clock, "virtual", False):
            raise TypeError(f"{self.name}: serve() needs a virtual clock")
        self._rx.handler = (handler, name)

    def reset_input(self) -> None:
        self._rx.chunks.clear()

    def close(self) -> None:
        for p in (self._rx, self._tx):
            p.closed = True
            p.changed.set()
            if p.handler is not None:  # as a reader woken by the close: runs after those ready
                fn, name = p.handler
                self.clock.call_at(self.clock.monotonic(), fn, name)  # type: ignore[attr-defined]


def link(
    clock: Clock,
    name: str,
    *,
    byte_time_s: float = 0.0,
    latency_s: float = 0.0,
) -> tuple[Endpoint, Endpoint]:
    """A byte link: (host end, device end), ``latency_s`` and ``byte_time_s`` both ways."""
    a_to_b, b_to_a = _Pipe(clock), _Pipe(clock)
    host = Endpoint(clock, b_to_a, a_to_b, f"{name} (host end)",
                    byte_time_s=byte_time_s, latency_s=latency_s)
    device = Endpoint(clock, a_to_b, b_to_a, f"{name} (device end)",
                      byte_time_s=byte_time_s, latency_s=latency_s)
    return host, device


_REGISTRY: dict[str, Endpoint] = {}


def register(name: str, endpoint: Endpoint) -> str:
    """Make ``endpoint`` openable as ``simchan://NAME``; returns the URL."""
    _REGISTRY[name] = endpoint
    return f"simchan://{name}"


def unregister(name: str) -> None:
    """Forget ``name`` (or its ``simchan://`` URL)."""
    _REGISTRY.pop(name.split("://", 1)[-1], None)


def free_name(base: str) -> str:
    """``base``, or ``base-2``, ``base-3``… : the first name no open endpoint is registered
    under (the same names in the same order in every run of one process)."""
    name, n = base, 1
    while name in _REGISTRY and not _REGISTRY[name].closed:
        n += 1
        name = f"{base}-{n}"
    return name


def lookup(url: str) -> Endpoint:
    name = url.split("://", 1)[1] if "://" in url else url
    try:
        return _REGISTRY[name]
    except KeyError:
        raise serial.SerialException(f"{url}: no such simulated channel") from None
