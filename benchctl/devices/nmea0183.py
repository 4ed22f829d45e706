"""NMEA 0183 attitude over a serial port: ``$PASHR``, ``$PHTRO`` and ``$--XDR`` roll/pitch.

Sign convention of the samples (and of the simulator): roll positive starboard down (port up),
pitch positive bow up, degrees.

- ``$PASHR,hhmmss.sss,heading,T,roll,pitch,heave,roll_acc,pitch_acc,heading_acc,gnss_q,imu``
  split by pynmea2; its UTC time of day (``hhmmss`` with any decimals, empty: none; a leap
  second ``235960.000`` is 86400 s) becomes ``device_time_s`` (s since midnight). Another
  Ashtech sentence (``$PASHR,POS,…``, ``HPR``, ``VEL``…) is ``id``.
- ``$PHTRO,pitch,M|P,roll,B|T`` parsed here (pynmea2 has no class for it): M bow up → +pitch,
  P bow down → −pitch; T port up → +roll, B port down → −roll.
- ``$--XDR,A,value,D,PTCH,A,value,D,ROLL`` (any talker, any order of quadruplets) parsed by
  pynmea2; transducers of type A in degrees named PTCH/PITCH and ROLL.

Every line becomes a sample or a counted bad frame, whatever its bytes. A line is counted bad
and skipped when its checksum is missing or wrong (``checksum``), it is longer than 82
characters or has too few fields (``length``), it is another sentence than the config asks for
(``id``), a needed field is empty, beyond ±180° roll / ±90° pitch or a time of day beyond
23:59:60 (``range``), or it cannot be parsed (``decode``: not printable ASCII, not starting
with ``$``, a number or time that is not one, anything pynmea2 raises on it).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from typing import Any

import pynmea2
import serial

from benchctl.clock import REAL, Clock
from benchctl.config import InstrumentConfig
from benchctl.devices.base import DeviceIdentity, InstrumentSample
from benchctl.devices.reader import (
    BAD_CHECKSUM,
    BAD_DECODE,
    BAD_ID,
    BAD_LENGTH,
    BAD_RANGE,
    DECODE_ERRORS,
    BadFrame,
    LinkLost,
    SensorReader,
)
from benchctl.errors import DeviceError

log = logging.getLogger(__name__)

#: IEC 61162-1: at most 82 characters including "$" and CR LF
MAX_SENTENCE_CHARS = 82
LIMIT_DEG = {"roll": 180.0, "pitch": 90.0}
SENTENCES = ("PASHR", "PHTRO", "XDR")
#: fields a sentence needs (its name included): PASHR up to pitch, PHTRO all, XDR one quadruplet
MIN_FIELDS = {"PASHR": 6, "PHTRO": 5, "XDR": 5}
#: a decimal number as NMEA 0183 writes it (no exponent, no inf/nan, no spaces or underscores)
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)", re.ASCII)
_TIME = re.compile(r"(\d\d)(\d\d)(\d\d(?:\.\d*)?)", re.ASCII)


@dataclass(frozen=True)
class Attitude:
    """One decoded sentence: angles by axis (deg), the device's time of day if it has one."""

    sentence: str
    talker: str
    angle_deg: dict[str, float]
    device_time_s: float | None = None


def checksum(body: str) -> int:
    """XOR of the characters between ``$`` and ``*`` (``body`` excludes both)."""
    c = 0
    for ch in body.encode("ascii", errors="replace"):
        c ^= ch
    return c


def with_checksum(body: str) -> str:
    """``$body*HH`` without line end, e.g. ``with_checksum("PHTRO,1.00,M,2.00,T")``."""
    return f"${body}*{checksum(body):02X}"


def _sentence_id(body: str) -> tuple[str, str]:
    """(talker, sentence) of a body: ``PASHR``/``PHTRO`` are proprietary, else 2 + 3 letters."""
    head = body.split(",", 1)[0]
    if head.startswith("P"):
        return "P", head
    return head[:2], head[2:]


def _angle(text: str, axis: str) -> float:
    if not text:
        raise BadFrame(BAD_RANGE)  # field empty: not available
    if _NUMBER.fullmatch(text) is None:
        raise BadFrame(BAD_DECODE)
    v = float(text)
    if not abs(v) <= LIMIT_DEG[axis]:
        raise BadFrame(BAD_RANGE)
    return v


def time_of_day(text: str) -> float:
    """``hhmmss[.sss]`` UTC as seconds since midnight (23:59:60.x, a leap second, ≥ 86400).

    ``BadFrame``: ``decode`` if it is not of that form, ``range`` if a part is out of range.
    """
    m = _TIME.fullmatch(text)
    if m is None:
        raise BadFrame(BAD_DECODE)
    h, mi, sec = int(m[1]), int(m[2]), float(m[3])
    if h > 23 or mi > 59 or sec >= 61.0:
        raise BadFrame(BAD_RANGE)
    return h * 3600 + mi * 60 + sec


def parse_line(line: str, *, sentence: str | None = None) -> Attitude:
    """Decode one NMEA 0183 line (without CR LF) into an ``Attitude``.

    ``sentence`` restricts to one of ``PASHR``, ``PHTRO``, ``XDR`` (None: any of them). Raises
    ``BadFrame(reason)`` for a line to count and skip (reasons in the module docstring), and
    nothing else, whatever the line.
    """
    if len(line) + 2 > MAX_SENTENCE_CHARS:
        raise BadFrame(BAD_LENGTH)
    if not line.startswith("$") or not (line.isascii() and line.isprintable()):
        raise BadFrame(BAD_DECODE)  # IEC 61162-1: printable ASCII only
    star = line.rfind("*")
    if star < 0 or len(line) != star + 3:
        raise BadFrame(BAD_CHECKSUM)
    body = line[1:star]
    try:
        given = int(line[star + 1:], 16)
    except ValueError:
        raise BadFrame(BAD_CHECKSUM) from None
    if given != checksum(body):
        raise BadFrame(BAD_CHECKSUM)
    talker, kind = _sentence_id(body)
    if kind not in SENTENCES or (sentence is not None and kind != sentence):
        raise BadFrame(BAD_ID)
    if len(body.split(",")) < MIN_FIELDS[kind]:
        raise BadFrame(BAD_LENGTH)
    if kind == "PHTRO":
        return _parse_phtro(body)
    try:
        msg: Any = pynmea2.parse(line)
        data = [str(x) for x in msg.data]
    except (pynmea2.ParseError, *DECODE_ERRORS):  # pynmea2 raises many things on odd lines
        raise BadFrame(BAD_DECODE) from None
    return _parse_pashr(data) if kind == "PASHR" else _parse_xdr(data, talker)


def _parse_phtro(body: str) -> Attitude:
    f = body.split(",")
    pitch = _angle(f[1], "pitch")
    roll = _angle(f[3], "roll")
    if f[2] not in ("M", "P") or f[4] not in ("B", "T"):
        raise BadFrame(BAD_DECODE)
    return Attitude("PHTRO", "P", {
        "pitch": pitch if f[2] == "M" else -pitch,
        "roll": roll if f[4] == "T" else -roll,
    })


def _parse_pashr(data: list[str]) -> Attitude:
    # pynmea2's Ashtech data: ["R", time, heading, "T", roll, pitch, …]; its own time parsing
    # (ASHRATT.timestamp) returns the text for a time it cannot read and rejects a leap second
    if len(data) < 6:
        raise BadFrame(BAD_LENGTH)
    if data[1][:1].isalpha():  # $PASHR,POS / HPR / VEL …: another Ashtech sentence
        raise BadFrame(BAD_ID)
    t = time_of_day(data[1]) if data[1] else None
    roll = _angle(data[4], "roll")
    pitch = _angle(data[5], "pitch")
    return Attitude("PASHR", "P", {"roll": roll, "pitch": pitch}, t)


def _parse_xdr(data: list[str], talker: str) -> Attitude:
    # quadruplets (type, value, units, name), as pynmea2's XDR.get_transducer reads them
    if len(data) % 4 != 0 or not data:
        raise BadFrame(BAD_LENGTH)
    angles: dict[str, float] = {}
    for i in range(0, len(data), 4):
        kind, value, units, name = data[i:i + 4]
        axis = {"PTCH": "pitch", "PITCH": "pitch", "ROLL": "roll"}.get(name.upper())
        if axis is None or kind != "A":
            continue
        if units != "D":
            raise BadFrame(BAD_DECODE)
        angles[axis] = _angle(value, axis)
    return Attitude("XDR", talker, angles)


class Nmea0183Instrument(SensorReader):
    """An NMEA 0183 attitude talker on a serial port; implements ``AngleSensor``.

    Parameters
    ----------
    port : serial.Serial
        An open pyserial port (or anything with ``read``, ``in_waiting``, ``close``) with a
        short read timeout (see ``open_serial``).
    cfg : InstrumentConfig
        ``sentence`` (None accepts any of the three), axes, timeouts.
    owns_port : bool
        Close the port in ``close``.
    """

    protocol = "NMEA 0183"

    def __init__(
        self, port: Any, cfg: InstrumentConfig, *, owns_port: bool = True, clock: Clock = REAL
    ) -> None:
        super().__init__(cfg, str(cfg.serial_port), clock=clock)
        self._port = port
        self._owns_port = owns_port
        self._buf = bytearray()
        self._last: Attitude | None = None

    def _identify(self) -> DeviceIdentity:
        self._wait_first_frame()
        a = self._last
        assert a is not None
        return DeviceIdentity(
            vendor="unknown (NMEA 0183 talker)",
            model=f"{a.talker}{a.sentence} talker" if a.sentence == "XDR" else f"${a.sentence}",
            protocol=self.protocol,
            extra={"sentence": a.sentence, "talker": a.talker, "port": str(self.cfg.serial_port)},
        )

    def _poll(self) -> list[tuple[Any, float]]:
        try:
            chunk = self._port.read(max(1, self._port.in_waiting))
        except (serial.SerialException, OSError, TypeError, AttributeError) as e:
            raise LinkLost(str(e)) from e
        if not chunk:
            return []
        t_host = self.clock.monotonic()
        self._buf.extend(chunk)
        lines: list[tuple[Any, float]] = []
        while True:
            nl = self._buf.find(b"\n")
            if nl < 0:
                break
            raw = bytes(self._buf[:nl]).rstrip(b"\r")
            del self._buf[:nl + 1]
            if raw:
                lines.append((raw, t_host))
        if len(self._buf) > 4 * MAX_SENTENCE_CHARS:  # garbage without a line end
            self._buf.clear()
            self.stats.count_bad(BAD_LENGTH)
        return lines

    def _handle(self, item: Any, t_host: float) -> None:
        if self.cfg.wire_trace:
            log.debug("rx %r", item)
        try:
            line = item.decode("ascii")
        except UnicodeDecodeError:
            raise BadFrame(BAD_DECODE) from None
        a = parse_line(line.strip(), sentence=self.cfg.sentence)
        missing = [ax for ax in self.outputs if ax not in a.angle_deg]
        if missing:
            raise BadFrame(BAD_RANGE)
        self._last = a
        self._emit(InstrumentSample(
            t_host=t_host,
            angle_deg={ax: a.angle_deg[ax] for ax in self.outputs},
            device_time_s=a.device_time_s,
        ))

    def _close_transport(self) -> None:
        if self._owns_port:
            try:
                self._port.close()
            except Exception as e:  # the pty may be gone already
                log.debug("closing %s: %s", self._where, e)


def open_serial(cfg: InstrumentConfig) -> Any:
    """Open ``cfg.serial_port`` (a device path or a pyserial URL) for the reader."""
    try:
        return serial.serial_for_url(cfg.serial_port, baudrate=cfg.baudrate, timeout=0.05)
    except (serial.SerialException, OSError, ValueError) as e:
        raise DeviceError(f"instrument serial_port {cfg.serial_port!r}: cannot open: {e}") from e
