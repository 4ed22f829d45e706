"""The recorder: every stream of the run into the recording, on the host's monotonic clock.

It listens where the data is born, so nothing the stand sees or is told escapes the recording:

- the stand driver's ``on_sample`` listener → every feedback block the driver decodes (the
  loop's samples, the sample that carried a fault or E-stop bit before the driver raised it,
  the cleanup ramp's reads and the final state);
- the stand driver's ``on_setpoint`` listener → every setpoint sent (the profile, a rejoin,
  the cleanup ramp);
- the instrument reader's callbacks → every decoded instrument sample, and its faults straight
  to the supervisor;
- ``points`` → the buffered trajectory's points as they are queued.

A recording that cannot be written (a full disk, an I/O error) is the run's fault once, and the
run ends through the one cleanup path; the stand driver is never disturbed by it.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Mapping

from benchctl.clock import Clock
from benchctl.devices.base import InstrumentSample, Stand, StandSample
from benchctl.errors import BenchError
from benchctl.recording import RecordingWriter
from benchctl.run.live import Histogram, LiveView, RunningSigma
from benchctl.run.supervisor import Supervisor

log = logging.getLogger(__name__)


class Recorder:
    """Wires the streams into the recording and keeps the counters the run reports."""

    def __init__(
        self,
        writer: RecordingWriter,
        supervisor: Supervisor,
        axes: tuple[str, ...],
        *,
        clock: Clock | None = None,
    ) -> None:
        self.writer = writer
        self.supervisor = supervisor
        #: the run's clock (default: the supervisor's)
        self.clock = clock if clock is not None else supervisor.clock
        self.live = LiveView()
        self.sigma = RunningSigma(axes, clock=self.clock)
        self.rtt = Histogram()
        self.n_instrument = 0
        self.n_stand = 0
        self.instrument_lost = 0
        self.t_last_instrument: float | None = None
        self.t_last_instrument_ref: float | None = None  # when the reader started
        self.t_last_stand: float | None = None
        self.last_stand: StandSample | None = None
        self._last_counter: int | None = None
        self._window: deque[InstrumentSample] = deque(maxlen=100_000)
        self._collect = False
        self._write_failed = False
        # listeners of the stand's samples beside the recording (the running excitation
        # estimate): each must be cheap and must not raise (it runs in the stand's thread)
        self.stand_taps: list[Callable[[StandSample], None]] = []

    def attach(self, stand: Stand) -> None:
        """Listen to the stand driver: every sample it decodes, every setpoint it sends."""
        stand.on_sample = self.on_stand
        stand.on_setpoint = self.on_setpoint

    def _guard(self, what: str, fn: object, *args: object) -> None:
        """Write one row; a recording that cannot be written is the run's fault (once)."""
        if self._write_failed:
            return
        try:
            fn(*args)  # type: ignore[operator]
        except (OSError, BenchError) as e:
            self._write_failed = True
            self.supervisor.fault(e, f"recording ({what})")

    # instrument side (called from the driver's reader thread)
    def on_sample(self, s: InstrumentSample) -> None:
        self._guard("instrument", self.writer.write_instrument, s)
        self.n_instrument += 1
        self.t_last_instrument = s.t_host
        if s.counter is not None:
            if self._last_counter is not None:
                gap = s.counter - self._last_counter - 1
                if gap > 0:
                    self.instrument_lost += gap
            self._last_counter = s.counter
        self.live.instrument = s
        self.sigma.add_instrument(s)
        if self._collect:
            self._window.append(s)

    def on_error(self, e: BaseException) -> None:
        self.supervisor.fault(e, "instrument reader")

    # stand side (called by the stand driver, from whichever thread talks to it)
    def on_stand(self, s: StandSample) -> None:
        self._guard("stand", self.writer.write_stand, s)
        self.n_stand += 1
        self.rtt.add(s.rtt_s)
        self.live.stand = s
        self.last_stand = s
        self.t_last_stand = s.t_host
        self.sigma.add_stand(s.t_host, s.angle_deg)
        for tap in self.stand_taps:
            tap(s)

    def on_setpoint(
        self, t_send: float, angle_deg: Mapping[str, float], t_slot: float | None
    ) -> None:
        self._guard("setpoints", self.writer.write_setpoint, t_send, angle_deg, t_slot)

    def points(
        self, t_send: float, rows: list[tuple[float, Mapping[str, float]]]
    ) -> None:
        """Trajectory points queued at ``t_send``: (planned host time of play, angles) each."""
        for t_play, angle in rows:
            self._guard("setpoints", self.writer.write_setpoint, t_send, angle, t_play)

    def event(self, kind: str, **fields: object) -> None:
        self._guard("events", lambda: self.writer.event(kind, **fields))

    def collect(self, on: bool) -> list[InstrumentSample]:
        """Start (on=True) or stop collecting instrument samples for a precheck; returns them."""
        if on:
            self._window.clear()
            self._collect = True
            return []
        self._collect = False
        out = list(self._window)
        self._window.clear()
        return out
