"""The slcan bus waits on its own clock: on simulated time a silent bus's ``recv(timeout)``
returns None after exactly ``timeout`` simulated seconds, however long the host takes (the
library's own ``recv`` counted the time left on the host's wall clock: a silent bus then waited
a few tenths of simulated seconds, another amount each run)."""

from __future__ import annotations

import time

import pytest

from benchctl import channels
from benchctl.clock.virtual import VirtualClock
from benchctl.devices.can.slcan import SlcanBus


# (start, timeout): at 1000.1 s and 12345.678 s the elapsed time (start + timeout) − start reads
# a rounding error short of the timeout (4.5e-14, 7.3e-13 s): a time left counted as timeout −
# elapsed never reached 0 and the receive spun for ever on a clock that did not move
@pytest.mark.timeout(30)  # a receive that never ends fails here, not at the suite's 120 s
@pytest.mark.parametrize("start, timeout", [(0.0, 0.05), (0.0, 0.3), (1000.1, 0.05),
                                            (12345.678, 0.3)])
def test_a_silent_bus_times_out_after_exactly_its_timeout_on_simulated_time(
        start: float, timeout: float) -> None:
    clock = VirtualClock(start_s=start)
    with clock.running():
        host, _dev = channels.link(clock, "slcan-silent")
        url = channels.register(channels.free_name("slcan-silent"), host)
        try:
            bus = SlcanBus(url, bitrate=500000, sleep_after_open=0, clock=clock)
            try:
                t0 = clock.monotonic()
                wall0 = time.monotonic()
                got = bus.recv(timeout=timeout)
                while time.monotonic() - wall0 < 0.01:  # the host slower than the simulation
                    pass
                assert got is None
                assert clock.monotonic() - t0 == pytest.approx(timeout, abs=1e-9)
                assert bus.recv(timeout=timeout) is None  # and again from there
            finally:
                bus.shutdown()
        finally:
            channels.unregister(url)


def test_a_frame_after_a_filtered_one_is_taken_within_the_timeout() -> None:
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        host, dev = channels.link(clock, "slcan-filter")
        url = channels.register(channels.free_name("slcan-filter"), host)
        try:
            bus = SlcanBus(url, bitrate=500000, sleep_after_open=0, clock=clock,
                           can_filters=[{"can_id": 0x18A, "can_mask": 0x7FF}])
            try:
                dev.read(100, timeout=0.0)  # what the bus sent on open
                dev.write(b"t0011AA\r")  # filtered out
                clock.sleep(0.01)
                dev.write(b"t18A2E803\r")
                t0 = clock.monotonic()
                msg = bus.recv(timeout=0.5)
                assert msg is not None and msg.arbitration_id == 0x18A
                assert bytes(msg.data) == bytes.fromhex("E803")
                assert clock.monotonic() - t0 < 0.5
            finally:
                bus.shutdown()
        finally:
            channels.unregister(url)
