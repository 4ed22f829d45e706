"""The fast paths of a run on simulated time do what the slow ones did.

- ``Clock.set_at``: the virtual clock sets an event at its time, by itself (no thread wakes
  before then); the real clock sets it at once. A reader of an in-process link waiting for a
  write wakes once, on its arrival, not also when it was sent.
"""

from __future__ import annotations

import threading

from benchctl import channels
from benchctl.clock import REAL
from benchctl.clock.virtual import VirtualClock


def test_set_at_sets_the_event_at_its_time_and_no_earlier() -> None:
    clock = VirtualClock(start_s=0.0)
    woke: list[tuple[str, float]] = []
    with clock.running():
        ev = clock.event()

        def waiter() -> None:
            assert ev.wait(None)
            woke.append(("waiter", clock.monotonic()))

        t = clock.thread(waiter, name="waiter")
        t.start()
        clock.set_at(ev, 0.25)
        clock.set_at(ev, 0.1)  # the earlier one sets it: the waiter runs then
        assert not ev.is_set()
        clock.sleep(0.05)
        assert not ev.is_set() and not woke
        t.join()
        assert woke == [("waiter", 0.1)]
        ev.clear()
        clock.sleep(0.2)  # the later one fires too, with nobody waiting: the flag is set
        assert ev.is_set()
        clock.set_at(ev, 0.0)  # a time already passed: now
        assert ev.is_set()


def test_set_at_on_the_real_clock_sets_the_event_at_once() -> None:
    ev = REAL.event()
    REAL.set_at(ev, REAL.monotonic() + 3600.0)
    assert ev.is_set()
    assert isinstance(ev, threading.Event)


def test_a_link_reader_wakes_once_per_write_on_its_arrival() -> None:
    clock = VirtualClock(start_s=0.0)
    got: list[tuple[bytes, float]] = []
    with clock.running():
        host, dev = channels.link(clock, "t", latency_s=0.0005, byte_time_s=0.0001)

        def reader() -> None:
            for _ in range(3):
                got.append((dev.read(100, timeout=None), clock.monotonic()))

        t = clock.thread(reader, name="reader")
        t.start()
        clock.sleep(0.001)
        before = clock.switches
        for _ in range(3):
            host.write(b"ab")
            clock.sleep(0.01)
        t.join()
        # per write: the reader's one wake (at the arrival), and this thread's sleep
        assert clock.switches - before <= 2 * 3 + 1
    assert [d for d, _ in got] == [b"ab"] * 3
    for i, (_, when) in enumerate(got):
        assert abs(when - (0.001 + 0.01 * i + 0.0005 + 0.0002)) < 1e-12
