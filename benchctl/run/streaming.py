"""The stand loop and the recorder wiring: both streams on the host's monotonic clock.

One thread (``StandLoop``) owns the stand's cycle from connect to shutdown:

- **hold** — before and after the motion: read the stand at ``sample_rate_hz``, record it,
  keep the heartbeat;
- **stream** mode — setpoints at ``setpoint_rate_hz`` on ABSOLUTE deadlines
  ``t_start + k·period`` (``time.monotonic``). After a stall the loop skips to the current slot
  (no burst of catch-up setpoints, the stand holds or interpolates) and counts the missed
  cycles; a setpoint goes out within ``SEND_WINDOW`` of a period after its slot or its slot is
  missed, so setpoints are always a whole number of periods apart. Each cycle sends the
  slot's setpoint, reads the stand sample (recorded as the reference), checks it and keeps the
  heartbeat;
- **table** mode — the harmonic table is uploaded and started; the loop polls the stand's angle
  at ``sample_rate_hz`` and compares it to the profile evaluated from the start time.

Checks on every stand sample: fault / E-stop and angle limit (at once); tracking error
(measured vs the stand's own setpoint) and profile departure (measured vs the profile), each
over its tolerance for ``DEBOUNCE`` consecutive samples and ``BREACH_HOLD_S`` seconds; and a
silent instrument (no sample for ``silence_timeout_s``). A breach raises inside the loop
thread; the supervisor turns it into the run's fault at once.

The instrument's background reader calls ``Recorder.on_sample`` (straight into the recording)
and ``Recorder.on_error`` (straight to the supervisor).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from benchctl.devices.base import AngleSensor, InstrumentSample, Stand, StandSample
from benchctl.errors import SafetyAbort, StandFault
from benchctl.harmonics import HarmonicTable
from benchctl.recording import RecordingWriter
from benchctl.run.state import RunState, StateMachine
from benchctl.run.supervisor import Supervisor

log = logging.getLogger(__name__)

SEND_WINDOW = 0.25  # a setpoint goes out within this fraction of a period after its slot, or not
DEBOUNCE = 3  # consecutive stand samples over a tolerance before the run aborts …
# … held for this long: after a host stall the stand's setpoint jumps and its servo needs
# ~1/bandwidth to catch up; a stand that really does not follow stays over for longer
BREACH_HOLD_S = 0.25
SETTLE_TIMEOUT_S = 10.0  # after the profile: wait this long at most for the stand to come to rest
REST_RATE_DEG_S = 0.5  # "at rest": |rate| below this on every axis


class Histogram:
    """Fixed-bin histogram of non-negative durations (s): p50/p99 in O(1) memory.

    Bins of ``resolution_s`` up to ``max_s``; larger values land in the last bin and ``max``
    keeps the true largest value.
    """

    def __init__(self, resolution_s: float = 1e-5, max_s: float = 0.5) -> None:
        self.resolution_s = resolution_s
        self.counts = np.zeros(int(max_s / resolution_s) + 1, dtype=np.int64)
        self.n = 0
        self.max = 0.0
        self.total = 0.0

    def add(self, x: float) -> None:
        x = max(0.0, x)
        i = min(int(x / self.resolution_s), self.counts.size - 1)
        self.counts[i] += 1
        self.n += 1
        self.total += x
        if x > self.max:
            self.max = x

    def quantile(self, q: float) -> float:
        if self.n == 0:
            return math.nan
        c = np.cumsum(self.counts)
        i = int(np.searchsorted(c, q * self.n, side="left"))
        return min((i + 0.5) * self.resolution_s, self.max)

    def summary(self) -> dict[str, float]:
        return {
            "n": self.n,
            "p50": self.quantile(0.5),
            "p99": self.quantile(0.99),
            "max": self.max if self.n else math.nan,
            "mean": self.total / self.n if self.n else math.nan,
        }


class RunningSigma:
    """Running σ of ε = y − x per axis (Welford), x linearly interpolated at the instrument's t.

    Only a live display estimate: the verdict comes from the full analysis. Instrument samples
    wait until a stand sample later than them has arrived; memory is bounded.
    """

    def __init__(self, axes: tuple[str, ...]) -> None:
        self.axes = axes
        self._lock = threading.Lock()
        self._stand: deque[tuple[float, dict[str, float]]] = deque(maxlen=512)
        self._pending: deque[InstrumentSample] = deque(maxlen=4096)
        self.active = False
        self.n = dict.fromkeys(axes, 0)
        self._mean = dict.fromkeys(axes, 0.0)
        self._m2 = dict.fromkeys(axes, 0.0)

    def add_stand(self, t: float, angle: Mapping[str, float]) -> None:
        with self._lock:
            self._stand.append((t, dict(angle)))
            self._drain()

    def add_instrument(self, s: InstrumentSample) -> None:
        if not self.active:
            return
        with self._lock:
            self._pending.append(s)

    def _drain(self) -> None:
        if len(self._stand) < 2:
            return
        t_last = self._stand[-1][0]
        t_first = self._stand[0][0]
        while self._pending and self._pending[0].t_host <= t_last:
            s = self._pending.popleft()
            if s.t_host < t_first:
                continue
            x = self._interp(s.t_host)
            for a in self.axes:
                if a in s.angle_deg and a in x:
                    self._push(a, s.angle_deg[a] - x[a])

    def _interp(self, t: float) -> dict[str, float]:
        hist = self._stand
        for i in range(len(hist) - 1, 0, -1):
            t0, x0 = hist[i - 1]
            t1, x1 = hist[i]
            if t0 <= t <= t1:
                w = (t - t0) / (t1 - t0) if t1 > t0 else 0.0
                return {a: x0[a] + w * (x1[a] - x0[a]) for a in x0 if a in x1}
        return {}

    def _push(self, a: str, e: float) -> None:
        self.n[a] += 1
        d = e - self._mean[a]
        self._mean[a] += d / self.n[a]
        self._m2[a] += d * (e - self._mean[a])

    def sigma(self) -> dict[str, float]:
        with self._lock:
            return {
                a: math.sqrt(self._m2[a] / (self.n[a] - 1)) if self.n[a] > 1 else math.nan
                for a in self.axes
            }


@dataclass
class LiveView:
    """What the display shows; written by the loop and the reader, read by the main thread."""

    stand: StandSample | None = None
    instrument: InstrumentSample | None = None
    tracking_error_deg: dict[str, float] = field(default_factory=dict)
    departure_deg: dict[str, float] = field(default_factory=dict)
    t_motion_start: float | None = None


class Recorder:
    """Wires the streams into the recording and keeps the counters the run reports."""

    def __init__(
        self, writer: RecordingWriter, supervisor: Supervisor, axes: tuple[str, ...]
    ) -> None:
        self.writer = writer
        self.supervisor = supervisor
        self.live = LiveView()
        self.sigma = RunningSigma(axes)
        self.rtt = Histogram()
        self.n_instrument = 0
        self.instrument_lost = 0
        self.t_last_instrument: float | None = None
        self.t_last_instrument_ref: float | None = None  # when the reader started
        self._last_counter: int | None = None
        self._window: deque[InstrumentSample] = deque(maxlen=100_000)
        self._collect = False

    # instrument side (called from the driver's reader thread)
    def on_sample(self, s: InstrumentSample) -> None:
        self.writer.write_instrument(s)
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

    # stand side (called from the stand loop)
    def on_stand(self, s: StandSample) -> None:
        self.writer.write_stand(s)
        self.rtt.add(s.rtt_s)
        self.live.stand = s
        self.sigma.add_stand(s.t_host, s.angle_deg)

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


class SerializedStand:
    """The stand with every call serialised by one lock: the loop and the main thread share it."""

    def __init__(self, stand: Stand) -> None:
        self._stand = stand
        self._lock = threading.RLock()
        self.axes = stand.axes
        self.limits = stand.limits

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._stand, name)
        if not callable(attr):
            return attr

        def call(*args: Any, **kwargs: Any) -> Any:
            with self._lock:
                return attr(*args, **kwargs)

        return call

    def as_stand(self) -> Stand:
        return cast(Stand, self)


@dataclass
class MotionPlan:
    """The profile on the loop's grid: ``values[axis][k]`` is the angle at ``k·period_s``."""

    axes: tuple[str, ...]
    period_s: float
    values: dict[str, NDArray[np.float64]]
    duration_s: float
    fade_in_s: float
    fade_out_s: float
    mode: str = "stream"
    tables: dict[str, HarmonicTable] | None = None

    @property
    def n_slots(self) -> int:
        return int(next(iter(self.values.values())).size)

    def at(self, t: float) -> dict[str, float]:
        """The profile at profile time ``t`` (linear between grid points; 0 outside)."""
        if t <= 0.0 or t >= self.duration_s or self.n_slots < 2:
            return dict.fromkeys(self.axes, 0.0)
        x = t / self.period_s
        i = min(int(x), self.n_slots - 2)
        w = x - i
        return {a: float(v[i] + w * (v[i + 1] - v[i])) for a, v in self.values.items()}

    def state_at(self, t: float) -> RunState:
        if t < self.fade_in_s:
            return RunState.FADE_IN
        if t < self.duration_s - self.fade_out_s:
            return RunState.RUNNING
        return RunState.FADE_OUT


def make_plan(
    evaluate: Callable[[NDArray[np.float64]], Mapping[str, NDArray[np.float64]]],
    axes: tuple[str, ...],
    duration_s: float,
    rate_hz: float,
    fade_in_s: float,
    fade_out_s: float,
    mode: str = "stream",
    tables: dict[str, HarmonicTable] | None = None,
) -> MotionPlan:
    """Evaluate the profile once on the loop's grid ``k / rate_hz`` for k = 0 … duration·rate."""
    period = 1.0 / rate_hz
    n = math.floor(duration_s * rate_hz + 1e-9) + 1
    t = np.arange(n, dtype=np.float64) * period
    vals = evaluate(t)
    values = {a: np.asarray(vals[a], dtype=float) for a in axes}
    return MotionPlan(axes, period, values, duration_s, fade_in_s, fade_out_s, mode, tables)


@dataclass
class LoopLimits:
    angle_deg: float
    tracking_tolerance_deg: float
    profile_tolerance_deg: float
    silence_timeout_s: float
    heartbeat_period_s: float
    sample_rate_hz: float
    zero_tolerance_deg: float


class StandLoop:
    """The thread that owns the stand's cycle (hold → motion → settle → hold)."""

    def __init__(
        self,
        stand: Stand,
        recorder: Recorder,
        supervisor: Supervisor,
        machine: StateMachine,
        plan: MotionPlan,
        limits: LoopLimits,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.stand = stand
        self.rec = recorder
        self.sup = supervisor
        self.machine = machine
        self.plan = plan
        self.lim = limits
        self.clock = clock
        self._stop = threading.Event()
        self._go = threading.Event()
        self.motion_done = threading.Event()
        self.lateness = Histogram()
        self.missed_cycles = 0
        self.cycles = 0
        self.setpoints_sent = 0
        self.t_motion_start: float | None = None
        self.t_motion_end: float | None = None
        self.t_last_cycle: float | None = None
        self._t_heartbeat = -math.inf
        self._over: dict[str, tuple[int, float]] = {}
        self._thread: threading.Thread | None = None

    # control from the main thread
    def start(self) -> None:
        self._thread = self.sup.thread("stand loop", self._run)
        self._thread.start()

    def begin_motion(self) -> None:
        self._go.set()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout_s)
            if t.is_alive():
                log.error("stand loop did not stop within %.1f s", timeout_s)

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _stopping(self) -> bool:
        return self._stop.is_set() or self.sup.stop_event.is_set()

    def _wait_until(self, deadline: float) -> bool:
        """Sleep until ``deadline``; False when the loop must stop."""
        while True:
            now = self.clock()
            if now >= deadline:
                return not self._stopping()
            if self._stop.wait(min(deadline - now, 0.05)) or self.sup.stop_event.is_set():
                return False

    # the thread
    def _run(self) -> None:
        self._hold(until_go=True)
        if self._stopping():
            return
        if self.plan.mode == "table":
            self._table()
        else:
            self._stream()
        if self._stopping():
            return
        self.t_motion_end = self.clock()
        self._settle()
        if self._stopping():
            return
        self.motion_done.set()
        self._hold(until_go=False)

    def _heartbeat(self, now: float) -> None:
        if now - self._t_heartbeat >= self.lim.heartbeat_period_s:
            self.stand.heartbeat()
            self._t_heartbeat = now

    def _check_instrument(self, now: float) -> None:
        t = self.rec.t_last_instrument
        since = self.rec.t_last_instrument_ref if t is None else t
        if since is not None and now - since > self.lim.silence_timeout_s:
            raise SafetyAbort(
                f"instrument silent: no sample for {now - since:.2f} s "
                f"(silence_timeout_s = {self.lim.silence_timeout_s} s)"
            )

    def _sample(self, profile_t: float | None) -> StandSample:
        s = self.stand.read_sample()
        self.rec.on_stand(s)
        self._check_sample(s, profile_t)
        return s

    def _over_tol(self, key: str, over: bool, t: float) -> bool:
        """True once ``over`` has held for ``DEBOUNCE`` samples and ``BREACH_HOLD_S`` seconds."""
        if not over:
            self._over.pop(key, None)
            return False
        n, t0 = self._over.get(key, (0, t))
        self._over[key] = (n + 1, t0)
        return n + 1 >= DEBOUNCE and t - t0 >= BREACH_HOLD_S

    def _check_sample(self, s: StandSample, profile_t: float | None) -> None:
        st = s.status
        if st.estop:
            raise StandFault("stand reports E-stop", st.fault_code)
        if st.fault:
            raise StandFault(f"stand reports fault code {st.fault_code}", st.fault_code)
        for a, v in s.angle_deg.items():
            if abs(v) > self.lim.angle_deg:
                raise SafetyAbort(f"limit breach: {a} angle {v:.3f}° beyond ±{self.lim.angle_deg}°")
        if profile_t is None:
            return
        ref = self.plan.at(profile_t)
        track = {
            a: s.angle_deg[a] - s.setpoint_deg[a] for a in self.plan.axes if a in s.setpoint_deg
        }
        dep = {a: s.angle_deg[a] - ref[a] for a in self.plan.axes}
        self.rec.live.tracking_error_deg = track
        self.rec.live.departure_deg = dep
        for a, e in track.items():
            if self._over_tol("track " + a, abs(e) > self.lim.tracking_tolerance_deg, s.t_host):
                raise SafetyAbort(
                    f"tracking error on {a}: {e:+.3f}° (measured − stand setpoint) beyond "
                    f"±{self.lim.tracking_tolerance_deg}° (stand.tracking_tolerance_deg)"
                )
        for a, e in dep.items():
            if self._over_tol("depart " + a, abs(e) > self.lim.profile_tolerance_deg, s.t_host):
                raise SafetyAbort(
                    f"stand departs from the profile on {a}: {e:+.3f}° at t = {profile_t:.2f} s "
                    f"beyond ±{self.lim.profile_tolerance_deg}° (run.profile_tolerance_deg)"
                )

    def _hold(self, until_go: bool) -> None:
        period = 1.0 / self.lim.sample_rate_hz
        t0 = self.clock()
        k = 0
        while not self._stopping():
            if until_go and self._go.is_set():
                return
            if not self._wait_until(t0 + k * period):
                return
            now = self.clock()
            k = max(k + 1, int((now - t0) / period) + 1)
            self._heartbeat(now)
            self._sample(None)
            self._check_instrument(now)
            self.t_last_cycle = now

    def _advance_state(self, t_profile: float) -> None:
        target = self.plan.state_at(t_profile)
        if self.machine.state is not target:
            self.machine.advance_to(target)
            # the running σ shown live covers the steady part, like the verdict
            self.rec.sigma.active = target is RunState.RUNNING

    def _start_motion(self, t_start: float) -> None:
        self.t_motion_start = t_start
        self.rec.live.t_motion_start = t_start
        self.rec.writer.event("motion_start", t_host=t_start, mode=self.plan.mode)
        self._advance_state(0.0)

    def _stream(self) -> None:
        plan = self.plan
        period = plan.period_s
        t_start = self.clock() + period  # first slot one period ahead
        self._start_motion(t_start)
        k = 0
        while True:
            deadline = t_start + k * period
            if not self._wait_until(deadline):
                return
            now = self.clock()
            late = now - deadline
            if late >= SEND_WINDOW * period:
                # stalled: no burst. A slot whose moment has passed by more than the send window
                # is missed (counted); the loop waits for the next slot. Sending only close to
                # its slot keeps the interval between setpoints a whole number of periods, as
                # the stand plays them.
                skip = int(late / period) + 1
                self.missed_cycles += skip
                k += skip
                continue
            if k >= plan.n_slots:
                break
            self.lateness.add(late)
            # The profile on the uniform slot grid: the stand plays setpoints on its own
            # period, so a late send carries its slot's value and the commanded trajectory
            # does not depend on host jitter.
            sp = {a: float(plan.values[a][k]) for a in plan.axes}
            # one transaction where the stand takes it (Modbus FC23): write, then read back
            t_send, s = self.stand.send_setpoint_and_read(sp)
            self.rec.writer.write_setpoint(t_send, sp, t_slot=deadline)
            self.setpoints_sent += 1
            self._heartbeat(now)
            self.rec.on_stand(s)
            self._check_sample(s, s.t_host - t_start)
            self._check_instrument(now)
            self._advance_state(k * period)
            self.cycles += 1
            self.t_last_cycle = now
            k += 1

    def _table(self) -> None:
        plan = self.plan
        assert plan.tables is not None
        period = 1.0 / self.lim.sample_rate_hz
        t_start = self.stand.start_table()
        self._start_motion(t_start)
        k = 1
        while True:
            deadline = t_start + k * period
            if not self._wait_until(deadline):
                return
            now = self.clock()
            late = now - deadline
            if late >= period:
                skip = int(late / period)
                self.missed_cycles += skip
                k += skip
                late = now - (t_start + k * period)
            self.lateness.add(late)
            self._heartbeat(now)
            s = self.stand.read_sample()
            self.rec.on_stand(s)
            t_prof = s.t_host - t_start
            self._check_sample(s, t_prof if t_prof <= plan.duration_s else None)
            self._check_instrument(now)
            self._advance_state(min(t_prof, plan.duration_s))
            self.cycles += 1
            self.t_last_cycle = now
            if t_prof > plan.duration_s:
                break
            k += 1
        self.stand.stop_table()

    def _settle(self) -> None:
        """After the profile: keep recording until the stand is at rest near zero."""
        period = 1.0 / self.lim.sample_rate_hz
        t0 = self.clock()
        k = 1
        while self.clock() - t0 < SETTLE_TIMEOUT_S:
            if not self._wait_until(t0 + k * period):
                return
            now = self.clock()
            k = max(k + 1, int((now - t0) / period) + 1)
            self._heartbeat(now)
            s = self._sample(None)
            self._check_instrument(now)
            if all(abs(v) <= self.lim.zero_tolerance_deg for v in s.angle_deg.values()) and all(
                abs(v) <= REST_RATE_DEG_S for v in s.rate_deg_s.values()
            ):
                return
        raise SafetyAbort(
            f"stand not at rest {SETTLE_TIMEOUT_S:.0f} s after the profile ended "
            f"(zero_tolerance_deg = {self.lim.zero_tolerance_deg}°)"
        )

    def stats(self) -> dict[str, Any]:
        lat = self.lateness.summary()
        return {
            "cycles": self.cycles,
            "setpoints_sent": self.setpoints_sent,
            "missed_cycles": self.missed_cycles,
            "cycle_lateness_s": lat,
            "stand_rtt_s": self.rec.rtt.summary(),
            "instrument_samples": self.rec.n_instrument,
            "instrument_lost": self.rec.instrument_lost,
            "motion_start": self.t_motion_start,
            "motion_end": self.t_motion_end,
        }


def start_instrument(sensor: AngleSensor, recorder: Recorder) -> None:
    """Start the instrument's reader wired straight into the recording and the supervisor."""
    recorder.t_last_instrument_ref = time.monotonic()
    sensor.start(recorder.on_sample, recorder.on_error)
