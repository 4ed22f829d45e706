"""The CAN half of the instrument drivers: a ``SensorReader`` over a handed-in ``can.Bus``.

A protocol fills in ``_identify()`` and ``_handle(msg, t_host)`` (see ``benchctl.devices.reader``).

What ``bus.recv`` gives or raises:

- a data frame → ``_handle`` (a sample or a counted bad frame);
- a remote frame → ``id``, an error frame → ``decode`` (counted, never data);
- a garbled adapter line → ``decode``, and reading goes on: ``SlcanLineError`` from our
  ``SlcanBus``, ``ValueError``/``IndexError`` from python-can's slcan parser, or python-can's
  ``CanOperationError`` caused by a ``UnicodeDecodeError`` (a byte that is not UTF-8: python-can
  keeps that line in its buffer, so it is dropped here, else every later line would fail too);
- any other exception (serial port gone, interface down) → the link is lost (``ConnectionLost``).

A frame with an adapter timestamp (``SlcanBus``: ``Z1``) gives its sample ``adapter_time_s``:
the adapter's millisecond clock unwrapped into seconds by an ``AdapterClock`` (every frame
counts the wraps, service frames too).

Every received frame, good or bad, goes to the raw log (``can.Logger``: ``.blf``, ``.asc`` …)
when a path is given; ``can.LogReader`` reads it back.
"""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

import can

from benchctl.clock import REAL, Clock
from benchctl.config import InstrumentConfig
from benchctl.devices.base import InstrumentSample
from benchctl.devices.can.bus import shutdown_bus
from benchctl.devices.can.slcan import AdapterClock
from benchctl.devices.reader import (
    BAD_DECODE,
    BAD_ID,
    BAD_LENGTH,
    BAD_RANGE,
    BAD_STATUS,
    DECODE_ERRORS,
    BadFrame,
    LinkLost,
    SensorReader,
)
from benchctl.errors import DeviceError

__all__ = ["BAD_DECODE", "BAD_ID", "BAD_LENGTH", "BAD_RANGE", "BAD_STATUS", "DECODE_ERRORS",
           "BadFrame", "CanInstrument", "is_line_noise"]

log = logging.getLogger(__name__)

_RECV_TIMEOUT_S = 0.05


def is_line_noise(exc: BaseException) -> bool:
    """True if ``exc`` from ``bus.recv`` is a garbled line, not a failing link.

    python-can's slcan wraps a line it cannot decode as UTF-8 in ``CanOperationError`` (its
    ``__cause__``), the same type it raises for a port that is gone.
    """
    if isinstance(exc, (ValueError, IndexError)):  # SlcanLineError, python-can's hex parsing
        return True
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, UnicodeError):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _drop_stale_line(bus: can.BusABC) -> None:
    """python-can's slcan leaves an undecodable line in its buffer: drop it (else every later
    line fails to decode with it)."""
    buf = getattr(bus, "_buffer", None)
    if isinstance(buf, bytearray):
        buf.clear()


class CanInstrument(SensorReader):
    """Base of the CAN instrument drivers.

    Parameters
    ----------
    bus : can.BusABC
        The open bus (see ``benchctl.devices.can.bus.open_can_bus``).
    cfg : InstrumentConfig
        Axes, timeouts, node id / source address, EDS / DBC.
    can_log_path : Path, optional
        Write every received frame there (format from the suffix: ``.blf``, ``.asc`` …).
    owns_bus : bool
        Shut the bus down in ``close``.
    clock : Clock
        Receipt times and the reader thread (``benchctl.clock``; the real one by default).
    """

    protocol = "CAN"

    def __init__(
        self,
        bus: can.BusABC,
        cfg: InstrumentConfig,
        *,
        can_log_path: Path | None = None,
        owns_bus: bool = True,
        clock: Clock = REAL,
    ) -> None:
        super().__init__(cfg, f"{cfg.interface}:{cfg.channel}", clock=clock)
        self._bus = bus
        self._owns_bus = owns_bus
        self._adapter_clock = AdapterClock()
        self._adapter_s: float | None = None  # the adapter time of the frame being handled
        self._can_logger: Any = None
        if can_log_path is not None:
            try:
                self._can_logger = can.Logger(str(can_log_path))
            except (OSError, ValueError) as e:
                raise DeviceError(f"{can_log_path}: cannot write the raw CAN log: {e}") from e

    def _poll(self) -> list[tuple[Any, float]]:
        try:
            msg = self._bus.recv(timeout=_RECV_TIMEOUT_S)
        except Exception as e:
            if not is_line_noise(e):  # serial port gone, interface down
                raise LinkLost(str(e)) from e
            _drop_stale_line(self._bus)
            self.stats.count_bad(BAD_DECODE)
            if self.cfg.wire_trace:
                log.debug("rx garbled line: %s", e)
            return []
        if msg is None:
            return []
        t_host = self.clock.monotonic()
        ms = getattr(msg, "adapter_ms", None)
        self._adapter_s = None if ms is None else self._adapter_clock.unwrap(ms, t_host)
        self._log_frame(msg)
        if msg.is_error_frame:
            self.stats.count_bad(BAD_DECODE)
            return []
        if msg.is_remote_frame:
            self.stats.count_bad(BAD_ID)
            return []
        return [(msg, t_host)]

    def _emit(self, sample: InstrumentSample) -> None:
        if self._adapter_s is not None and sample.adapter_time_s is None:
            sample = dataclasses.replace(sample, adapter_time_s=self._adapter_s)
        super()._emit(sample)

    def _log_frame(self, msg: can.Message) -> None:
        if self._can_logger is not None:
            try:
                self._can_logger.on_message_received(msg)
            except Exception as e:
                self._can_logger = None
                self._report(DeviceError(f"raw CAN log: cannot write: {e}"))
        if self.cfg.wire_trace:
            log.debug("rx %s", msg)

    def _close_transport(self) -> None:
        self._close_protocol()
        if self._can_logger is not None:
            try:
                self._can_logger.stop()
            except Exception as e:  # a full disk must not keep the bus open
                log.error("raw CAN log: cannot close: %s", e)
            self._can_logger = None
        if self._owns_bus:
            try:
                shutdown_bus(self._bus)
            except Exception as e:  # the link may already be gone (dropped pty)
                log.debug("CAN bus shutdown on %s: %s", self._where, e)

    def _close_protocol(self) -> None:
        """Release protocol state (override if needed)."""
