"""Small in-test fakes of the ``Stand`` and ``AngleSensor`` protocols for the run layer tests.

They exercise the state machine, the loop and the one cleanup path; the end-to-end tests use the
real simulators over the real protocols. The fake stand follows its setpoint at once (or plays
its table), so the reference is exact; faults are injected at a motion time.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from benchctl.clock import REAL, Clock, ThreadLike
from benchctl.config import BenchConfig, parse_config
from benchctl.devices.base import (
    DeviceIdentity,
    FrameStats,
    InstrumentSample,
    StandLimitsView,
    StandSample,
    StandStatus,
)
from benchctl.errors import ConnectionLost, DeviceTimeout
from benchctl.harmonics import HarmonicTable
from benchctl.run import prechecks as pc
from benchctl.run.display import NullDisplay
from benchctl.run.plan import make_plan
from benchctl.run.prepare import PreparedMotion

#: a fake stand's round trip on simulated time (on the host's clock the call takes its own time)
SIM_RTT_S = 0.0005


class FakeStand:
    """Follows each setpoint at once. ``fault_at``/``estop_at``/``drop_at``/``raise_at``: motion
    time (s) at which a fault appears; ``lag_deg``: a constant offset (a stand off its track).
    ``clock``: the run's (a ``VirtualClock`` for a test on simulated time)."""

    def __init__(
        self, axes: tuple[str, ...] = ("roll",), angle_limit: float = 20.0, *, clock: Clock = REAL
    ) -> None:
        self.axes = axes
        self.clock = clock
        self.limits = StandLimitsView(angle_limit, 50.0, 300.0)
        self._lock = clock.lock()
        self.angle = dict.fromkeys(axes, 0.0)
        self.setpoint = dict.fromkeys(axes, 0.0)
        self.enabled = False
        self.fault = False
        self.estop_on = False
        self.t_motion: float | None = None
        self.table: dict[str, HarmonicTable] | None = None
        self.table_t0: float | None = None
        self.calls: list[str] = []
        self.fault_at: float | None = None
        self.estop_at: float | None = None
        self.drop_at: float | None = None
        self.raise_at: float | None = None
        self.stall_at: float | None = None
        self.stall_s = 0.0
        self.offset_deg = 0.0
        self.motion_gain = 1.0  # a stand that scales its motion (and reports that as its setpoint)
        self.on_motion_time: Callable[[float], None] | None = None
        self.ramped = False
        self.closed = False
        self.heartbeats = 0
        self.sent: list[tuple[float, dict[str, float]]] = []
        self._history: list[tuple[float, dict[str, float]]] = []  # (time, angle) of each change
        self.on_sample: Callable[[StandSample], None] | None = None
        self.on_setpoint: Callable[[float, dict[str, float], float | None], None] | None = None

    # fault schedule, by motion time
    def _tick(self) -> None:
        if self.t_motion is None:
            return
        tm = self.clock.monotonic() - self.t_motion
        if self.on_motion_time is not None:
            self.on_motion_time(tm)
        if self.drop_at is not None and tm >= self.drop_at:
            raise ConnectionLost("fake stand: connection reset by peer")
        if self.raise_at is not None and tm >= self.raise_at:
            raise RuntimeError("fake stand: driver bug")
        if self.fault_at is not None and tm >= self.fault_at:
            self.fault = True
        if self.estop_at is not None and tm >= self.estop_at:
            self.estop_on = True
        if self.stall_at is not None and tm >= self.stall_at:
            self.stall_at = None
            self.clock.sleep(self.stall_s)

    def _set_angle(self, angle: dict[str, float]) -> float:
        """The stand is now at ``angle`` (lock held); returns the moment, kept in the history."""
        t = self.clock.monotonic()
        self.angle = angle
        self._history.append((t, dict(angle)))
        if len(self._history) > 400:
            del self._history[:200]
        return t

    def true_angle(self, t: float | None = None) -> dict[str, float]:
        """The stand's angle at host time ``t`` (default now): its table, or the setpoint in
        force at that moment (the history of setpoint changes), plus its offset."""
        with self._lock:
            if self.table is not None and self.table_t0 is not None:
                tt = (self.clock.monotonic() if t is None else t) - self.table_t0
                return {a: self.table[a].at(tt) + self.offset_deg for a in self.axes}
            angle = self.angle
            if t is not None:
                for t_set, a_set in reversed(self._history):
                    if t_set <= t:
                        angle = a_set
                        break
            return {a: v + self.offset_deg for a, v in angle.items()}

    def connect(self) -> DeviceIdentity:
        self.calls.append("connect")
        return DeviceIdentity("fake", "stand", "S1", "1.0", "fake")

    def close(self) -> None:
        self.calls.append("close")
        self.closed = True

    def read_status(self) -> StandStatus:
        return StandStatus(
            ready=not (self.fault or self.estop_on),
            enabled=self.enabled,
            moving=False,
            fault=self.fault,
            estop=self.estop_on,
            limit=False,
            table_running=self.table_t0 is not None,
            fault_code=7 if self.fault else 0,
        )

    def read_sample(self) -> StandSample:
        self._tick()
        t0 = self.clock.monotonic()
        if self.clock.virtual:  # a read takes time (on the host's clock, the call itself does)
            self.clock.sleep(SIM_RTT_S)
        ang = self.true_angle()
        t1 = self.clock.monotonic()
        s = StandSample(
            t_host=0.5 * (t0 + t1),
            rtt_s=t1 - t0,
            angle_deg=ang,
            rate_deg_s=dict.fromkeys(self.axes, 0.0),
            setpoint_deg={a: v - self.offset_deg for a, v in ang.items()},
            status=self.read_status(),
        )
        if self.on_sample is not None:
            self.on_sample(s)
        return s

    def enable(self) -> None:
        self.calls.append("enable")
        self.enabled = True

    def disable(self) -> None:
        self.calls.append("disable")
        self.enabled = False

    def heartbeat(self) -> None:
        self.heartbeats += 1

    def send_setpoint(self, angle_deg: dict[str, float], *, t_slot: float | None = None) -> float:
        if self.t_motion is None:
            self.t_motion = self.clock.monotonic()
        self._tick()
        with self._lock:
            t = self._set_angle({a: self.motion_gain * v for a, v in angle_deg.items()})
            self.setpoint = dict(angle_deg)
        self.sent.append((t, dict(angle_deg)))
        if self.on_setpoint is not None:
            self.on_setpoint(t, dict(angle_deg), t_slot)
        return t

    def send_setpoint_and_read(
        self, angle_deg: dict[str, float], *, t_slot: float | None = None
    ) -> tuple[float, StandSample]:
        return self.send_setpoint(angle_deg, t_slot=t_slot), self.read_sample()

    def upload_table(self, tables: dict[str, HarmonicTable]) -> None:
        self.calls.append("upload_table")
        self._pending = tables

    def start_table(self) -> float:
        self.calls.append("start_table")
        t = self.clock.monotonic()
        with self._lock:
            self.table, self.table_t0 = self._pending, t
        self.t_motion = t
        return t

    def stop_table(self) -> None:
        self.calls.append("stop_table")
        with self._lock:
            if self.table is not None and self.table_t0 is not None:
                t = self.clock.monotonic() - self.table_t0
                self._set_angle({a: self.table[a].at(t) for a in self.axes})
            self.table, self.table_t0 = None, None

    def go_to_zero(self, timeout_s: float = 30.0) -> None:
        self.calls.append("go_to_zero")
        with self._lock:
            self._set_angle(dict.fromkeys(self.axes, 0.0))

    def ramp_to_zero(self, timeout_s: float = 30.0) -> None:
        self.calls.append("ramp_to_zero")
        if self.drop_at is not None and self.t_motion is not None:
            raise ConnectionLost("fake stand: no link")
        with self._lock:
            self._set_angle(dict.fromkeys(self.axes, 0.0))
            self.offset_deg = 0.0
        self.ramped = True

    def stop(self) -> None:
        self.calls.append("stop")

    def estop(self) -> None:
        self.calls.append("estop")

    def reset_fault(self) -> None:
        self.fault = False


class FakeSensor:
    """Streams the fake stand's angle ×gain + bias at ``rate_hz`` from a reader thread.

    ``silent_after`` (s of motion): stop sending; ``error_after``: the reader dies and reports it.
    """

    def __init__(
        self, stand: FakeStand, rate_hz: float = 100.0, gain: float = 1.0, bias: float = 0.0
    ) -> None:
        self.stand = stand
        self.clock = stand.clock
        self.axes = stand.axes
        self.stats = FrameStats()
        self.rate_hz = rate_hz
        self.gain = gain
        self.bias = bias
        self.noise = 0.0
        self.silent_after: float | None = None
        self.error_after: float | None = None
        self._stop = self.clock.event()
        self._thread: ThreadLike | None = None
        self.stopped = False
        self.closed = False

    def connect(self) -> DeviceIdentity:
        return DeviceIdentity("fake", "inclinometer", "I1", "2.0", "fake")

    def start(
        self,
        on_sample: Callable[[InstrumentSample], None],
        on_error: Callable[[BaseException], None],
    ) -> None:
        rng = np.random.default_rng(3)

        def run() -> None:
            n = 0
            period = 1.0 / self.rate_hz
            t0 = self.clock.monotonic()
            while not self._stop.wait(max(0.0, t0 + n * period - self.clock.monotonic())):
                t_mo = self.stand.t_motion
                tm = None if t_mo is None else self.clock.monotonic() - t_mo
                if tm is not None and self.error_after is not None and tm >= self.error_after:
                    on_error(DeviceTimeout("fake instrument: bus error"))
                    return
                if not (
                    tm is not None and self.silent_after is not None and tm >= self.silent_after
                ):
                    # a real instrument samples on its own clock: the instant n·period, the
                    # angle in force then, received now (a busy host only makes it late)
                    t = t0 + n * period
                    x = self.stand.true_angle(t)
                    y = {
                        a: self.gain * v + self.bias + self.noise * rng.standard_normal()
                        for a, v in x.items()
                    }
                    on_sample(InstrumentSample(self.clock.monotonic(), y, counter=n))
                n += 1

        # a device's thread (``sim-…``): a host stall on simulated time does not stop it
        self._thread = self.clock.thread(run, name="sim-fake-instrument")
        self._thread.start()

    def stop(self) -> None:
        self.stopped = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    def close(self) -> None:
        self.stop()
        self.closed = True


def bench_config(tmp: Path, **run: Any) -> BenchConfig:
    data = {
        "station": "test-bench",
        "stand": {
            "driver": "modbus-tcp",
            "limits": {"angle_deg": 20.0, "rate_deg_s": 50.0, "accel_deg_s2": 300.0},
            "setpoint_rate_hz": 100.0,
            "sample_rate_hz": 100.0,
            "tracking_tolerance_deg": 0.5,
        },
        "instrument": {
            "driver": "nmea0183",
            "serial_port": "/dev/null",
            "axes": ["roll", "pitch"],
            "silence_timeout_s": 0.5,
            "static_tolerance_deg": 0.2,
        },
        # the fake stand follows each setpoint at once and the fake instrument reads it at
        # once: after a rejoin nothing settles (the analysis leaves out the hold and the path).
        # The mounting check is off unless a test turns it on: the fakes time their faults
        # from the first setpoint sent (the tilt's, with the check on), and these tests count
        # the recording's setpoints as the profile's (test_mounting.py tests it on the fakes).
        # No report figures (matplotlib: 1-3 s of each run, drawn after the verdict from
        # report.json's data): nothing on the fakes looks at them; the report's own tests
        # (tests/unit/report/) and the end-to-end runs (test_run_e2e.py) draw them, and a test
        # that wants them here passes figures=True
        "run": {"limit_sigma_deg": 0.4, "output_dir": str(tmp), "precheck_window_s": 0.5,
                "analysis": {"departure_settle_s": 0.0},
                "mounting_check": {"enabled": False}, "figures": False, **run},
    }
    return parse_config(data, tmp / "bench.yaml")


def sine_motion(
    axes: tuple[str, ...] = ("roll",),
    duration_s: float = 4.0,
    mode: str = "stream",
    fade_s: float = 1.0,
) -> PreparedMotion:
    """A 5° sine per axis (roll 0.5 Hz, pitch 1 Hz) with raised-cosine fades."""
    tables = {
        a: HarmonicTable(
            np.array([0.5 * (1 + i)]),
            np.array([5.0]),
            np.array([0.3 * i]),
            duration_s,
            fade_s,
            fade_s,
        )
        for i, a in enumerate(axes)
    }

    def evaluate(t: np.ndarray) -> dict[str, np.ndarray]:
        return {a: tb.evaluate(t) for a, tb in tables.items()}

    plan = make_plan(evaluate, axes, duration_s, 100.0, fade_s, fade_s, mode=mode, tables=tables)
    check = pc.CheckResult("profile within limits", True, "fake sine", {})
    meta = {
        "profile_name": "fake-sine",
        "seed": 1,
        "duration_s": duration_s,
        "fade_in_s": fade_s,
        "fade_out_s": fade_s,
        "profile": {"kind": "fake"},
    }
    return PreparedMotion(None, None, plan, check, meta)


def wait_for(cond: Callable[[], bool], timeout_s: float = 10.0, clock: Clock = REAL) -> bool:
    """Whether ``cond()`` became true within ``timeout_s`` on ``clock``."""
    end = clock.monotonic() + timeout_s
    while clock.monotonic() < end:
        if cond():
            return True
        clock.sleep(0.01)
    return cond()


def sigma_sine_gain(amp: float, gain: float) -> float:
    """σ of (g−1)·A·sin over whole periods: |g−1|·A/√2."""
    return abs(gain - 1.0) * amp / math.sqrt(2.0)


class Lines(NullDisplay):
    """A run's display that keeps every message the operator would read, in order (the
    states, figures and verdict it is shown go nowhere)."""

    def __init__(self) -> None:
        self.messages: list[str] = []

    def message(self, text: str) -> None:
        self.messages.append(text)
