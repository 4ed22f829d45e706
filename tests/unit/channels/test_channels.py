"""In-process links on a virtual clock: a write arrives whole after its latency and its bytes'
time on the line, one write after another; a closed link reads empty at once."""

from __future__ import annotations

import pytest
import serial

from benchctl import channels
from benchctl.clock.virtual import VirtualClock


def test_a_write_arrives_whole_after_its_latency_and_byte_times() -> None:
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        host, dev = channels.link(clock, "t", byte_time_s=0.001, latency_s=0.0005)
        host.write(b"hello")  # on the line 0.5 ms … 5.5 ms
        host.write(b"ab")  # waits for the first: 5.5 … 7.5 ms
        clock.sleep(0.005)
        assert dev.in_waiting == 0
        assert dev.read(100, timeout=None) == b"hello"
        assert clock.monotonic() == pytest.approx(0.0055)
        assert dev.read(1, timeout=0.0) == b""  # "ab" is still on the line
        assert dev.read(1, timeout=1.0) == b"a"
        assert clock.monotonic() == pytest.approx(0.0075)
        assert dev.in_waiting == 1 and dev.read(10) == b"b"


def test_a_read_times_out_exactly_and_a_closed_link_reads_empty_at_once() -> None:
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        host, dev = channels.link(clock, "t")
        assert dev.read(10, timeout=0.25) == b""
        assert clock.monotonic() == 0.25
        host.write(b"x")
        host.close()
        assert dev.read(10, timeout=5.0) == b"x"  # what was in flight, then nothing
        assert dev.read(10, timeout=5.0) == b"" and clock.monotonic() == 0.25
        with pytest.raises(OSError, match="closed"):
            dev.write(b"y")


def test_seeded_delay_and_loss_act_on_each_write() -> None:
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        host, dev = channels.link(clock, "t")
        extra = iter([0.5, None, 0.0])
        host.delay = lambda data: next(extra)
        host.write(b"slow")
        host.write(b"lost")
        host.write(b"next")  # queued behind the slow one on the line: arrives with it
        assert dev.read(100, timeout=None) == b"slownext" and clock.monotonic() == 0.5


def test_a_registered_endpoint_opens_as_a_pyserial_port_with_its_timeout() -> None:
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        host, dev = channels.link(clock, "t")
        url = channels.register(channels.free_name("test-port"), host)
        try:
            port = serial.serial_for_url(url, baudrate=9600, timeout=0.05)
            dev.write(b"abc")
            assert port.read(5) == b"abc"  # waits its whole timeout for the two missing
            assert clock.monotonic() == pytest.approx(0.05)
            port.write(b"ok")
            assert dev.read(5, timeout=0.0) == b"ok"
        finally:
            channels.unregister(url)
