"""The virtual clock: deterministic threads on simulated time, exact deadlines, hangs named."""

from __future__ import annotations

import os
import queue
import threading
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchctl.clock import REAL
from benchctl.clock.virtual import VirtualClock
from benchctl.errors import SimulationHang


def test_sleepers_wake_at_their_exact_simulated_instants_in_deadline_order() -> None:
    clock = VirtualClock(start_s=0.0)
    seen: list[tuple[float, str]] = []

    def sleeper(name: str, period: float, n: int) -> None:
        for _ in range(n):
            clock.sleep(period)
            seen.append((clock.monotonic(), name))

    with clock.running():
        a = clock.thread(sleeper, name="a", args=("a", 0.25, 4))
        b = clock.thread(sleeper, name="b", args=("b", 0.4, 2))
        a.start()
        b.start()
        a.join()
        b.join()
        assert clock.monotonic() == 1.0
    assert seen == [(0.25, "a"), (0.4, "b"), (0.5, "a"), (0.75, "a"), (0.8, "b"), (1.0, "a")]


def test_a_simulated_hour_takes_no_host_time() -> None:
    clock = VirtualClock(start_s=0.0)
    t0 = time.perf_counter()
    with clock.running():
        clock.sleep(3600.0)
        assert clock.monotonic() == 3600.0
    assert time.perf_counter() - t0 < 30.0  # generous: no host wait of an hour


def test_wall_time_starts_at_the_epoch_and_follows_simulated_time() -> None:
    clock = VirtualClock(start_s=5.0)
    with clock.running():
        t = clock.time()
        clock.sleep(1.5)
        assert clock.time() - t == 1.5
        assert clock.now_utc().isoformat() == "2026-01-01T00:00:01.500000+00:00"


def test_event_wait_times_out_exactly_and_returns_at_once_when_set() -> None:
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        ev = clock.event()
        assert ev.wait(0.3) is False
        assert clock.monotonic() == 0.3

        def setter() -> None:
            clock.sleep(0.2)
            ev.set()

        clock.thread(setter, name="setter").start()
        assert ev.wait(5.0) is True
        assert clock.monotonic() == pytest.approx(0.5)


def test_queue_get_with_timeout_and_fifo_order() -> None:
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        q = clock.queue()

        def producer() -> None:
            for i in range(3):
                clock.sleep(1.0)
                q.put(i)

        clock.thread(producer, name="producer").start()
        assert [q.get(timeout=2.0) for _ in range(3)] == [0, 1, 2]
        assert clock.monotonic() == 3.0
        with pytest.raises(queue.Empty):
            q.get(timeout=0.5)
        assert clock.monotonic() == 3.5
        with pytest.raises(queue.Empty):
            q.get_nowait()


def test_a_lock_held_across_a_wait_is_handed_over_in_order() -> None:
    clock = VirtualClock(start_s=0.0)
    order: list[str] = []
    with clock.running():
        lock = clock.rlock()

        def holder() -> None:
            with lock, lock:  # re-entrant
                clock.sleep(1.0)
                order.append("holder")

        def contender(name: str) -> None:
            clock.sleep(0.1)
            with lock:
                order.append(name)

        threads = [clock.thread(holder, name="h")]
        threads += [clock.thread(contender, name=n, args=(n,)) for n in ("c1", "c2")]
        for t in threads:
            t.start()
        clock.sleep(0.05)
        assert lock.acquire(timeout=0.2) is False  # held by the holder until t = 1
        assert clock.monotonic() == pytest.approx(0.25)
        for t in threads:
            t.join()
    assert order == ["holder", "c1", "c2"]


def test_condition_wait_for_with_timeout() -> None:
    clock = VirtualClock(start_s=0.0)
    box: list[int] = []
    with clock.running():
        cond = clock.condition()

        def filler() -> None:
            for i in range(3):
                clock.sleep(0.1)
                with cond:
                    box.append(i)
                    cond.notify_all()

        clock.thread(filler, name="filler").start()
        with cond:
            assert cond.wait_for(lambda: len(box) == 3, timeout=1.0)
        assert clock.monotonic() == pytest.approx(0.3)
        with cond:
            assert not cond.wait_for(lambda: len(box) == 4, timeout=0.5)


def test_join_with_timeout() -> None:
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        t = clock.thread(clock.sleep, name="long", args=(10.0,))
        t.start()
        t.join(timeout=2.0)
        assert t.is_alive() and clock.monotonic() == 2.0
        t.join()
        assert not t.is_alive() and clock.monotonic() == 10.0


def test_every_thread_waiting_forever_is_a_named_hang() -> None:
    clock = VirtualClock(start_s=0.0)
    hang = r"(?s)every thread waits.*stuck: waits on Event"
    with pytest.raises(SimulationHang, match=hang), clock.running():
        never = clock.event()
        clock.thread(never.wait, name="stuck").start()
        never.wait()


def test_a_wait_outside_the_clock_is_named_by_the_watchdog() -> None:
    clock = VirtualClock(start_s=0.0, hang_s=1.0)
    with pytest.raises(SimulationHang), clock.running():
        for _ in range(200):  # a loop of host sleeps: never gives the clock up
            time.sleep(0.05)
    assert clock.hang is not None
    assert "MainThread" in clock.hang and "time.sleep(0.05)" in clock.hang


def test_a_stopped_process_is_not_a_hang(monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole process stopped for longer than ``hang_s`` (SIGSTOP, a suspended machine)
    while a thread held the clock: host time jumps, but that thread was not stuck. A
    campaign run paused that way for 50 min ended in SimulationHang (seed 600569)."""
    import benchctl.clock.virtual as virtual

    jump = [0.0]
    real = time.monotonic
    monkeypatch.setattr(virtual.time, "monotonic", lambda: real() + jump[0])
    clock = VirtualClock(start_s=0.0, hang_s=4.0)  # the watchdog looks every 1 s
    with clock.running():
        start = real()
        jump[0] = 3000.0  # the host's clock leaps, as after SIGCONT …
        while real() < start + 1.3:  # … while this thread holds the clock, busy, past the
            pass  # watchdog's first look (that look saw 3000 s without a hand-over)
        clock.sleep(0.01)
    assert clock.hang is None


def test_a_thread_not_started_by_the_clock_is_refused() -> None:
    clock = VirtualClock(start_s=0.0)
    errors: list[BaseException] = []
    with clock.running():
        ev = clock.event()

        def outsider() -> None:
            try:
                ev.wait(1.0)
            except SimulationHang as e:
                errors.append(e)

        t = threading.Thread(target=outsider)  # the point: a thread the clock did not start
        t.start()
        t.join()
    assert errors and "not started by it" in str(errors[0])


def test_threads_left_waiting_are_ended_when_the_clock_is_left() -> None:
    clock = VirtualClock(start_s=0.0)
    ended: list[str] = []

    def forever() -> None:
        try:
            clock.event().wait()
        finally:
            ended.append("forever")

    with clock.running():
        t = clock.thread(forever, name="forever")
        t.start()
        clock.sleep(1.0)
    assert ended == ["forever"] and not t.is_alive()


@settings(max_examples=30, deadline=None)
@given(
    periods=st.lists(st.integers(min_value=1, max_value=50), min_size=1, max_size=5),
    horizon=st.integers(min_value=1, max_value=200),
)
def test_interleaving_is_the_same_every_time(periods: list[int], horizon: int) -> None:
    """Threads ticking at integer-millisecond periods: the trace of who ran when is the
    deadline order (ties by the order the waits began), and identical on a second run."""

    def trace() -> list[tuple[int, int]]:
        clock = VirtualClock(start_s=0.0)
        out: list[tuple[int, int]] = []

        def ticker(i: int, p: int) -> None:
            k = 0
            while (k + 1) * p <= horizon:
                clock.sleep(p / 1000)
                k += 1
                out.append((round(clock.monotonic() * 1000), i))

        with clock.running():
            ts = [clock.thread(ticker, name=f"t{i}", args=(i, p)) for i, p in enumerate(periods)]
            for t in ts:
                t.start()
            for t in ts:
                t.join()
        return out

    first = trace()
    assert first == trace()
    assert [t for t, _ in first] == sorted(t for t, _ in first)
    expected = sorted((k * p, i) for i, p in enumerate(periods) for k in range(1, horizon // p + 1))
    assert sorted(first) == expected


def test_the_real_clock_is_the_operating_systems() -> None:
    assert REAL.virtual is False
    t0 = REAL.monotonic()
    REAL.sleep(0.01)
    assert REAL.monotonic() > t0
    ev = REAL.event()
    assert ev.wait(0.0) is False
    q = REAL.queue()
    q.put(1)
    assert q.get(timeout=0.1) == 1


def test_a_host_stall_holds_the_hosts_threads_not_the_devices() -> None:
    """A stall (the run's process stopped) puts off every host thread due inside it to its
    end, keeping what its wait gave; a device thread (``sim-…``) runs on through it."""
    clock = VirtualClock(start_s=0.0)
    host: list[float] = []
    device: list[float] = []
    with clock.running():
        clock.stall_host(1.05, 0.5)  # [1.05, 1.55)
        ev = clock.event()

        def dev() -> None:
            for _ in range(20):
                clock.sleep(0.1)
                device.append(round(clock.monotonic(), 9))
                if len(device) == 12:
                    ev.set()  # at 1.2, inside the stall

        d = clock.thread(dev, name="sim-device")
        d.start()
        for _ in range(4):
            clock.sleep(0.3)
            host.append(round(clock.monotonic(), 9))
        assert ev.wait(5.0) is True  # set at 1.2: seen at the stall's end
        assert clock.monotonic() == pytest.approx(1.55)
        assert ev.wait(0.0)
        d.join()
    assert host == [0.3, 0.6, 0.9, 1.55]  # due at 1.2: ran at 1.55
    assert device == [round(0.1 * k, 9) for k in range(1, 21)]  # on time throughout


def _affinity() -> set[int] | None:
    get = getattr(os, "sched_getaffinity", None)
    return None if get is None else set(get(0))


def test_a_running_clock_keeps_its_threads_on_one_cpu_and_gives_the_set_back() -> None:
    """Inside ``running()`` the entering thread and the threads the clock starts share one CPU
    (where the process may use more than one); on leaving, the former set is back. A clock
    made with ``pin_cpu=False`` changes nothing."""
    before = _affinity()
    c = VirtualClock()
    seen: list[set[int] | None] = []
    with c.running():
        inside = _affinity()
        t = c.thread(lambda: seen.append(_affinity()), name="worker")
        t.start()
        t.join()
    after = _affinity()
    assert after == before
    if before is not None and len(before) > 1:
        assert inside is not None and len(inside) == 1 and inside <= before
        assert seen == [inside]
    else:  # one CPU allowed, or no affinity call here: nothing to change
        assert inside == before and seen == [before]
    with VirtualClock(pin_cpu=False).running():
        assert _affinity() == before


def test_the_clocks_threads_may_move_together_to_another_cpu() -> None:
    """``_repin`` (the watchdog's, every two seconds): the clock's threads are let free for a
    moment and kept together again where the thread holding the baton went, one CPU of the
    former set; leaving the clock gives the whole set back."""
    before = _affinity()
    if before is None or len(before) < 2:
        with VirtualClock().running():
            assert _affinity() == before  # nothing kept, nothing moved
        return
    c = VirtualClock()
    seen: list[set[int] | None] = []
    with c.running():
        go = c.event()

        def worker() -> None:
            go.wait()
            seen.append(_affinity())

        t = c.thread(worker, name="worker")
        t.start()
        c.sleep(0.1)  # the worker runs up to its wait
        c._repin(before)
        here = _affinity()
        go.set()
        t.join()
    assert here is not None and len(here) == 1 and here <= before
    assert seen == [here]
    assert _affinity() == before


def test_a_signal_that_lands_inside_the_clock_is_the_runs_fault_not_a_deadlock() -> None:
    """A real Ctrl-C on simulated time: Python runs the run's handler in the main thread
    between two bytecodes, here while that thread holds the clock's mutex (where it lands
    when it hands the baton over). The handler reached the fault's stop event, which takes
    that mutex: the run hung for good. Through ``from_signal`` the fault is the run's at the
    next wait, and whoever waits on its stop event wakes."""
    import signal

    from benchctl.run.supervisor import Supervisor

    clock = VirtualClock(hang_s=30.0)
    woke: list[float] = []
    with clock.running():
        sup = Supervisor(clock=clock)

        def waiter() -> None:
            if sup.stop_event.wait(5.0):
                woke.append(clock.monotonic())

        t = clock.thread(waiter, name="waiter")
        t.start()
        clock.sleep(0.5)
        with sup.signals():
            with clock._mu:  # the handler must run while this thread holds the mutex
                signal.raise_signal(signal.SIGINT)  # its handler runs before it returns
            assert sup.first is None  # handed over, not reported under the mutex
            clock.sleep(0.1)  # the next wait: the fault reported, the waiter woken
        t.join()
    assert sup.first is not None and "interrupted by SIGINT" in sup.first.reason
    assert woke and woke[0] == pytest.approx(1000.5)
