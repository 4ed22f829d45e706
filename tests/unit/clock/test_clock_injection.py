"""The injected clock reaches the run's code: a stand loop, the recording, an instrument reader
and the CANopen SDO client run on a ``VirtualClock`` (simulated seconds, stamps on simulated
time), and ruff's banned-API rule refuses a raw ``time.sleep`` in the package."""

from __future__ import annotations

import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import canopen
import pytest
from canopen.sdo.client import SdoClient
from canopen.sdo.exceptions import SdoCommunicationError
from repo_paths import ROOT
from run_fakes import bench_config, sine_motion

from benchctl.clock import Clock
from benchctl.clock.virtual import VirtualClock
from benchctl.devices.base import (
    DeviceIdentity,
    InstrumentSample,
    StandLimitsView,
    StandSample,
    StandStatus,
)
from benchctl.devices.can.canopen_incl import _sdo_on_clock
from benchctl.devices.reader import SensorReader
from benchctl.recording import RecordingWriter, load_recording
from benchctl.run.recorder import Recorder
from benchctl.run.serialized_stand import SerializedStand
from benchctl.run.stand_loop import LoopLimits, StandLoop, start_instrument
from benchctl.run.state import RunState, StateMachine
from benchctl.run.supervisor import Supervisor

AXES = ("roll",)


class ClockStand:
    """A stand that is where it was last told to be, stamped on the clock it is handed."""

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.axes = AXES
        self.limits = StandLimitsView(20.0, 50.0, 300.0)
        self.angle = dict.fromkeys(AXES, 0.0)
        self.heartbeats = 0
        self.on_sample: Any = None
        self.on_setpoint: Any = None

    def connect(self) -> DeviceIdentity:
        return DeviceIdentity("fake", "stand", "S1", "1.0", "fake")

    def close(self) -> None:
        pass

    def read_status(self) -> StandStatus:
        return StandStatus(ready=True, enabled=True, moving=False, fault=False, estop=False,
                           limit=False, table_running=False, fault_code=0)

    def read_sample(self) -> StandSample:
        t = self.clock.monotonic()
        s = StandSample(t_host=t, rtt_s=0.0, angle_deg=dict(self.angle),
                        rate_deg_s=dict.fromkeys(AXES, 0.0), setpoint_deg=dict(self.angle),
                        status=self.read_status())
        if self.on_sample is not None:
            self.on_sample(s)
        return s

    def heartbeat(self) -> None:
        self.heartbeats += 1

    def send_setpoint(self, angle_deg: dict[str, float], *, t_slot: float | None = None) -> float:
        t = self.clock.monotonic()
        self.angle = dict(angle_deg)
        if self.on_setpoint is not None:
            self.on_setpoint(t, dict(angle_deg), t_slot)
        return t

    def send_setpoint_and_read(
        self, angle_deg: dict[str, float], *, t_slot: float | None = None
    ) -> tuple[float, StandSample]:
        return self.send_setpoint(angle_deg, t_slot=t_slot), self.read_sample()

    def enable(self) -> None:
        pass

    def disable(self) -> None:
        pass

    def stop_table(self) -> None:
        pass

    def go_to_zero(self, timeout_s: float = 30.0) -> None:
        self.angle = dict.fromkeys(AXES, 0.0)

    def ramp_to_zero(self, timeout_s: float = 30.0) -> None:
        self.angle = dict.fromkeys(AXES, 0.0)

    def stop(self) -> None:
        pass


class ClockSensor(SensorReader):
    """An instrument reader whose transport is the stand itself, polled every 10 ms on the
    reader's clock (the base class's thread, events and silence check on the same clock); the
    10 ms are the instrument's: the reader's own work per frame does not stretch them."""

    def __init__(self, stand: ClockStand, cfg: Any, clock: Clock) -> None:
        super().__init__(cfg, "fake", clock=clock)
        self.stand = stand
        self._next: float | None = None

    def _identify(self) -> DeviceIdentity:
        return DeviceIdentity("fake", "inclinometer", "I1", "2.0", "fake")

    def _poll(self) -> list[tuple[Any, float]]:
        now = self.clock.monotonic()
        self._next = (now if self._next is None else self._next) + 0.01
        self.clock.sleep(self._next - now)
        return [(dict(self.stand.angle), self.clock.monotonic())]

    def _handle(self, item: Any, t_host: float) -> None:
        self._emit(InstrumentSample(t_host, item))


def test_a_stand_loop_plays_ten_simulated_seconds_on_the_virtual_clock(tmp_path: Path) -> None:
    cfg = bench_config(tmp_path).instrument.model_copy(update={"axes": list(AXES)})
    clock = VirtualClock(start_s=500.0)
    host0 = time.perf_counter()
    with clock.running():
        w = RecordingWriter(tmp_path / "rec", AXES, {}, clock=clock)
        sup = Supervisor(clock=clock)
        rec = Recorder(w, sup, AXES)  # the supervisor's clock
        stand = ClockStand(clock)
        rec.attach(stand)
        sensor = ClockSensor(stand, cfg, clock)
        sm = StateMachine(clock)
        sm.to(RunState.PRECHECKS)
        plan = sine_motion(AXES, duration_s=10.0, fade_s=1.0).plan
        lim = LoopLimits(20.0, 0.5, 1.0, 0.5, 0.1, 100.0, 0.05, rate_deg_s=50.0,
                         accel_deg_s2=1000.0)
        loop = StandLoop(SerializedStand(stand, clock=clock).as_stand(), rec, sup, sm, plan, lim,
                         clock=clock)
        sensor.connect()
        start_instrument(sensor, rec)
        loop.start()
        clock.sleep(0.5)  # the hold: heartbeat and samples before the motion
        loop.begin_motion()
        assert loop.motion_done.wait(60.0)
        t_end = clock.monotonic()
        loop.stop()
        sensor.close()
        w.close("done")
    host = time.perf_counter() - host0
    assert not sup.faulted, sup.first
    assert loop.t_motion_start is not None and loop.t_motion_end is not None
    motion = loop.t_motion_end - loop.t_motion_start
    assert motion >= 10.0  # the whole profile (and the settle after it) on simulated time
    # far faster than the real time it simulates (typically well under a second on the host;
    # the bound leaves room for a loaded CI machine)
    assert host < 0.5 * (t_end - 500.0), f"{host:.2f} s of host time"
    assert loop.missed_cycles == 0  # nothing of the host's speed reaches simulated time
    assert loop.setpoints_sent >= 1000

    r = load_recording(tmp_path / "rec")
    st, ins = r.streams["stand"]["t_host"], r.streams["instrument"]["t_host"]
    assert st.min() >= 500.0 and st.max() <= t_end  # stamped on simulated time
    assert ins.min() > 500.0 and ins.max() <= t_end
    assert ins.size >= 1000
    # the reader's samples: exactly every 10 ms of simulated time (no host jitter)
    gaps = ins[1:] - ins[:-1]
    assert abs(gaps - 0.01).max() < 1e-9
    assert r.meta["start_utc"] == "2026-01-01T00:00:00.000+00:00"  # the clock's epoch
    assert r.meta["start_monotonic"] == 500.0
    # the states too: stamped at their simulated instants
    assert sm.history[0][1] == 500.0


def test_the_canopen_sdo_client_waits_for_its_answers_on_the_clock() -> None:
    clock = VirtualClock(start_s=0.0)
    sdo = SdoClient(0x601, 0x581, canopen.ObjectDictionary())
    sdo.RESPONSE_TIMEOUT = 2.0
    _sdo_on_clock(sdo, clock)
    answer = bytes([0x4B, 0x00, 0x60, 0x00, 0x0A, 0x00, 0x00, 0x00])

    class Net:
        """The node answers each request 50 ms later (simulated), from its own clock thread."""

        def send_message(self, cob_id: int, data: bytes) -> None:
            def reply() -> None:
                clock.sleep(0.05)
                sdo.on_response(0x581, answer, 0.0)

            clock.thread(reply, name="sdo-server").start()

    sdo.network = Net()  # type: ignore[assignment]
    with clock.running():
        sdo.responses.put(b"stale")  # a late answer from before: dropped, queue kept
        t0 = clock.monotonic()
        assert sdo.request_response(bytes(8)) == answer
        assert clock.monotonic() - t0 == pytest.approx(0.05)
        t0 = clock.monotonic()
        with pytest.raises(SdoCommunicationError):
            sdo.read_response()  # nobody answers: the timeout, on simulated time
        assert clock.monotonic() - t0 == pytest.approx(2.0)


def _ruff() -> str | None:
    exe = Path(sys.executable).with_name("ruff")
    return str(exe) if exe.exists() else shutil.which("ruff")


@pytest.mark.skipif(_ruff() is None, reason="ruff not installed")
def test_ruff_refuses_a_raw_wait_or_time_read_outside_the_clock(tmp_path: Path) -> None:
    ruff = _ruff()
    assert ruff is not None
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    body = ("import threading\nimport time\nfrom datetime import UTC, datetime\n\n"
            "time.sleep(0.1)\nt = time.monotonic()\nstamp = datetime.now(UTC)\n"
            "done = threading.Event()\n")
    for where in ("benchctl/run/probe.py", "benchctl/clock/probe.py"):
        (tmp_path / where).parent.mkdir(parents=True)
        (tmp_path / where).write_text(body)

    def check(where: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [ruff, "check", "--no-cache", "--config", str(tmp_path / "pyproject.toml"),
             "--output-format", "concise", where],
            cwd=tmp_path, capture_output=True, text=True, timeout=60,
        )

    out = check("benchctl/run/probe.py")
    assert out.returncode == 1, out.stdout + out.stderr
    for banned in ("time.sleep", "time.monotonic", "datetime.datetime.now", "threading.Event"):
        assert f"TID251 `{banned}` is banned" in out.stdout, out.stdout
    assert "benchctl.clock" in out.stdout
    # the clock's own package is where the raw calls belong
    assert check("benchctl/clock/probe.py").returncode == 0
