"""A slcan (LAWICEL ASCII) CAN adapter: the protocol state machine, no I/O.

Host → adapter commands, each ending in CR; the adapter answers CR for OK and BEL for an error:

====================  =========================================================================
``Sn`` (n = 0…8)      bitrate 10k, 20k, 50k, 100k, 125k, 250k, 500k, 800k (750k), 1M; only
                      while closed
``sXXYY``             BTR registers (bitrate then unknown: frames pass); only while closed
``O`` / ``L``         open normal / listen-only (``O`` while open is accepted: python-can
                      sends it twice on open)
``C``                 close
``V`` / ``N``         version ``V1013`` / serial number ``NSIM1``
``F``                 status flags ``F00``
``Z0`` / ``Z1``       timestamps off / on (4 hex digits of ms, 0…EA5F, appended to frames);
                      only while closed
``M``/``m``/``X``/``W`` acceptance code/mask, auto-poll, filter mode: accepted, no effect
``tIIIL…`` ``TIIIIIIIIL…`` ``r…`` ``R…``  transmit (open, not listen-only) → ``z``/``Z`` + CR
empty line            CR
====================  =========================================================================

Adapter → host: received bus frames as ``tIIILDD…`` / ``TIIIIIIIILDD…`` lines (upper-case hex)
while open, and only if the host's bitrate equals the bus bitrate (else the adapter sees only
error frames: nothing). With ``Z1`` each line ends in the adapter's own millisecond clock
(``clock``, counted from the adapter's start, ``drift_ppm`` off the host's rate, wrapping at
60 000 ms) read when the frame was complete on the bus — as a real adapter stamps a frame when
it takes it off the bus, whatever happens to it on its way to the host: ``line_for(msg,
t_bus=…)`` with the frame's bus time on the host clock, or now.
"""

from __future__ import annotations

import binascii
from collections.abc import Callable

import can

from benchctl.clock import REAL

OK = b"\r"
BEL = b"\a"

#: ``Sn`` command digit → bitrate (bit/s)
BITRATES = {0: 10_000, 1: 20_000, 2: 50_000, 3: 100_000, 4: 125_000, 5: 250_000,
            6: 500_000, 7: 750_000, 8: 1_000_000}


def frame_line(msg: can.Message, timestamp_ms: int | None = None) -> bytes:
    """The slcan line for a frame, e.g. ``b"t18A4E80318FC\\r"``."""
    remote = msg.is_remote_frame
    if msg.is_extended_id:
        line = b"%s%08X%d" % (b"R" if remote else b"T", msg.arbitration_id, msg.dlc)
    else:
        line = b"%s%03X%d" % (b"r" if remote else b"t", msg.arbitration_id, msg.dlc)
    if not remote:
        line += binascii.hexlify(msg.data).upper()
    if timestamp_ms is not None:
        line += b"%04X" % (timestamp_ms % 60000)
    return line + OK


def frame_bits(msg: can.Message) -> int:
    """Bits of a classic data frame on the bus, before stuffing (SOF … EOF and intermission)."""
    return (67 if msg.is_extended_id else 47) + (0 if msg.is_remote_frame else 8 * msg.dlc)


def parse_frame(cmd: str) -> can.Message | None:
    """A ``t``/``T``/``r``/``R`` command as a message, or None if it is malformed."""
    kind = cmd[:1]
    ext = kind in ("T", "R")
    n_id = 8 if ext else 3
    try:
        cid = int(cmd[1:1 + n_id], 16)
        dlc = int(cmd[1 + n_id], 10)
    except (ValueError, IndexError):
        return None
    if dlc > 8 or cid > (0x1FFFFFFF if ext else 0x7FF) or len(cmd[1:1 + n_id]) != n_id:
        return None
    remote = kind in ("r", "R")
    data = b""
    if not remote:
        hexdata = cmd[2 + n_id:]
        if len(hexdata) != 2 * dlc:
            return None
        try:
            data = bytes.fromhex(hexdata)
        except ValueError:
            return None
    return can.Message(arbitration_id=cid, is_extended_id=ext, is_remote_frame=remote, dlc=dlc,
                       data=data)


class SlcanAdapter:
    """LAWICEL command interpreter; ``feed`` the host's bytes, it returns the answer bytes.

    Parameters
    ----------
    bus_bitrate : int
        The simulated bus's bitrate (bit/s); the host must select the same to see frames.
    on_transmit : callable
        Called with each frame the host transmits (e.g. SDO requests to a simulated node).
    clock : callable
        The host's clock (the run's: real or simulated) the adapter's own clock runs from (s);
        its timestamps count ms from the adapter's creation, ``drift_ppm`` fast.
    """

    def __init__(
        self,
        bus_bitrate: int,
        on_transmit: Callable[[can.Message], None],
        *,
        clock: Callable[[], float] = REAL.monotonic,
        drift_ppm: float = 0.0,
    ) -> None:
        self.bus_bitrate = bus_bitrate
        self.on_transmit = on_transmit
        self.clock = clock
        self.drift_ppm = drift_ppm
        self._t_boot = clock()
        self.is_open = False
        self.listen_only = False
        self.timestamps = False
        self.host_bitrate: int | None = None  # None: never set (or BTR): assume it matches
        self.commands = 0
        self.errors = 0
        self._buf = bytearray()

    @property
    def forwarding(self) -> bool:
        """True when bus frames reach the host."""
        return self.is_open and (self.host_bitrate is None or self.host_bitrate == self.bus_bitrate)

    def now(self, t_host: float | None = None) -> float:
        """The adapter's own clock (s since it started) now, or at host time ``t_host``."""
        t = self.clock() if t_host is None else t_host
        return (t - self._t_boot) * (1.0 + 1e-6 * self.drift_ppm)

    def line_for(
        self, msg: can.Message, t_s: float | None = None, *, t_bus: float | None = None
    ) -> bytes | None:
        """The line to send the host for a bus frame, or None if not forwarded. Its timestamp
        (with ``Z1``): ``t_s`` (s on the adapter's clock), else the adapter's clock at the
        frame's bus time ``t_bus`` (host clock), else now."""
        if not self.forwarding:
            return None
        if not self.timestamps:
            return frame_line(msg)
        return frame_line(msg, int((self.now(t_bus) if t_s is None else t_s) * 1000))

    def feed(self, data: bytes) -> bytes:
        """Interpret complete CR-terminated commands in ``data``; return the answers."""
        self._buf.extend(data)
        out = bytearray()
        while True:
            i = self._buf.find(b"\r")
            if i < 0:
                break
            raw = bytes(self._buf[:i])
            del self._buf[:i + 1]
            out += self.command(raw.decode("ascii", errors="replace").strip("\n"))
        if len(self._buf) > 64:  # no CR in sight: garbage
            self._buf.clear()
            self.errors += 1
        return bytes(out)

    def command(self, cmd: str) -> bytes:
        """Answer one command (without its CR)."""
        self.commands += 1
        answer = self._command(cmd)
        if answer == BEL:
            self.errors += 1
        return answer

    def _command(self, cmd: str) -> bytes:
        if cmd == "":
            return OK
        c = cmd[0]
        if c == "S":
            if self.is_open or len(cmd) != 2 or not cmd[1].isdigit() or int(cmd[1]) not in BITRATES:
                return BEL
            self.host_bitrate = BITRATES[int(cmd[1])]
            return OK
        if c == "s":
            if self.is_open or len(cmd) != 5:
                return BEL
            self.host_bitrate = None
            return OK
        if cmd in ("O", "L"):
            self.is_open = True
            self.listen_only = cmd == "L"
            return OK
        if cmd == "C":
            self.is_open = False
            return OK
        if cmd == "V":
            return b"V1013\r"
        if cmd == "N":
            return b"NSIM1\r"
        if cmd == "F":
            return b"F00\r" if self.is_open else BEL
        if cmd in ("Z0", "Z1"):
            if self.is_open:
                return BEL
            self.timestamps = cmd == "Z1"
            return OK
        if c in "MmXW":
            return OK
        if c in "tTrR":
            if not self.is_open or self.listen_only:
                return BEL
            msg = parse_frame(cmd)
            if msg is None:
                return BEL
            if self.forwarding:
                self.on_transmit(msg)
            return b"Z\r" if msg.is_extended_id else b"z\r"
        return BEL
