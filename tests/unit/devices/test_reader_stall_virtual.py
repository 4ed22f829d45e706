"""An instrument reader on simulated time, its host stalled: the burst it reads after the stall
is stamped frame by frame, as on a real host.

On simulated time decoding a frame cost nothing, so every frame of the burst got one and the
same receipt stamp — which a recording reads as one batch read (``resolve_batches``) and dates
back by the stream's period: the stall vanished from the receipt stamps, and what a stalled
host does to them (late receipts, the timing warning as received) was not what a simulated run
recorded. The reader now charges ``FRAME_HOST_COST_S`` of host time per frame on the clock.
"""

from __future__ import annotations

import queue
from pathlib import Path
from typing import Any

import numpy as np
from run_fakes import bench_config

from benchctl.clock.virtual import VirtualClock
from benchctl.devices.base import DeviceIdentity, InstrumentSample
from benchctl.devices.reader import FRAME_HOST_COST_S, SensorReader
from benchctl.recording.reader import resolve_batches

PERIOD_S = 0.01


class QueueSensor(SensorReader):
    """A reader whose transport is a queue a device fills every 10 ms: one frame a poll, taken
    at once when one is waiting (as python-can's slcan bus gives a buffered frame)."""

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
        self._emit(InstrumentSample(t_host, {"roll": float(item)}))


def test_a_burst_after_a_host_stall_is_stamped_frame_by_frame(tmp_path: Path) -> None:
    cfg = bench_config(tmp_path).instrument.model_copy(update={"axes": ["roll"]})
    clock = VirtualClock(start_s=0.0)
    got: list[InstrumentSample] = []
    with clock.running():
        sensor = QueueSensor(cfg, clock)

        def talker() -> None:  # the instrument: a device thread, which the stall leaves be
            for n in range(100):
                clock.sleep(max(0.0, n * PERIOD_S - clock.monotonic()))
                sensor.wire.put(n)

        clock.stall_host(0.305, 0.2)  # the host stopped for 20 periods
        dev = clock.thread(talker, name="sim-talker")
        dev.start()
        sensor.connect()
        sensor.start(got.append, lambda e: None)
        dev.join()
        clock.sleep(0.1)
        sensor.close()
    t = np.array([s.t_host for s in got])
    assert len(t) == 100
    assert np.all(np.diff(t) > 0)  # no two frames share a receipt stamp
    late = t - np.arange(100) * PERIOD_S
    burst = late > PERIOD_S / 2
    # frames 31 … 50 arrived inside the stall: read after it, one frame's work apart
    assert np.flatnonzero(burst).tolist() == list(range(31, 51))
    np.testing.assert_allclose(np.diff(t[burst]), FRAME_HOST_COST_S, rtol=1e-6)
    assert t[31] == np.float64(0.505)
    # a recording keeps them as they came: late, not dated back as one read
    assert np.array_equal(resolve_batches(t), t)


class StampedSensor(QueueSensor):
    """Each frame carries the device's own time of sending (as adapter timestamps do)."""

    def _handle(self, item: Any, t_host: float) -> None:
        t_device, value = item
        self._emit(InstrumentSample(t_device, {"roll": value}))


def test_a_host_stall_longer_than_the_silence_timeout_is_not_the_instruments_silence(
    tmp_path: Path,
) -> None:
    """A host stall is not the instrument's silence: frames that waited in the port while the
    host was stopped prove the instrument was talking, whatever time they are stamped with.

    A reader judged silence from the last sample's own stamp — for a CAN adapter with
    timestamps, the adapter's time of the frame — so after a host stall longer than
    ``silence_timeout_s`` the backlog it read back carried old stamps, and the run aborted
    "instrument silent" with the instrument's frames in its hands (a 4.7 s stall of the loaded
    ``run_under_load`` benchmark). Silence is judged from when the reader got its last sample."""
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
