"""The fast paths of a run on simulated time do what the slow ones did.

- ``Clock.set_at``: the virtual clock sets an event at its time, by itself (no thread wakes
  before then); the real clock sets it at once. A reader of an in-process link waiting for a
  write wakes once, on its arrival, not also when it was sent.
- ``VirtualClock.call_at`` and ``Endpoint.serve``: the clock runs a device's work at its time,
  in order with the threads, where a thread woken then would have run; it never waits.
- The simulated stand's fast path for reads and read/writes answers as pymodbus's path does,
  byte for byte.
- The simulated instrument's loop run by the clock outputs what its thread outputs, at the same
  instants.
"""

from __future__ import annotations

import math
import threading
from typing import Any

import pytest
from repo_paths import ROOT

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


def test_call_at_runs_at_its_time_in_order_with_the_threads() -> None:
    clock = VirtualClock(start_s=0.0)
    seen: list[tuple[str, float]] = []
    with clock.running():
        def worker() -> None:
            clock.sleep(0.2)
            seen.append(("thread", clock.monotonic()))
            clock.call_at(clock.monotonic(), lambda: seen.append(("now", clock.monotonic())),
                          "sim-now")
            seen.append(("thread again", clock.monotonic()))

        t = clock.thread(worker, name="worker")
        t.start()
        clock.call_at(0.1, lambda: seen.append(("cb", clock.monotonic())), "sim-cb")
        clock.call_at(0.2, lambda: seen.append(("cb2", clock.monotonic())), "sim-cb2")
        t.join()
        clock.sleep(0.01)
    # at 0.2 the callback set first runs before the worker's sleep (set when the worker first
    # ran, once this thread waited) ends; a callback due now runs once the thread running has
    # given the baton up
    assert seen == [("cb", 0.1), ("cb2", 0.2), ("thread", 0.2), ("thread again", 0.2),
                    ("now", 0.2)]


def test_a_callback_never_waits_and_its_error_is_reported_as_a_threads(monkeypatch: Any) -> None:
    from benchctl.errors import SimulationHang

    hooked: list[tuple[type[BaseException] | None, str]] = []
    monkeypatch.setattr(threading, "excepthook",
                        lambda a: hooked.append((a.exc_type, a.thread.name)))
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        clock.call_at(0.1, lambda: clock.sleep(1.0), "sim-sleeper")
        clock.call_at(0.2, lambda: 1 / 0, "sim-divider")
        clock.sleep(0.5)
        assert clock.monotonic() == 0.5
    assert hooked == [(SimulationHang, "sim-sleeper"), (ZeroDivisionError, "sim-divider")]


def test_a_served_endpoint_runs_its_handler_at_each_arrival() -> None:
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        host, dev = channels.link(clock, "t", latency_s=0.001)
        calls: list[float] = []

        def handler() -> None:
            calls.append(clock.monotonic())
            data = dev.read(100, 0.0)
            if data:
                dev.write(data.upper())

        dev.serve(handler, "sim-echo")
        host.write(b"ab")
        assert host.read(10, timeout=1.0) == b"AB"
        assert clock.monotonic() == 0.002 and calls == [0.001]
        host.write(b"c")
        host.write(b"d")  # two writes in flight: the first call reads both
        assert host.read(10, timeout=1.0) == b"CD"
        assert calls == [0.001, 0.003, 0.003]
    with pytest.raises(TypeError):
        channels.link(REAL, "r")[1].serve(handler, "sim-echo")


# -- the simulated stand's fast path for reads and read/writes ------------------------------

def _stands(framing: str, clock: VirtualClock, *, general_physics: bool = False,
            **cfg: Any) -> tuple[Any, Any, Any, Any]:
    """Two identical stands, one answering through the fast path, one through pymodbus's (or,
    ``general_physics``: both through the fast path, the second ticking its physics through
    the general ``_tick`` only)."""
    from benchctl.config import SimStandConfig, StandLimits
    from benchctl.sim.stand import SimStand
    from benchctl.sim.stand_wire import StandWire

    root = ROOT
    out: list[Any] = []
    for _ in range(2):
        st = SimStand(SimStandConfig(**{"bandwidth_hz": 8, "damping": 0.8, "watchdog_s": 3600,
                                        **cfg}),
                      limits=StandLimits(angle_deg=30, rate_deg_s=30, accel_deg_s2=60),
                      register_map=root / "drivers/stand_generic.yaml", transport="channel",
                      framing=framing, clock=clock)  # type: ignore[arg-type]
        st._t0 = st._hb_time = st._start_time = clock.monotonic()
        st._clock_on = True
        out += [st, StandWire(st, framing)]
    if general_physics:
        out[2]._follow = lambda t, states: False
        out[2]._follow2 = lambda k, k_target, states: k
    else:
        out[3]._fast = lambda data: None  # the general path only
    return out[0], out[1], out[2], out[3]


def _requests(framing: str, seed: int, n: int) -> list[bytes]:
    """Seeded request frames: well-formed FC3/FC23 reads and writes over the map and around
    it (a trajectory being pushed and started, the servo enabled), other function codes,
    other unit ids, and frames cut short, lengthened or with a wrong CRC or length."""
    import random
    import struct

    from pymodbus.framer import FramerRTU

    rng = random.Random(seed)
    out: list[bytes] = []
    tid = 0
    f32 = struct.Struct(">f")

    def words(v: float) -> list[int]:
        b = f32.pack(v)
        return [int.from_bytes(b[:2], "big"), int.from_bytes(b[2:], "big")]

    nxt = 0
    for k in range(n):
        tid = (tid + 1) & 0xFFFF
        r = rng.random()
        unit = 1 if rng.random() > 0.03 else rng.choice([0, 2, 247])
        if r < 0.45:  # the feedback read, or a read anywhere near the map
            addr, cnt = (200, 26) if rng.random() < 0.7 else (
                rng.choice([0, 28, 29, 99, 100, 199, 200, 225, 226, 230, 300, 400, 1000,
                            2400, 65535]) + rng.randint(-2, 2), rng.randint(0, 130))
            pdu = struct.pack(">BHH", 3, addr & 0xFFFF, cnt)
        elif r < 0.8:  # a read/write: a push of points, the period, the control word
            what = rng.random()
            if what < 0.5:
                cnt_pts = rng.randint(1, 24) if rng.random() > 0.05 else rng.randint(25, 30)
                first = nxt if rng.random() > 0.1 else rng.randint(0, nxt + 3)
                regs = [first >> 16, first & 0xFFFF, cnt_pts]
                for j in range(cnt_pts):
                    t = (first + j) * 0.01
                    regs += words(5.0 * math.sin(t)) + words(2.0 * math.cos(t))
                if first == nxt:
                    nxt += cnt_pts
                w_addr = 400
            elif what < 0.65:
                regs, w_addr = words(rng.choice([0.01, 0.02, 0.0, 5.0])), 230
            elif what < 0.85:
                regs = [rng.choice([1, 1, 1 | 32, 0, 4, 8, 1 | 2, 16, 0xFFFF]),
                        rng.randint(0, 0xFFFF)]
                w_addr = 100
            else:
                w_addr = rng.choice([0, 29, 100, 101, 102, 200, 300, 301, 304, 1000, 2500])
                regs = [rng.randint(0, 0xFFFF) for _ in range(rng.randint(0, 125))]
            addr, cnt = (200, 26) if rng.random() < 0.8 else (rng.randint(190, 240),
                                                               rng.randint(0, 130))
            pdu = struct.pack(">BHHHHB", 23, addr, cnt, w_addr, len(regs), 2 * len(regs))
            pdu += b"".join(v.to_bytes(2, "big") for v in regs)
        elif r < 0.9:  # the heartbeat or the setpoints: the general path
            pdu = (struct.pack(">BHH", 6, 101, k & 0xFFFF) if rng.random() < 0.5 else
                   struct.pack(">BHHB", 16, 300, 4, 8) + b"".join(
                       w.to_bytes(2, "big") for w in words(1.0) + words(-1.0)))
        else:
            pdu = bytes([rng.choice([1, 2, 4, 5, 8, 15, 17, 43, 0x83])]) + bytes(
                rng.randint(0, 255) for _ in range(rng.randint(0, 12)))
        if framing == "tcp":
            frame = struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu
        else:
            body = bytes([unit]) + pdu
            frame = body + FramerRTU.compute_CRC(body).to_bytes(2, "big")
        damage = rng.random()
        if damage < 0.03:
            frame = frame[: rng.randint(1, len(frame) - 1)]
        elif damage < 0.05:
            frame = frame + bytes([rng.randint(0, 255)])
        elif damage < 0.07:
            i = rng.randrange(len(frame))
            frame = frame[:i] + bytes([frame[i] ^ (1 << rng.randrange(8))]) + frame[i + 1:]
        out.append(frame)
    return out



@pytest.mark.parametrize("framing", ["tcp", "rtu"])
def test_the_stands_fast_path_answers_as_pymodbus_does_byte_for_byte(framing: str) -> None:
    clock = VirtualClock(start_s=0.0)
    with clock.running():
        fast_st, fast, slow_st, slow = _stands(framing, clock)
        fast_hits = 0
        orig = fast._fast  # type: ignore[attr-defined]

        def counting(data: bytes) -> bytes | None:
            nonlocal fast_hits
            got = orig(data)
            fast_hits += got is not None
            return got

        fast._fast = counting
        for i, frame in enumerate(_requests(framing, 7, 4000)):
            a = fast.feed(frame)
            b = slow.feed(frame)
            assert a == b, (i, frame.hex(), a.hex(), b.hex())
            if i % 10 == 9:  # a frame left half-way in one buffer: both start afresh
                fast._buf = slow._buf = b""
            clock.sleep(0.003)
        assert fast._regs == slow._regs
        assert fast_st.requests == slow_st.requests
        assert fast_st._traj.points == slow_st._traj.points
        assert fast_st._enabled == slow_st._enabled
        assert fast_hits > 1000  # the well-formed reads and read/writes went the fast way


def _episodes(seed: int, n: int) -> Any:
    """A host driving a stand through trajectory episodes (MBAP frames, each with the pause
    after it): reset, period, enable, pushes ahead, start; then heartbeats, feedback reads and
    pushes every 10 ms until the episode ends — by a stop, an E-stop, a silence (the watchdog),
    the queue run dry (an underrun) or points beyond the soft limit."""
    import random
    import struct

    rng = random.Random(seed)
    tid = 0

    def frame(pdu: bytes) -> bytes:
        nonlocal tid
        tid = (tid + 1) & 0xFFFF
        return struct.pack(">HHHB", tid, 0, len(pdu) + 1, 1) + pdu

    def fc16(addr: int, words: list[int]) -> bytes:
        return frame(struct.pack(">BHHB", 16, addr, len(words), 2 * len(words))
                     + b"".join(w.to_bytes(2, "big") for w in words))

    def f32(v: float) -> list[int]:
        b = struct.pack(">f", v)
        return [int.from_bytes(b[:2], "big"), int.from_bytes(b[2:], "big")]

    def push(first: int, amp: float, count: int) -> bytes:
        regs = [first >> 16, first & 0xFFFF, count]
        for j in range(count):
            t = (first + j) * 0.01
            regs += f32(amp * math.sin(1.3 * t)) + f32(0.6 * amp * math.cos(0.7 * t))
        return frame(struct.pack(">BHHHHB", 23, 200, 26, 400, len(regs), 2 * len(regs))
                     + b"".join(w.to_bytes(2, "big") for w in regs))

    read = frame(struct.pack(">BHH", 3, 200, 26))
    hb = 0
    for _ in range(n):
        end = rng.choice(["stop", "estop", "silence", "dry", "soft", "long"])
        amp = 6.0 if end == "soft" else rng.uniform(1.0, 3.5)
        yield fc16(100, [8]), 0.002  # fault reset
        yield fc16(230, f32(0.01)), 0.002
        yield fc16(100, [1]), 0.002
        nxt = 0
        yield push(nxt, amp, 24), 0.002
        nxt += 24
        yield fc16(100, [1 | 32]), 0.003
        for c in range(rng.randint(60, 400)):
            if end != "silence" or c < 30:
                hb = (hb + 1) & 0xFFFF
                yield frame(struct.pack(">BHH", 6, 101, hb)), 0.0005
            if (end != "dry" or c < 40) and nxt < (c + 1) + 40:
                yield push(nxt, amp, 12), 0.001
                nxt += 12
            else:
                yield read, 0.001
            yield read, rng.choice([0.0085, 0.0085, 0.0085, 0.02, 0.0013])
        if end == "stop":
            yield fc16(100, [1 | 4]), 0.3
        elif end == "estop":
            yield fc16(100, [16]), 0.3
        else:
            yield read, 0.5


def test_the_stands_physics_in_one_piece_ticks_as_the_general_tick() -> None:
    """Following the trajectory queue, tick by tick or many ticks at once, against the
    general tick alone — through soft-limit faults (a low soft limit), the watchdog, scheduled
    faults, underruns, stops, E-stops and resets: the same replies, states, history, peaks."""
    import numpy as np

    from benchctl.config import SimStandFault

    clock = VirtualClock(start_s=0.0)
    with clock.running():
        fast_st, fast, slow_st, slow = _stands(
            "tcp", clock, general_physics=True, soft_limit_deg=4.5, watchdog_s=0.3,
            faults=(SimStandFault(kind="stand_fault", after_s=13.0, code=9),
                    SimStandFault(kind="estop", after_s=41.0)))
        followed = 0
        orig = fast_st._follow2

        def counting(k: int, k_target: int, states: Any) -> int:
            nonlocal followed
            done: int = orig(k, k_target, states)
            followed += done - k
            return done

        fast_st._follow2 = counting
        for i, (frame, pause) in enumerate(_episodes(5, 40)):
            assert fast.feed(frame) == slow.feed(frame), i
            clock.sleep(pause)
            if i % 25 == 0:  # as the instrument and the physics thread look at it
                ts = clock.monotonic() - 0.0137 * np.arange(5)[::-1]
                ta, tb = fast_st.true_angles_many(ts), slow_st.true_angles_many(ts)
                assert all((ta[a] == tb[a]).all() for a in ta)
        for name in ("_k", "_mode", "_enabled", "_fault_code", "_estop", "_limit", "_target",
                     "_stream_target", "_peaks", "_axis_fault", "_traj_stop"):
            assert getattr(fast_st, name) == getattr(slow_st, name), name
        assert [(s.angle_deg, s.rate_deg_s) for s in fast_st._state.values()] == [
            (s.angle_deg, s.rate_deg_s) for s in slow_st._state.values()]
        assert (fast_st._hist == slow_st._hist).all()
        assert fast_st._traj.points == slow_st._traj.points
        assert fast_st._traj.underruns == slow_st._traj.underruns > 0
        assert fast_st.enables > 10
        assert followed > 20_000  # most ticks went the one-piece way


# -- the simulated instrument's loop run by the clock ---------------------------------------

class _Sine:
    def true_angles(self, t: float) -> dict[str, float]:
        return {"roll": 3.0 * math.sin(t), "pitch": math.cos(2.0 * t)}


def _instrument_trace(driver: str, threaded: bool, monkeypatch: Any) -> list[Any]:
    """What the host end of a simulated instrument's link receives over 3 s of simulated time
    (each read with its instant), with the host's own bytes, raw bytes and faults meanwhile,
    then what it gets as the instrument stops; its loop as a thread or run by the clock."""
    from benchctl.config import InstrumentConfig, SimInstrumentConfig
    from benchctl.sim import instrument as sim_instrument

    root = ROOT / "drivers"
    base: dict[str, Any] = {"driver": driver}
    if driver == "nmea0183":
        base["serial_port"] = "set-by-the-simulator"
    else:
        base.update(interface="slcan", channel="set-by-the-simulator")
    if driver == "canopen":
        base["eds"] = root / "cia410_inclinometer.eds"
    if driver == "j1939":
        base["dbc"] = root / "j1939_slope.dbc"
    with monkeypatch.context() as mp:
        if threaded:  # the loop as a thread, as on the host's time
            mp.setattr(sim_instrument.SimInstrument, "start", _threaded_start)
        clock = VirtualClock(start_s=0.0)
        out: list[Any] = []
        with clock.running():
            sim = sim_instrument.SimInstrument(
                SimInstrumentConfig(rate_hz=100.0, noise_deg=0.05, lag_s=0.05, seed=3),
                InstrumentConfig(**base), _Sine(), clock=clock,
                channel=channels.free_name("fast-paths"))
            sim.start()
            assert isinstance(sim._thread, sim_instrument._Loop) != threaded
            host = channels.lookup(sim.channel or "")
            if driver != "nmea0183":
                host.write(b"C\rS6\rO\r")  # the host opens the adapter (acknowledged)
            if driver == "canopen":  # NMT start: the node sends its PDOs
                host.write(f"t000201{sim.cfg.node_id:02X}\r".encode())
            end = clock.monotonic() + 3.0
            while clock.monotonic() < end:
                got = host.read(1 << 16, 0.013)
                out.append((round(clock.monotonic(), 9), got))
                n = len(out)
                if n == 40:
                    sim.send_raw(b"raw!\r")
                if n == 60:
                    sim.inject("garbled", fraction=0.5)
                if n == 90:
                    sim.clear_faults()
                    sim.inject("silent")
                if n == 120:
                    sim.clear_faults()
            sim.stop()
            out.append(("stopped", round(clock.monotonic(), 9), dict(sim.counts)))
            channels.unregister(sim.channel or "")
        return out


def _threaded_start(self: Any) -> None:
    self._port = __import__("benchctl.sim.instrument", fromlist=["_ChannelPort"])._ChannelPort(
        self.clock, self.channel_name, self.cfg.baudrate)
    self.serial_port = self.channel = self._port.path
    if self.is_can:
        from benchctl.sim.slcan import SlcanAdapter

        self._adapter = SlcanAdapter(self.cfg.bitrate, self._on_host_frame,
                                     clock=self.clock.monotonic)
    self._stop.clear()
    self._thread = self.clock.thread(self._run_channel, name=f"sim-instrument-{self.driver}")
    self._thread.start()
    self._ready.wait(5.0)


@pytest.mark.parametrize("driver", ["canopen", "j1939", "nmea0183"])
def test_the_instruments_loop_run_by_the_clock_outputs_as_its_thread(
        driver: str, monkeypatch: Any) -> None:
    by_clock = _instrument_trace(driver, False, monkeypatch)
    by_thread = _instrument_trace(driver, True, monkeypatch)
    assert sum(len(b) for _, b in by_clock[:-1]) > 3000  # it did talk
    assert by_clock == by_thread
