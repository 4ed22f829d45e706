"""End to end: bad frames on the instrument's wire during a real run are counted, the run PASSes.

For each instrument protocol family (NMEA 0183, CANopen over slcan; the real drivers over
in-process links, on simulated time) a real short run (``run_test``, ci_short shortened to 20 s)
against the simulators; once the stand moves, the simulated instrument puts one bad frame of
each known kind on the wire (``send_raw``: byte-exact) and then a burst of ``garbled
how=bytes`` frames, from a device thread (``sim-…``). The run must end
``done`` with a PASS verdict, every one of those frames counted in ``stats`` by its reason, and
nothing else counted bad.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from live_bench import ROOT, LiveBench, live_bench

from benchctl.clock import EventLike
from benchctl.clock.virtual import VirtualClock
from benchctl.run import RunOptions, run_test

pytestmark = pytest.mark.slow

PROFILE = ROOT / "profiles/ci_short.yaml"
DURATION_S = 20.0  # the steady part (minus 3 + 3 s fades) must resolve 0.08 Hz
GARBLED_BURST = 15  # frames damaged by garbled how=bytes

# byte-exact bad frames of each known kind, with the reason the driver must count
NMEA_BAD = [
    (b"$PASHR*58\r\n", "length"),  # was IndexError inside pynmea2
    # a leap second (was AttributeError from pynmea2's time parsing), roll beyond 180°
    (b"$PASHR,235960.000,224.19,T,999.99,+00.83,+00.00,0.101,0.113,0.267,1,0*14\r\n", "range"),
    (b"$PASHR,245960.000,224.19,T,-01.26,+00.83*28\r\n", "range"),  # hour 24
    (b"$PASHR,\xff\xfe\x00\x1b,T,-01.26,+00.83*28\r\n", "decode"),  # bytes beyond ASCII
]
SLCAN_BAD = [  # node 10: TPDO1 18A, EMCY 8A, heartbeat 70A, SDO answer 58A
    (b"t18A4\xff\xfe0318FC\r", "decode"),  # not UTF-8: python-can's "lost link"
    (b"#\x00\x1bgarbage\r", "decode"),  # a line python-can dropped without a word
    (b"t08A3108101\r", "length"),  # EMCY of 3 bytes: was struct.error in canopen
    (b"t70A0\r", "length"),  # heartbeat of 0 bytes: was struct.error in canopen
    (b"t58A443001000\r", "length"),  # SDO answer of 4 bytes
    (b"t70A133\r", "range"),  # heartbeat with no NMT state
]


def _wait(cond: Callable[[], bool], timeout_s: float, what: str, stop: EventLike,
          clock: VirtualClock) -> None:
    end = clock.monotonic() + timeout_s
    while not cond():
        if stop.is_set():
            raise RuntimeError("test over")
        if clock.monotonic() > end:
            raise AssertionError(f"timed out waiting for {what}")
        clock.sleep(0.02)


def _moving(bench: LiveBench) -> bool:
    now = bench.stand.clock.monotonic()
    return any(abs(v) > 0.2 for v in bench.stand.true_angles(now).values())


def _inject(bench: LiveBench, bad: list[tuple[bytes, str]], stop: EventLike,
            clock: VirtualClock) -> None:
    sim = bench.instrument
    _wait(lambda: _moving(bench), 60.0, "the stand to move", stop, clock)
    for data, _ in bad:
        sim.send_raw(data)
    _wait(lambda: sim.counts["raw"] == len(bad), 10.0, "the raw frames on the wire", stop, clock)
    sim.inject("garbled", fraction=0.25, how="bytes")
    try:
        _wait(lambda: sim.counts["garbled"] >= GARBLED_BURST, 10.0, "the garbled burst", stop,
              clock)
    finally:
        sim.clear_faults()


@pytest.mark.parametrize(
    ("instrument", "bad"),
    [("nmea0183", NMEA_BAD), ("canopen", SLCAN_BAD)],
    ids=["nmea0183", "canopen-slcan"],
)
def test_bad_frames_during_a_run_are_counted_and_it_passes(
    tmp_path: Path, instrument: str, bad: list[tuple[bytes, str]], vclock: VirtualClock
) -> None:
    errors: list[BaseException] = []
    stop = vclock.event()
    with live_bench(tmp_path, instrument=instrument, clock=vclock) as b:

        def injector() -> None:
            try:
                _inject(b, bad, stop, vclock)
            except BaseException as e:  # reported by the test, not lost in a thread
                errors.append(e)

        # the simulated instrument's side: a device thread (sim-…), which host stalls leave be
        t = vclock.thread(injector, name="sim-inject-bad-frames")
        t.start()
        try:
            res = run_test(b.cfg, PROFILE, RunOptions("BAD-FRAMES", "ci", duration_s=DURATION_S),
                           clock=vclock)
        finally:
            stop.set()
            t.join(timeout=10.0)
        garbled = b.instrument.counts["garbled"]
        assert b.instrument.error is None
    assert errors == [], errors
    assert res.state == "done" and res.exit_code == 0, res.reason
    assert res.report is not None and res.report.verdict == "PASS"
    expected: dict[str, int] = {}
    for _, reason in bad:
        expected[reason] = expected.get(reason, 0) + 1
    expected["decode"] = expected.get("decode", 0) + garbled
    st = res.stats
    assert garbled >= GARBLED_BURST
    assert st["instrument_bad_by_reason"] == expected
    assert st["instrument_bad_frames"] == len(bad) + garbled
