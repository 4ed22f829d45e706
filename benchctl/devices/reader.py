"""The shared half of every instrument driver: a background reader that never dies quietly.

A driver fills in ``_identify()`` (called by ``connect``, the reader already running),
``_poll()`` (one bounded wait for input, returning the frames/lines that arrived, each with
its host receipt time on the monotonic clock: ``self.clock.monotonic()``) and
``_handle(item, t_host)``, which decodes one frame and either calls ``_emit`` with a sample or
raises ``BadFrame(reason)``; the reader counts the reason in ``stats`` and goes on.

A bad frame is a counted bad frame, always: every input a driver reads, whatever its bytes,
ends as exactly one of a sample (``stats.good``), a counted bad frame (``stats.bad[reason]``,
reasons ``BAD_REASONS``) or, for CANopen, a well-formed service frame (SDO answer, EMCY,
heartbeat: ``service_frames``). A driver turns what its parsing libraries raise on malformed
input (``DECODE_ERRORS``) into ``BadFrame(BAD_DECODE)``; line noise on a transport (a byte that
is not ASCII, a line the adapter never sends) is ``decode`` too, never a lost link.

Faults go to ``on_error`` at once:

- the link fails (serial port gone, CAN interface down) → ``ConnectionLost``; the reader ends;
- no valid sample for ``silence_timeout_s`` after ``start`` → ``DeviceTimeout`` (once per silence;
  samples that come back are delivered again);
- an unexpected exception while decoding (a bug: no input may cause one) → counted as
  ``decode`` and passed on as it is; the reader goes on;
- an exception raised by ``on_sample`` → passed to ``on_error``; the reader goes on.
"""

from __future__ import annotations

import dataclasses
import logging
import struct
import threading
from typing import Any

from benchctl.clock import REAL, Clock, ThreadLike
from benchctl.config import InstrumentConfig, axis_map
from benchctl.devices.base import (
    DeviceIdentity,
    ErrorCallback,
    FrameStats,
    InstrumentSample,
    SampleCallback,
)
from benchctl.errors import ConnectionLost, DeviceError, DeviceTimeout

log = logging.getLogger(__name__)

#: reasons a frame is counted as bad in ``FrameStats.bad``
BAD_CHECKSUM = "checksum"  # NMEA 0183 checksum missing or wrong
BAD_LENGTH = "length"  # wrong DLC / field count / an over-long line
BAD_RANGE = "range"  # a value outside its valid range, or a "not available"/"error" code
BAD_ID = "id"  # an identifier, source address or sentence the driver does not expect
BAD_DECODE = "decode"  # an adapter line or payload that cannot be parsed
BAD_STATUS = "status"  # the device flags the value as erroneous (e.g. J1939 figure of merit)
BAD_REASONS = (BAD_CHECKSUM, BAD_LENGTH, BAD_RANGE, BAD_ID, BAD_DECODE, BAD_STATUS)

#: host time the reader spends on one received frame (decode, checks, delivery), charged on a
#: simulated clock (``Clock.compute``; on the real clock the work takes its own time): a burst
#: read after a host stall is then stamped frame by frame, as on a real host, and not all at one
#: instant — which a recording reads as one batch read and dates back, erasing the stall
FRAME_HOST_COST_S = 50e-6

#: what the parsing libraries (pynmea2, cantools, canopen, struct, int/float) raise on malformed
#: input; a driver catches exactly these around a library call and counts the frame as ``decode``
DECODE_ERRORS: tuple[type[Exception], ...] = (
    ValueError, LookupError, TypeError, AttributeError, ArithmeticError, struct.error,
)


class BadFrame(Exception):
    """Raised by a driver's ``_handle`` for a frame to count and skip (internal)."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(reason)


class LinkLost(Exception):
    """Raised by ``_poll`` when the transport is gone (internal; becomes ``ConnectionLost``)."""


class SensorReader:
    """Base of the instrument drivers: implements ``AngleSensor`` around three hooks."""

    protocol = "instrument"

    def __init__(self, cfg: InstrumentConfig, where: str, *, clock: Clock = REAL) -> None:
        self.cfg = cfg
        self.clock = clock
        # instrument.axes: the stand axis each reading is for, from which output, with which
        # sign; the driver decodes ``outputs``, ``_emit`` hands on the stand's axes
        self._axis_map = axis_map(cfg.axes)
        self._identity_map = all(o == a and s == 1 for a, (o, s) in self._axis_map.items())
        self.axes: tuple[str, ...] = tuple(self._axis_map)
        self.outputs: tuple[str, ...] = tuple(o for o, _ in self._axis_map.values())
        self.stats = FrameStats()
        self._where = where
        self._lock = clock.lock()
        self._thread: ThreadLike | None = None
        self._ident: int | None = None  # the reader thread's, while it runs
        self._stop_evt = clock.event()
        self._on_sample: SampleCallback | None = None
        self._on_error: ErrorCallback | None = None
        self._fault: BaseException | None = None
        self._first_good = clock.event()
        self._started_t: float | None = None
        self._last_good_t: float | None = None
        self._silence_reported = False
        self._closed = False
        self.identity: DeviceIdentity | None = None
        #: well-formed frames of the protocol that carry no sample (CANopen SDO, EMCY, heartbeat)
        self.service_frames = 0

    # ------------------------------------------------------------------ AngleSensor
    def connect(self) -> DeviceIdentity:
        """Start the reader and identify the device (protocol specific); raise on failure."""
        if self._closed:
            raise DeviceError(f"instrument {self.protocol} on {self._where}: already closed")
        self._start_reader()
        self.identity = self._identify()
        if self._fault is not None:
            raise self._fault
        return self.identity

    def start(self, on_sample: SampleCallback, on_error: ErrorCallback) -> None:
        """Deliver samples to ``on_sample`` and faults to ``on_error`` from the reader thread."""
        if self._closed:
            raise DeviceError(f"instrument {self.protocol} on {self._where}: already closed")
        with self._lock:
            self._on_sample = on_sample
            self._on_error = on_error
            self._started_t = self.clock.monotonic()
            self._last_good_t = None
            self._silence_reported = False
        self._start_reader()
        if self._fault is not None:
            on_error(self._fault)

    def stop(self) -> None:
        """Stop delivering samples and stop the reader thread (idempotent)."""
        with self._lock:
            self._on_sample = None
            self._on_error = None
            self._started_t = None
        self._stop_reader()

    def close(self) -> None:
        """Stop and release the transport if owned (idempotent)."""
        if self._closed:
            return
        self._closed = True
        self.stop()
        self._close_transport()

    def __enter__(self) -> SensorReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ for the drivers
    def _identify(self) -> DeviceIdentity:
        raise NotImplementedError

    def _poll(self) -> list[tuple[Any, float]]:
        raise NotImplementedError

    def _handle(self, item: Any, t_host: float) -> None:
        raise NotImplementedError

    def _close_transport(self) -> None:
        """Release the transport (override)."""

    def _emit(self, sample: InstrumentSample) -> None:
        if not self._identity_map:  # the outputs as the stand's axes (instrument.axes)
            got = sample.angle_deg
            sample = dataclasses.replace(sample, angle_deg={
                a: s * got[o] for a, (o, s) in self._axis_map.items() if o in got})
        self.stats.good += 1
        if not self._first_good.is_set():  # once: a set event stays set
            self._first_good.set()
        with self._lock:
            cb, err = self._on_sample, self._on_error
            # silence is judged from when the reader got it, not from the sample's own stamp
            # (an adapter's time of the frame): a backlog read after a host stall is old by its
            # stamps, yet it proves the instrument was talking
            self._last_good_t = self.clock.monotonic()
            self._silence_reported = False
        if cb is None:
            return
        try:
            cb(sample)
        except Exception as e:
            if err is not None:
                err(e)

    def _wait_first_frame(self) -> None:
        """Block until the first valid sample (identification of broadcast-only protocols)."""
        if not self._first_good.wait(self.cfg.connect_timeout_s):
            if self._fault is not None:
                raise self._fault
            raise DeviceTimeout(
                f"instrument {self.protocol} on {self._where}: no valid frame within "
                f"connect_timeout_s={self.cfg.connect_timeout_s} s "
                f"(frames seen: {self.stats.good} good, bad {self.stats.bad})"
            )

    # ------------------------------------------------------------------ reader thread
    def _start_reader(self) -> None:
        if self._thread is not None and self._thread.is_alive():
            return
        if isinstance(self._fault, ConnectionLost):
            return
        self._stop_evt.clear()
        self._thread = self.clock.thread(
            self._run, name=f"{self.protocol}-reader-{self._where}", daemon=True
        )
        self._thread.start()

    def _stop_reader(self) -> None:
        self._stop_evt.set()
        t = self._thread
        if t is not None and threading.get_ident() != self._ident:
            t.join(timeout=5.0)
        self._thread = None

    def _report(self, exc: BaseException) -> None:
        if isinstance(exc, ConnectionLost):  # the one fault that outlives the reader
            self._fault = exc
        with self._lock:
            err = self._on_error
        log.error("%s", exc)
        if err is not None:
            err(exc)

    def _check_silence(self, now: float) -> None:
        with self._lock:
            if self._started_t is None or self._silence_reported:
                return
            since = self._last_good_t if self._last_good_t is not None else self._started_t
            if now - since <= self.cfg.silence_timeout_s:
                return
            self._silence_reported = True
        self._report(DeviceTimeout(
            f"instrument silent: {self.protocol} on {self._where}: no valid sample for "
            f"{now - since:.2f} s (silence_timeout_s={self.cfg.silence_timeout_s})"
        ))

    def _run(self) -> None:
        self._ident = threading.get_ident()
        while not self._stop_evt.is_set():
            try:
                items = self._poll()
            except LinkLost as e:
                self._report(ConnectionLost(
                    f"instrument {self.protocol} on {self._where}: link lost: {e}"
                ))
                return
            for item, t_host in items:
                try:
                    self._handle(item, t_host)
                except BadFrame as b:
                    self.stats.count_bad(b.reason)
                except Exception as e:  # a bug in a decoder: never silent
                    self.stats.count_bad(BAD_DECODE)
                    self._report(e)
                self.clock.compute(FRAME_HOST_COST_S)
            self._check_silence(self.clock.monotonic())
