"""In-process byte links on a clock: the TCP socket and the pseudo-terminals of a simulated run.

A :func:`link` is two :class:`Endpoint` objects joined by two one-way pipes. What one end writes
the other reads — after the modelled ``latency_s`` and, on a serial line, ``byte_time_s`` per
byte: a write arrives whole when its last byte is in (``per_byte=True``: byte by byte, as on the
wire, ``in_waiting`` growing while a frame comes in — truer, and dearer: a reader then wakes for
each byte). A line sends one write after another: a write waits for the one before to be on the
wire. Waits go through the clock the link was made
on, so on a :class:`~benchctl.clock.virtual.VirtualClock` a read that waits lets simulated time
run to the next byte's arrival.

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

_EPS = 1e-12
#: bytes counted as arrived a millionth of a byte time early: the sum of float times never
#: leaves a reader waking at a byte's arrival one rounding short of it
_BYTE_EPS = 1e-6


class _Pipe:
    """One direction: chunks of bytes with the time their first byte arrives."""

    def __init__(self, clock: Clock) -> None:
        self.chunks: deque[list[Any]] = deque()  # [t_first_byte_done, byte_time, data, taken]
        self.busy_until = -math.inf  # the line is sending until then
        self.changed = clock.event()
        self.closed = False

    def arrived(self, now: float) -> int:
        n = 0
        for t0, bt, data, taken in self.chunks:
            if now + _EPS < t0:
                break
            full = len(data) if bt <= 0 else min(len(data), int((now - t0) / bt + _BYTE_EPS) + 1)
            n += full - taken
            if full < len(data):
                break
        return n

    def next_arrival(self, now: float) -> float | None:
        """When the next byte not yet arrived arrives (None: nothing in flight)."""
        for t0, bt, data, taken in self.chunks:
            if now + _EPS < t0:
                return float(t0)
            full = len(data) if bt <= 0 else min(len(data), int((now - t0) / bt + _BYTE_EPS) + 1)
            if full < len(data):
                return float(t0 + full * bt)
            if full > taken:
                return now
        return None

    def take(self, now: float, size: int) -> bytes:
        out = bytearray()
        while self.chunks and len(out) < size:
            c = self.chunks[0]
            t0, bt, data, taken = c
            if now + _EPS < t0:
                break
            full = len(data) if bt <= 0 else min(len(data), int((now - t0) / bt + _BYTE_EPS) + 1)
            k = min(full - taken, size - len(out))
            out += data[taken : taken + k]
            c[3] = taken + k
            if c[3] == len(data):
                self.chunks.popleft()
            else:
                break
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
        per_byte: bool = False,
    ) -> None:
        self.clock = clock
        self.per_byte = per_byte
        self._rx = rx
        self._tx = tx
        self.name = name
        self.byte_time_s = byte_time_s
        self.latency_s = latency_s
        #: bytes written and read through this end (for figures and tests)
        self.bytes_out = 0
        self.bytes_in = 0
        #: while True every byte written from this end is lost (a cut line, a lost frame)
        self.muted = False
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
        if n == 0 or self.muted:
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
        now = self.clock.monotonic()
        start = max(now + self.latency_s + extra, self._tx.busy_until)
        bt = self.byte_time_s
        self._tx.busy_until = start + n * bt
        if self.per_byte:
            self._tx.chunks.append([start + bt, bt, bytes(data), 0])
        else:  # the whole write at once, when its last byte is in
            self._tx.chunks.append([start + n * bt, 0.0, bytes(data), 0])
        self._tx.changed.set()
        self.bytes_out += n
        return n

    @property
    def in_waiting(self) -> int:
        return self._rx.arrived(self.clock.monotonic())

    def read(self, size: int = 1, timeout: float | None = None) -> bytes:
        """Up to ``size`` bytes that have arrived; waits up to ``timeout`` (None: for ever) for
        the first one. ``b""`` on a timeout, and at once once the link is closed and empty."""
        clock = self.clock
        end = None if timeout is None else clock.monotonic() + max(0.0, timeout)
        while True:
            self._rx.changed.clear()
            now = clock.monotonic()
            got = self._rx.take(now, size)
            if got:
                self.bytes_in += len(got)
                return got
            nxt = self._rx.next_arrival(now)
            if nxt is None and self._rx.closed:
                return b""
            if end is not None and now >= end:
                return b""
            deadline = min(t for t in (end, nxt) if t is not None) if (end or nxt) else None
            self._rx.changed.wait(None if deadline is None else max(0.0, deadline - now))

    def wait_readable(self, timeout: float | None = None) -> bool:
        """Wait up to ``timeout`` until a byte has arrived (or the link closed); True if one
        has."""
        clock = self.clock
        end = None if timeout is None else clock.monotonic() + max(0.0, timeout)
        while True:
            self._rx.changed.clear()
            now = clock.monotonic()
            if self._rx.arrived(now):
                return True
            nxt = self._rx.next_arrival(now)
            if self._rx.closed and nxt is None:
                return False
            if end is not None and now >= end:
                return False
            deadline = min(t for t in (end, nxt) if t is not None) if (end or nxt) else None
            self._rx.changed.wait(None if deadline is None else max(0.0, deadline - now))

    def read_chunk(self, timeout: float | None = None) -> bytes:
        """Wait for the first chunk the peer wrote to arrive whole, and return it with every
        byte arrived after it (a device reading a frame up to the line's silence)."""
        clock = self.clock
        end = None if timeout is None else clock.monotonic() + max(0.0, timeout)
        while True:
            self._rx.changed.clear()
            now = clock.monotonic()
            if self._rx.chunks:
                t0, bt, data, _ = self._rx.chunks[0]
                done = t0 + (len(data) - 1) * bt
                if now + _EPS >= done:
                    got = self._rx.take(now, 1 << 30)
                    self.bytes_in += len(got)
                    return got
                deadline = done if end is None else min(done, end)
            elif self._rx.closed:
                return b""
            else:
                deadline = end
            if end is not None and now >= end:
                return b""
            self._rx.changed.wait(None if deadline is None else max(0.0, deadline - now))

    def reset_input(self) -> None:
        self._rx.chunks.clear()

    def close(self) -> None:
        for p in (self._rx, self._tx):
            p.closed = True
            p.changed.set()


def link(
    clock: Clock,
    name: str,
    *,
    byte_time_s: float = 0.0,
    latency_s: float = 0.0,
    per_byte: bool = False,
) -> tuple[Endpoint, Endpoint]:
    """A byte link: (host end, device end), ``latency_s`` and ``byte_time_s`` both ways."""
    a_to_b, b_to_a = _Pipe(clock), _Pipe(clock)
    host = Endpoint(clock, b_to_a, a_to_b, f"{name} (host end)",
                    byte_time_s=byte_time_s, latency_s=latency_s, per_byte=per_byte)
    device = Endpoint(clock, a_to_b, b_to_a, f"{name} (device end)",
                      byte_time_s=byte_time_s, latency_s=latency_s, per_byte=per_byte)
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
