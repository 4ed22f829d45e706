"""Broadcast angle messages described by a DBC file (J1939, NMEA 2000), decoded by cantools.

The DBC is loaded with ``frame_id_mask=0x03FFFF00`` so a message matches at any priority and
from any source address (a 29-bit J1939/NMEA 2000 id is priority(3) | PGN(18) | source(8)). A
protocol module supplies a ``DbcAngleSpec``: which message, which signals are which axis, how
to tell an unavailable value, and where a counter or a latency lives.

Every frame is a sample or a counted bad frame: an 11-bit frame, a 29-bit id beyond 1FFFFFFF,
another PGN or source address is ``id``; another length than the message's is ``length``; a
status signal saying error / not available is ``status``; an angle at a "not available" /
"error" code or beyond its valid range is ``range``; anything cantools raises is ``decode``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import cantools

from benchctl.clock import REAL, Clock
from benchctl.config import InstrumentConfig
from benchctl.devices.base import DeviceIdentity, InstrumentSample
from benchctl.devices.can.reader import (
    BAD_DECODE,
    BAD_ID,
    BAD_LENGTH,
    BAD_RANGE,
    BAD_STATUS,
    DECODE_ERRORS,
    BadFrame,
    CanInstrument,
)
from benchctl.errors import ConfigError
from benchctl.textfile import MAX_YAML_BYTES, check_input_file

#: priority and source address are masked off when matching a frame to a DBC message
FRAME_ID_MASK = 0x03FFFF00
MAX_EXTENDED_ID = 0x1FFFFFFF


@dataclass(frozen=True)
class DbcAngleSpec:
    """How one protocol's angle message is read out of its DBC."""

    protocol: str
    message: str  # message name in the DBC
    angle_signals: Mapping[str, str]  # axis -> signal name
    to_deg: float  # scaled signal value x to_deg = degrees
    raw_valid: Callable[[int], bool]  # False for "not available" / "error" / out-of-range codes
    counter_signal: str | None = None
    counter_not_available: int | None = None
    latency_signal_ms: str | None = None
    status_signals: Mapping[str, str] = field(default_factory=dict)  # axis -> status signal
    status_bad: frozenset[int] = frozenset()


def load_dbc(path: Path, message: str) -> tuple[Any, Any]:
    """Load ``path`` with the J1939 frame-id mask and return (database, message ``message``)."""
    check_input_file(path, "DBC file", ConfigError, MAX_YAML_BYTES)  # cantools reads it
    try:
        db: Any = cantools.database.load_file(str(path), frame_id_mask=FRAME_ID_MASK)
    except (OSError, cantools.database.UnsupportedDatabaseFormatError) as e:
        raise ConfigError(f"{path}: cannot load DBC file: {e}") from e
    try:
        msg = db.get_message_by_name(message)
    except KeyError:
        raise ConfigError(f"{path}: DBC has no message {message!r}") from None
    return db, msg


class DbcAngleInstrument(CanInstrument):
    """A broadcast angle sensor whose frames a DBC describes (see ``DbcAngleSpec``)."""

    spec: DbcAngleSpec

    def __init__(
        self,
        bus: can.BusABC,
        cfg: InstrumentConfig,
        *,
        can_log_path: Path | None = None,
        owns_bus: bool = True,
        clock: Clock = REAL,
    ) -> None:
        if cfg.dbc is None:
            raise ConfigError(f"instrument driver {cfg.driver}: needs dbc (a DBC file in drivers/)")
        self._db, self._msg = load_dbc(cfg.dbc, self.spec.message)
        self._pgn_id = self._msg.frame_id & FRAME_ID_MASK
        self._signals = {s.name: s for s in self._msg.signals}
        for axis in cfg.outputs:
            name = self.spec.angle_signals[axis]
            if name not in self._signals:
                raise ConfigError(f"{cfg.dbc}: message {self.spec.message} lacks signal {name!r}")
        self.protocol = self.spec.protocol
        self.source_address: int | None = None
        super().__init__(bus, cfg, can_log_path=can_log_path, owns_bus=owns_bus, clock=clock)

    def decode(self, frame_id: int, data: bytes, t_host: float,
               adapter_time_s: float | None = None) -> InstrumentSample:
        """Decode one frame to a sample (its ``adapter_time_s``: the frame's adapter time, if
        known); ``BadFrame(reason)`` if it must be counted and skipped."""
        if not 0 <= frame_id <= MAX_EXTENDED_ID or frame_id & FRAME_ID_MASK != self._pgn_id:
            raise BadFrame(BAD_ID)
        sa = frame_id & 0xFF
        if self.cfg.source_address is not None and sa != self.cfg.source_address:
            raise BadFrame(BAD_ID)
        if len(data) != self._msg.length:
            raise BadFrame(BAD_LENGTH)
        try:
            return self._decode(sa, data, t_host, adapter_time_s)
        except DECODE_ERRORS:
            raise BadFrame(BAD_DECODE) from None

    def _decode(self, sa: int, data: bytes, t_host: float,
                adapter_time_s: float | None) -> InstrumentSample:
        raw = self._msg.decode(data, decode_choices=False, scaling=False)
        spec = self.spec
        angles: dict[str, float] = {}
        for axis in self.outputs:
            status = spec.status_signals.get(axis)
            if status is not None and int(raw[status]) in spec.status_bad:
                raise BadFrame(BAD_STATUS)
            name = spec.angle_signals[axis]
            r = int(raw[name])
            if not spec.raw_valid(r):
                raise BadFrame(BAD_RANGE)
            sig = self._signals[name]
            angles[axis] = (r * sig.scale + sig.offset) * spec.to_deg
        counter = None
        if spec.counter_signal is not None:
            c = int(raw[spec.counter_signal])
            counter = None if c == spec.counter_not_available else c
        device_time = None
        if spec.latency_signal_ms is not None:
            sig = self._signals[spec.latency_signal_ms]
            latency_s = (int(raw[spec.latency_signal_ms]) * sig.scale + sig.offset) / 1000.0
            device_time = t_host - latency_s
        self.source_address = sa
        return InstrumentSample(t_host=t_host, angle_deg=angles, device_time_s=device_time,
                                counter=counter, adapter_time_s=adapter_time_s)

    def _handle(self, msg: can.Message, t_host: float) -> None:
        if not msg.is_extended_id:
            raise BadFrame(BAD_ID)
        self._emit(self.decode(msg.arbitration_id, bytes(msg.data), t_host, self._adapter_s))

    def _identify(self) -> DeviceIdentity:
        self._wait_first_frame()
        sa = self.source_address
        return DeviceIdentity(
            vendor="unknown (broadcast protocol)",
            model=f"{self.spec.protocol} {self.spec.message} sender",
            serial=f"SA 0x{sa:02X}" if sa is not None else "",
            protocol=self.spec.protocol,
            extra={"source_address": str(sa), "pgn": f"0x{self._pgn_id >> 8:05X}",
                   "dbc": str(self.cfg.dbc)},
        )
