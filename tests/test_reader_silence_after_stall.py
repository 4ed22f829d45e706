"""A host stall is not the instrument's silence: frames that waited in the port while the host
was stopped prove the instrument was talking, whatever time they are stamped with.

A reader judged silence from the last sample's own stamp — for a CAN adapter with timestamps,
the adapter's time of the frame, so after a host stall longer than ``silence_timeout_s`` the
backlog it read back carried old stamps, and the run aborted "instrument silent" with the
instrument's frames in its hands (the loaded ``run_under_load`` benchmark: a 4.7 s stall).
Silence is now judged from when the reader got its last good sample."""

from __future__ import annotations

import queue
from pathlib import Path
from typing import Any

from run_fakes import bench_config

from benchctl.clock.virtual import VirtualClock
from benchctl.devices.base import DeviceIdentity, InstrumentSample
from benchctl.devices.reader import SensorReader

PERIOD_S = 0.01


class StampedSensor(SensorReader):
    """Each frame carries the device's own time of sending (as adapter timestamps do)."""

    def __init__(self, cfg: Any, clock: VirtualClock) -> None:
        super().__init__(cfg, "queue", clock=clock)
        self.wire = clock.queue()

    def _identify(self) -> DeviceIdentity:
        return DeviceIdentity("fake", "inclinometer", "I1", "2.0", "fake")

    def _poll(self) -> list[tuple[Any, float]]:
        try:
            item = self.wire.get(timeout=0.1)
        except queue.Empty:
            return []
        return [(item, self.clock.monotonic())]

    def _handle(self, item: Any, t_host: float) -> None:
        t_device, value = item
        self._emit(InstrumentSample(t_device, {"roll": value}))


def test_a_host_stall_longer_than_the_silence_timeout_is_not_the_instruments_silence(
    tmp_path: Path,
) -> None:
    cfg = bench_config(tmp_path).instrument.model_copy(
        update={"axes": ["roll"], "silence_timeout_s": 2.0}
    )
    clock = VirtualClock(start_s=0.0)
    errors: list[BaseException] = []
    got: list[InstrumentSample] = []
    with clock.running():
        sensor = StampedSensor(cfg, clock)

        def talker() -> None:  # the instrument: a device thread, which the stall leaves be
            for n in range(800):
                clock.sleep(max(0.0, n * PERIOD_S - clock.monotonic()))
                sensor.wire.put((clock.monotonic(), 0.0))

        clock.thread(talker, name="sim-talker").start()
        sensor.start(got.append, errors.append)
        clock.stall_host(2.0, 3.0)  # the host stopped for 3 s, the instrument talking on
        clock.sleep(7.0)
        sensor.stop()
    assert len(got) > 600  # the backlog was read after the stall
    assert errors == []
