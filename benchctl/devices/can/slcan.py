"""The host side of a slcan (LAWICEL) adapter: every line it sends is a frame, an answer or bad.

python-can's ``slcanBus`` reads the serial line byte by byte, decodes each line as UTF-8 and
parses it leniently: a byte that is not UTF-8 raises ``CanOperationError`` (the same error as a
port that is gone) and leaves the line in its buffer, so every later line fails too; a line
with an unknown first character is dropped without a word; a frame line with hex digits missing
or left over is passed on. ``SlcanBus`` is that bus with its receive side replaced:

- the line is split at CR (OK) or BEL (error), as python-can does, from reads of whatever is
  waiting (not one byte per read);
- ``parse_line`` accepts ``tIIIL…``/``TIIIIIIIIL…`` data frames and ``r``/``R`` remote frames
  (classic CAN: DLC 0–8, 11-bit id ≤ 7FF, 29-bit id ≤ 1FFFFFFF, exactly ``2·DLC`` hex digits,
  optionally the 4 hex digits of a ``Z1`` timestamp), skips the adapter's answers (an empty
  line, BEL, ``z``/``Z`` transmit acknowledgements) and raises ``SlcanLineError`` for anything
  else: a byte that is not printable ASCII, an unknown command letter, a malformed frame;
- more than ``MAX_LINE`` bytes without CR or BEL is garbage: dropped, ``SlcanLineError``.

Adapter timestamps: with ``adapter_timestamps=True`` (the default) the bus sends ``Z1`` while
the channel is closed, before opening it, so the adapter appends to every received frame the
4 hex digits of its own millisecond clock at the moment it took the frame off the bus
(LAWICEL: 0…EA5F, wrapping at 60 000 ms; some firmwares wrap at 65 536). ``parse_line`` gives
that value as the message's ``adapter_ms`` (None when the line has none); ``AdapterClock``
unwraps it into continuous seconds, counting the wraps by the host's clock. An adapter that
refuses ``Z1`` (BEL) sends frames without a timestamp: they are read as before. With
``adapter_timestamps=False`` the bus sends ``Z0`` (an adapter keeps the setting across power
cycles).

``SlcanLineError`` is a ``ValueError``, as python-can's own parser raises for bad hex, so the CAN
reader counts it as a ``decode`` bad frame and reads on. A failing port (``SerialException``,
``OSError``) is still python-can's ``CanOperationError``: the link is lost.
"""

from __future__ import annotations

import binascii
import re
from collections import deque
from typing import Any

import can
from can.exceptions import CanOperationError
from can.interfaces.slcan import slcanBus

from benchctl.clock import REAL, Clock

OK = b"\r"
BEL = b"\a"
#: longest line an adapter sends: T + 8 id + DLC + 16 data + 4 timestamp + CR is 31 bytes
MAX_LINE = 64
#: answers of the adapter that are neither frames nor errors (transmit acks, OK)
ANSWERS = frozenset({b"", b"z", b"Z"})
#: ``field.translate(None, X)`` deletes the bytes of X: nothing left is a field of hex digits
#: only (``_HEX_DIGITS``), a line of printable ASCII but space only (``_PRINTABLE``)
_HEX_DIGITS = b"0123456789ABCDEFabcdef"
_PRINTABLE = bytes(range(0x21, 0x7F))
_LINE_END = re.compile(rb"[\r\a]")


class SlcanLineError(ValueError):
    """A line from the adapter that is not a frame nor one of its answers (counted ``decode``)."""

    def __init__(self, why: str, line: bytes) -> None:
        self.line = line
        super().__init__(f"slcan: {why}: {line[:MAX_LINE]!r}")


def _hex(field: bytes, line: bytes) -> int:
    if not field or field.translate(None, _HEX_DIGITS):
        raise SlcanLineError("not hex", line)
    return int(field, 16)


_message_init = can.Message.__init__


class SlcanMessage(can.Message):
    """A received frame with the adapter's timestamp (ms, as sent: wrapping), or None."""

    __slots__ = ("adapter_ms",)

    def __init__(self, *args: Any, adapter_ms: int | None = None, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.adapter_ms = adapter_ms

    @classmethod
    def received(cls, arbitration_id: int, is_extended_id: bool, is_remote_frame: bool, dlc: int,
                 data: bytes, timestamp: float, adapter_ms: int | None) -> SlcanMessage:
        """The same message as ``cls(arbitration_id=…, …, adapter_ms=…)``, built without the
        generic constructor's argument passing (``parse_line``: once per received frame)."""
        msg = cls.__new__(cls)
        _message_init(msg, timestamp=timestamp, arbitration_id=arbitration_id,
                      is_extended_id=is_extended_id, is_remote_frame=is_remote_frame, dlc=dlc,
                      data=data)
        msg.adapter_ms = adapter_ms
        return msg


#: LAWICEL timestamps wrap at 60 000 ms (0…EA5F); a value beyond shows a 16-bit counter
WRAP_MS = 60_000
WRAP_16BIT_MS = 65_536


class AdapterClock:
    """The adapter's wrapping millisecond timestamps as continuous seconds.

    ``unwrap(ms, t_host)``: the number of wraps since the previous frame is the one that
    brings the adapter's elapsed time nearest to the host's (``t_host``: the receipt time), so
    gaps and host stalls shorter than half a wrap (30 s) are counted right. The wrap is
    60 000 ms until a timestamp of 60 000 or more shows a 16-bit counter (65 536).
    """

    def __init__(self) -> None:
        self.wrap_ms = WRAP_MS
        self._last_ms: int | None = None
        self._last_host = 0.0
        self._total_ms = 0

    def unwrap(self, ms: int, t_host: float) -> float:
        if ms >= self.wrap_ms:
            self.wrap_ms = WRAP_16BIT_MS
        if self._last_ms is None:
            self._total_ms = ms
        else:
            dv = ms - self._last_ms
            dh = (t_host - self._last_host) * 1000.0
            wraps = round((dh - dv) / self.wrap_ms)
            self._total_ms += dv + wraps * self.wrap_ms
        self._last_ms = ms
        self._last_host = t_host
        return self._total_ms / 1000.0


def parse_line(line: bytes, clock: Clock = REAL) -> can.Message | None:
    """One adapter line (its CR or BEL stripped) as a frame; None for an adapter answer.

    The frame is a ``SlcanMessage``: ``adapter_ms`` is the line's ``Z1`` timestamp, or None;
    ``timestamp`` (python-can's receipt time, UTC seconds) is ``clock.time()``.

    Raises ``SlcanLineError`` for any other line (see the module docstring).
    """
    if line in ANSWERS:
        return None
    if line.translate(None, _PRINTABLE):  # a byte left that is not 0x21…0x7E
        raise SlcanLineError("a byte that is not printable ASCII", line)
    kind = line[:1]
    if kind not in (b"t", b"T", b"r", b"R"):
        raise SlcanLineError("not a frame", line)
    ext = kind in (b"T", b"R")
    remote = kind in (b"r", b"R")
    n_id = 8 if ext else 3
    if len(line) < 2 + n_id:
        raise SlcanLineError("too short", line)
    cid = _hex(line[1:1 + n_id], line)
    if cid > (0x1FFFFFFF if ext else 0x7FF):
        raise SlcanLineError("id out of range", line)
    dlc_char = line[1 + n_id]
    if not 0x30 <= dlc_char <= 0x38:  # "0" … "8": classic CAN
        raise SlcanLineError("DLC not 0-8", line)
    dlc = dlc_char - 0x30
    rest = line[2 + n_id:]
    n_data = 0 if remote else 2 * dlc
    if len(rest) not in (n_data, n_data + 4):  # + a Z1 timestamp
        raise SlcanLineError("length does not match the DLC", line)
    if rest:
        _hex(rest, line)
    data = b"" if remote else binascii.unhexlify(rest[:n_data])  # hex digits only: checked
    stamp = int(rest[n_data:], 16) if len(rest) > n_data else None
    return SlcanMessage.received(cid, ext, remote, dlc, data, clock.time(), stamp)


#: a receive with less than this left has timed out (far below any frame's time on the bus)
_RECV_RESOLUTION_S = 1e-9


class SlcanBus(slcanBus):
    """python-can's slcan bus whose every received line is a frame, an answer or an error.

    Same parameters as ``can.interfaces.slcan.slcanBus``, and ``adapter_timestamps``: ask the
    adapter for its ``Z1`` timestamps (default True) or switch them off (``Z0``), and ``clock``
    for the frames' receipt stamps (the serial port's own waits stay on the real time).
    """

    def __init__(
        self,
        channel: Any,
        *,
        adapter_timestamps: bool = True,
        clock: Clock = REAL,
        **kwargs: Any,
    ) -> None:
        self._clock = clock
        self._rx = bytearray()
        self._lines: deque[tuple[bytes, bytes]] = deque()  # (line, its CR or BEL)
        self.adapter_timestamps = adapter_timestamps
        self._channel_open = False
        self._closed = False  # python-can closes before it sets a bitrate, not otherwise
        super().__init__(channel, **kwargs)

    def open(self) -> None:
        """Set the timestamps while the channel is closed (closing it first if nothing has),
        then open it (python-can opens twice: the second ``O`` is accepted while open)."""
        if not self._channel_open:
            if not self._closed:
                self.close()
            self._write("Z1" if self.adapter_timestamps else "Z0")
        super().open()
        self._channel_open = True

    def close(self) -> None:
        super().close()
        self._channel_open = False
        self._closed = True

    def _next_line(self) -> tuple[bytes, bytes] | None:
        lines = self._lines
        if not lines:
            rx = self._rx
            if BEL in rx:
                start = 0
                for m in _LINE_END.finditer(rx):
                    lines.append((bytes(rx[start:m.start()]), m.group()))
                    start = m.end()
                del rx[:start]
            elif OK in rx:  # CR only (every frame line, every OK): split at each
                *whole, rest = bytes(rx).split(OK)
                for line in whole:
                    lines.append((line, OK))
                del rx[:len(rx) - len(rest)]
        if lines:
            return lines.popleft()
        if len(self._rx) > MAX_LINE:
            garbage = bytes(self._rx)
            self._rx.clear()
            raise SlcanLineError(f"no CR in {len(garbage)} bytes", garbage)
        return None

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """python-can's ``BusABC.recv`` on this bus's clock: a frame that passes the filters,
        or None once ``timeout`` has passed. (The library's own counts the time left on the
        host's wall clock: on simulated time a silent bus then waited for as long as the host
        took to reach that much real time — a few tenths of simulated seconds, another amount
        each run.)"""
        clock = self._clock
        deadline = None if timeout is None else clock.monotonic() + timeout
        time_left = timeout
        while True:
            msg, already_filtered = self._recv_internal(timeout=time_left)
            if msg is not None and (already_filtered or self._matches_filters(msg)):
                return msg
            if deadline is not None:
                # against one deadline: a time left computed as timeout − elapsed can stay a
                # rounding error above 0 on a clock that does not move while nothing arrives
                time_left = deadline - clock.monotonic()
                if time_left <= _RECV_RESOLUTION_S:
                    return None

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        clock = self._clock
        deadline = None if timeout is None else clock.monotonic() + timeout
        port = self.serialPortOrig
        while True:
            got = self._next_line()
            if got is not None:
                line, end = got
                if end == BEL:
                    if line:
                        raise SlcanLineError("ends in BEL", line + end)
                    continue  # the adapter refused a command of ours: not a frame
                msg = parse_line(line, self._clock)
                if msg is not None:
                    return msg, False
                continue
            try:  # python-can's error_check, without a context manager per read
                read_within = getattr(port, "read_within", None)
                if read_within is not None:  # a port that can wait for the first byte itself
                    left = None if deadline is None else max(0.0, deadline - clock.monotonic())
                    chunk = read_within(left)
                else:
                    chunk = port.read(max(1, port.in_waiting))
            except Exception as error:
                raise CanOperationError("Could not read from serial device") from error
            if chunk:
                self._rx += chunk
            elif deadline is not None and clock.monotonic() >= deadline:
                return None, False

    def flush(self) -> None:
        self._rx.clear()
        self._lines.clear()
        super().flush()
