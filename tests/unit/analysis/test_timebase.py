"""Time bases: instants that do not bias σ.

- slcan adapter timestamps: parsed from any frame line (property), unwrapped across the
  adapter's 60 000 ms (or 16-bit) wrap whatever the gaps and host delays (property);
- counters and device clocks: NMEA 2000 SID and a PASHR time of day across midnight;
- slots and the robust clock of receipt stamps: stalls (a burst of k late samples after a
  silence of k slots is a delay, not k drops), drops, heavy lateness, a 4 ms scheduler tick;
- a recording's best time base (device, adapter, fitted), and the stand's stamps;
- the analysis: 1 ms rms jitter on both streams changes σ by < 0.2 % for a 0.027° instrument
  at 5°/s rms roll rate with fitted time bases; given stamps are warned about, with the timing
  contribution σ_ẋ²·jitter² estimated;
- the RTU stamp at the end of the request on the wire.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from analysis_synthetic import Multisine, first_order
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from timing_drift import jittered_streams

from benchctl.analysis import analyze
from benchctl.analysis.clockfit import fit_slots, robust_clock
from benchctl.analysis.timebase import (
    Instants,
    counter_slots,
    instrument_timebase,
    label_of,
    stamp_error,
    unwrap,
)
from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
from benchctl.devices.can.slcan import AdapterClock, parse_line
from benchctl.devices.modbus.link import rtu_link, tcp_link
from benchctl.recording import RecordingWriter, load_recording
from benchctl.sim.slcan import SlcanAdapter, frame_line

PROPS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ------------------------------------------------------------------------------ slcan stamps
@PROPS
@given(
    ext=st.booleans(),
    remote=st.booleans(),
    data=st.binary(max_size=8),
    cid=st.integers(0, 0x1FFFFFFF),
    stamp=st.one_of(st.none(), st.integers(0, 0xFFFF)),
)
def test_slcan_line_with_or_without_timestamp(
    ext: bool, remote: bool, data: bytes, cid: int, stamp: int | None
) -> None:
    import can

    cid = cid if ext else cid & 0x7FF
    msg = can.Message(arbitration_id=cid, is_extended_id=ext, is_remote_frame=remote,
                      dlc=len(data), data=b"" if remote else data)
    line = frame_line(msg)[:-1] + (b"" if stamp is None else f"{stamp:04X}".encode())
    got = parse_line(line)
    assert got is not None
    assert got.arbitration_id == cid and got.is_extended_id == ext and got.dlc == len(data)
    assert bytes(got.data) == (b"" if remote else data)
    assert got.adapter_ms == stamp  # type: ignore[attr-defined]


@PROPS
@given(
    wrap=st.sampled_from([60_000, 65_536]),
    start_ms=st.integers(0, 59_999),
    steps=st.lists(st.integers(1, 25_000), min_size=1, max_size=60),
    delays=st.lists(st.floats(0.0, 0.5), min_size=61, max_size=61),
)
def test_adapter_clock_unwraps_any_gaps(
    wrap: int, start_ms: int, steps: list[int], delays: list[float]
) -> None:
    """Frames up to 25 s apart, received up to 0.5 s late: the unwrapped adapter time is the
    true elapsed time to the millisecond (a 16-bit counter is recognised by a value ≥ 60 000,
    which it shows before its first wrap when frames are ≤ 5 s apart)."""
    if wrap == 65_536:
        steps = [min(s, 5_000) for s in steps]
    true = start_ms + np.concatenate(([0], np.cumsum(steps)))
    clock = AdapterClock()
    out = [clock.unwrap(int(ms % wrap), 1000.0 + ms / 1000.0 + d)
           for ms, d in zip(true, delays, strict=False)]
    assert np.array_equal(np.rint((np.array(out) - out[0]) * 1000), true - true[0])


def test_simulated_adapter_stamps_by_its_own_clock() -> None:
    import can

    now = [100.0]
    a = SlcanAdapter(500_000, lambda m: None, clock=lambda: now[0], drift_ppm=50.0)
    a.feed(b"S6\rZ1\rO\r")
    assert a.feed(b"Z0\r") == b"\a"  # LAWICEL: only while closed
    msg = can.Message(arbitration_id=0x18A, is_extended_id=False, data=b"\x01\x02")
    now[0] = 161.0  # 61 s after the adapter started: wrapped, 50 ppm fast
    line = a.line_for(msg)
    assert line is not None and parse_line(line[:-1]).adapter_ms == 1003  # type: ignore[union-attr]
    line = a.line_for(msg, t_bus=100.5)  # a frame's bus time, as the simulator sends it later
    assert line is not None and parse_line(line[:-1]).adapter_ms == 500  # type: ignore[union-attr]


# ------------------------------------------------------------------------------ clocks
def test_counter_and_time_of_day_unwrap() -> None:
    rng = np.random.default_rng(5)
    n = 3000
    k = np.cumsum(rng.choice([1, 1, 1, 1, 2], n))  # drops
    t = 5000.0 + 0.01 * k + rng.exponential(0.0003, n)
    t[1000:1030] = t[1030] + np.arange(30) * 1e-5  # a 0.3 s stall, then a burst
    slots = counter_slots(k % 253, 253, t)
    assert np.array_equal(slots, k - k[0])
    tod = (86_390.0 + 0.01 * k) % 86_400.0  # a PASHR time of day across midnight
    c = unwrap(tod, 86_400.0, t)
    assert np.allclose(c - c[0], 0.01 * (k - k[0]), atol=1e-9)


@pytest.mark.parametrize("stall_s", [1.3, 1.8])
@pytest.mark.parametrize("with_adapter", [True, False])
def test_counter_wraps_across_a_host_stall_longer_than_half_its_period(
        stall_s: float, with_adapter: bool) -> None:
    """A 100 Hz NMEA 2000 SID wraps every 2.53 s. A host stall of 1.3 s (over half of that)
    holds the frames in the link's buffer; they are read in a burst after it, their receipt
    stamps late by up to the stall. Counted by the nearest wrap, the first of them went one
    wrap ahead (a campaign run's σ read 1.20° against 0.28°). The adapter's timestamps (taken
    as the frames arrive) count them right; without them the receipts, taken as one-sided
    (late, never early), do up to three quarters of a period."""
    rng = np.random.default_rng(7)
    n = 3000
    k = np.arange(n)
    true = 5000.0 + 0.01 * k
    t = true + rng.exponential(0.0003, n)
    i0 = 1200  # the host stalls from just after sample i0 - 1 for stall_s
    held = (true >= true[i0]) & (true < true[i0] + stall_s)
    t[held] = true[i0] + stall_s + np.arange(int(held.sum())) * 1e-5  # the burst
    t = np.maximum.accumulate(t)
    adapter = np.round(true - 4900.0, 3) if with_adapter else None  # 1 ms resolution
    slots = counter_slots(k % 253, 253, t, adapter)
    assert np.array_equal(slots, k)
    tb = instrument_timebase(t, counter=(k % 253).astype(float), driver="nmea2000",
                             adapter_time=adapter)
    assert tb.kind == "device"
    assert np.max(np.abs(tb.t - true - (tb.t[0] - true[0]))) < 2e-3


def _receipts(
    rng: np.random.Generator, n: int, stalls: list[tuple[int, float]], drop: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """True slots and instants of a 100 Hz device, its receipts — a small one-sided delay,
    and each stall (at sample i, for d s) holds every sample back until it ends — and which
    samples a stall held back."""
    k = np.flatnonzero(rng.random(n) >= drop)
    t_true = 2000.0 + 0.01 * 1.00004 * k
    recv = t_true + 0.0004 + rng.exponential(0.0002, k.size)
    held = np.zeros(k.size, dtype=bool)
    for i, d in stalls:
        a = t_true[min(i, k.size - 1)]
        late = (recv > a) & (recv < a + d)
        recv[late] = a + d + 2e-5 * np.arange(int(late.sum()))
        held |= late
    return k, t_true, recv, held


@PROPS
@example(seed=0, stalls=[(200, 0.5), (210, 0.5), (259, 0.5)], drop=0.02)  # one 1.09 s hold
@given(
    seed=st.integers(0, 2**32 - 1),
    stalls=st.lists(st.tuples(st.integers(200, 5800), st.floats(0.05, 0.5)), max_size=6),
    drop=st.sampled_from([0.0, 0.003, 0.02]),
)
def test_stalls_are_delays_not_drops(
    seed: int, stalls: list[tuple[int, float]], drop: float
) -> None:
    """However the stalls fall (0.05–0.5 s, up to six in a minute; overlapping ones make one
    hold of up to about 3 s) and whatever samples are
    really lost, the receipts' slots are the true ones (a sample lost during a stall cannot be
    placed by receipts alone: the burst fills the slots before the next sample on time, so
    only the samples a stall held back may sit a few slots off) and the fitted instants of the
    others are within 30 µs rms of the true ones (plus the constant receipt latency)."""
    rng = np.random.default_rng(seed)
    k, t_true, recv, held = _receipts(rng, 6000, stalls, drop)
    slots, clk = fit_slots(recv, one_sided=True)
    assert slots[-1] == k[-1] - k[0]  # every drop counted
    assert np.array_equal(slots[~held], (k - k[0])[~held])
    if drop == 0.0:
        assert np.array_equal(slots, k - k[0])
    err = (clk.at(slots) - t_true)[~held]
    assert float(np.sqrt(np.mean((err - err.mean()) ** 2))) < 30e-6
    assert 0.0 < float(err.mean()) < 0.001  # the on-time receipt latency, not the stalls'


@pytest.mark.parametrize("stalls", [
    [(200, 0.5), (210, 0.5), (259, 0.5)],  # overlapping: one 1.09 s hold
    [(200, 1.1)],
    [(3000, 2.0)],
    [(1000, 0.5), (1040, 0.5), (1090, 0.5), (1140, 0.5), (1190, 0.5), (1240, 0.5)],  # 2.9 s
])
@pytest.mark.parametrize("drop", [0.0, 0.02])
def test_a_long_hold_early_does_not_tilt_the_first_slots(
    stalls: list[tuple[int, float]], drop: float
) -> None:
    """A hold of 1–2 s: ~100–200 samples read in one burst 20 µs apart, late by up to the hold.
    The first slots' line was a plain least-squares fit through every stamp: a 1.09 s hold
    of 108 samples at 2 s into a minute tilted it by 9·10⁻⁴ of a step — 0.45 of a step over a
    block of the circular wander, which then unwrapped wrong, and the slots after the burst
    counted 33 too many. The line through the stamps on time leaves the burst out. Six
    overlapping stalls hold 2.9 s (290 samples): the lowest level ahead must look past the
    burst's end (``BURST_HORIZON_S``), or its first samples' level is taken for drops (84)."""
    rng = np.random.default_rng(0)
    k, t_true, recv, held = _receipts(rng, 6000, stalls, drop)
    slots, clk = fit_slots(recv, one_sided=True)
    assert slots[-1] == k[-1] - k[0]
    assert np.array_equal(slots[~held], (k - k[0])[~held])
    err = (clk.at(slots) - t_true)[~held]
    assert float(np.sqrt(np.mean((err - err.mean()) ** 2))) < 30e-6


def test_mostly_late_receipts_on_a_scheduler_tick() -> None:
    """A starved sender on 4 ms scheduler ticks: every receipt rounded up to a tick, 40 % of
    them late by up to 30 ms more, and bursts after 100–900 ms silences: still every slot."""
    rng = np.random.default_rng(11)
    n = 6000
    t_true = 3000.0 + 0.01 * np.arange(n)
    recv = np.ceil(t_true / 0.004) * 0.004 + rng.uniform(0, 2e-4, n)
    late = rng.random(n) < 0.4
    recv[late] += rng.uniform(0, 0.03, int(late.sum()))
    for i in rng.integers(100, n - 200, 8):
        recv[i : i + 90] = np.maximum(recv[i : i + 90], recv[i] + rng.uniform(0.1, 0.9))
    recv = np.maximum.accumulate(recv) + np.arange(n) * 1e-9  # received in order
    slots, clk = fit_slots(recv, one_sided=True)
    assert np.array_equal(slots, np.arange(n))
    assert clk.dt == pytest.approx(0.01, rel=1e-5)


def test_robust_clock_follows_a_rate_offset_and_wander() -> None:
    x = np.arange(100_000.0)  # 1000 s at 100 Hz: 80 ppm fast, wandering ±2 ms over 10 min
    t = 10.0 + 0.01 * (1 + 80e-6) * x + 0.002 * np.sin(2 * np.pi * x / 60_000)
    clk = robust_clock(x, t)
    assert np.max(np.abs(clk.at(x) - t)) < 5e-6
    assert clk.late == 0


# ------------------------------------------------------------------------------ recordings
def _meta(driver: str, stand: str = "modbus-tcp") -> dict[str, object]:
    return {"format": "benchctl-recording", "axes": ["roll"],
            "config": {"instrument": {"driver": driver}, "stand": {"driver": stand}}}


def _write(
    path: Path, driver: str, ms: Multisine, recv: np.ndarray, t_true: np.ndarray,
    *, adapter: np.ndarray | None = None, counter: np.ndarray | None = None,
    rtt_spike: bool = False,
) -> None:
    w = RecordingWriter(path, ("roll",), _meta(driver))
    status = StandStatus(True, True, True, False, False, False)
    tr = np.arange(t_true[0] - 1.0, t_true[-1] + 1.0, 0.01)
    # the reference at every instant at once (elementwise: each value the same as one instant's
    # alone, without recomputing the multisine's lines per sample)
    xr = ms.reference(tr)
    for i, t in enumerate(tr):
        rtt = 0.5 if (rtt_spike and i % 997 == 500) else 0.0004
        stamp = t + (0.25 if rtt > 0.1 else 0.0)  # a stalled poll: its midpoint far off
        w.write_stand(StandSample(stamp, rtt, {"roll": float(xr[i])},
                                  {"roll": 0.0}, {"roll": 0.0}, status))
    y = ms.through(first_order(0.05), t_true)
    for i in range(len(recv)):
        w.write_instrument(InstrumentSample(
            float(recv[i]), {"roll": float(y[i])},
            counter=None if counter is None else int(counter[i]),
            adapter_time_s=None if adapter is None else float(adapter[i])))
    w.close("done", "test")


MS = Multisine(period_s=50.0, f_lo=0.05, f_hi=0.6, rms_deg=3.0)


def _truth(t_true: np.ndarray, latency: float) -> float:
    """σ with the device's true instants, late by the constant receipt latency on time (which
    stays part of the measured delay, as with receipt stamps: it cannot be observed)."""
    y = MS.through(first_order(0.05), t_true)
    tr = np.arange(t_true[0] - 1.0, t_true[-1] + 1.0, 0.01)
    return analyze(tr, MS.reference(tr), t_true + latency, y).sigma


@pytest.mark.parametrize("kind", ["adapter", "device", "fitted"])
def test_recording_time_bases_undo_stalls(tmp_path: Path, kind: str) -> None:
    rng = np.random.default_rng(2)
    stalls = [(700, 0.3), (1900, 0.12), (3100, 0.25), (4400, 0.2), (5200, 0.1)]
    k, t_true, recv, _ = _receipts(rng, 6000, stalls, 0.0)
    adapter = 17.0 + (t_true - t_true[0]) * (1 + 30e-6) + rng.uniform(0, 1e-3, k.size)
    adapter = np.floor(adapter * 1000) / 1000  # 1 ms, as the adapter sends it
    driver = "nmea2000" if kind == "device" else "canopen"
    _write(tmp_path / "r", driver, MS, recv, t_true, rtt_spike=True,
           adapter=adapter if kind == "adapter" else None,
           counter=k % 253 if kind == "device" else None)
    rec = load_recording(tmp_path / "r")
    tr, xr, td, yd = rec.pair("roll")
    assert label_of(td) is not None and label_of(td)[0] == kind  # type: ignore[index]
    r = analyze(tr, xr, td, yd)
    assert r.timing["device_timebase"] == kind
    assert r.timing["reference_timebase"] == "midpoint"
    n_stand = rec.streams["stand"]["t_host"].size
    assert tr.info["dropped"] == len(range(500, n_stand, 997))  # type: ignore[attr-defined]
    assert r.gaps["device"]["missing_samples"] == int(k[-1] - k[0] + 1 - k.size)
    latency = float(np.median(np.asarray(td) - t_true))
    assert 0.0004 < latency < 0.0007  # 0.4 ms + the median of the receipts' jitter
    assert r.sigma == pytest.approx(_truth(t_true, latency), rel=1e-3)
    receipt = analyze(*rec.pair("roll", timebase="receipt"))
    assert receipt.sigma > 1.03 * r.sigma  # the bursts' instants, as they were
    assert any("timing:" in w for w in receipt.warnings)


def test_recording_asking_for_a_time_base_it_lacks(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    _, t_true, recv, _ = _receipts(rng, 2000, [], 0.0)
    _write(tmp_path / "r", "canopen", MS, recv, t_true)
    rec = load_recording(tmp_path / "r")
    from benchctl.errors import DataError

    with pytest.raises(DataError, match="no usable adapter time base"):
        rec.pair("roll", timebase="adapter")


def test_instrument_timebase_falls_back_when_a_clock_is_unusable() -> None:
    rng = np.random.default_rng(6)
    k, _, recv, _ = _receipts(rng, 3000, [(1500, 0.2)], 0.0)
    dev = np.full(k.size, np.nan)
    tb = instrument_timebase(recv, device_time=dev, driver="nmea0183")
    assert tb.kind == "fitted" and np.array_equal(tb.slots, k - k[0])  # type: ignore[arg-type]
    j1939 = recv - 0.01  # J1939: receipt minus the latency byte, no clock
    assert instrument_timebase(recv, device_time=j1939, driver="j1939").kind == "fitted"
    pashr = 43_200.0 + 0.01 * k
    assert instrument_timebase(recv, device_time=pashr, driver="nmea0183").kind == "device"


def test_stand_stamp_error_from_the_round_trips() -> None:
    rng = np.random.default_rng(1)
    rtt = 0.0005 + rng.exponential(0.0002, 5000)
    err = stamp_error(rtt)
    assert err == pytest.approx(0.5 * float(np.sqrt(np.mean((rtt - np.median(rtt)) ** 2))))
    assert 0 < err < 0.0005
    assert stamp_error(rtt, "request_end") == pytest.approx(err / 5)
    assert math.isnan(stamp_error([]))


# ------------------------------------------------------------------------------ the analysis
def test_jitter_on_both_streams_does_not_bias_sigma() -> None:
    """0.027° instrument, 5°/s rms roll rate, 100 Hz, 1 ms rms jitter on both streams' stamps:
    with fitted time bases σ changes by less than 0.2 %; as given it is inflated by about the
    timing contribution the result states, and warned about."""
    tr, x, t, y, jr, jd = jittered_streams(1e-3)
    exact = analyze(tr, x, t, y, lines="off")
    assert exact.sigma == pytest.approx(0.027, rel=1e-3)
    assert exact.timing["reference_rate_rms"] == pytest.approx(5.0, rel=0.01)
    fitted = analyze(jr, x, jd, y, timebase="fitted", reference_timebase="fitted", lines="off")
    assert abs(fitted.sigma / exact.sigma - 1) < 0.002
    assert fitted.timing["device_timebase"] == fitted.timing["reference_timebase"] == "fitted"
    assert fitted.timing["timing_share"] < 0.001
    assert not any("timing:" in w for w in fitted.warnings)
    given_ = analyze(jr, x, jd, y, lines="off", timebase="given", reference_timebase="given")
    added = given_.variance - exact.variance
    assert added / exact.variance > 0.05  # 25·(1e-6 + 1e-6)/0.027² ≈ 6.9 %
    assert given_.timing["timing_variance"] == pytest.approx(added, rel=0.25)
    assert any("timing:" in w for w in given_.warnings)


def test_labelled_instants_keep_their_label_through_cropping() -> None:
    t = Instants(np.arange(100.0), "adapter", 1e-5, {"late": 3})
    sub = t[t > 10]
    assert label_of(sub) == ("adapter", 1e-5, {"late": 3})
    assert label_of(np.asarray(sub)) is None


# ------------------------------------------------------------------------------ the stand's stamps
def test_rtu_stamp_is_the_end_of_the_request() -> None:
    link = rtu_link("/dev/null-nothing", baudrate=115200, parity="N", stopbits=1)
    assert link.byte_time_s == pytest.approx(10 / 115200)
    link._trace(True, bytes(8))  # an FC3 request, handed to the port now
    t_send = link._sent.last[0]
    assert link.sample_stamp(t_send - 1e-4, t_send + 0.01) == pytest.approx(
        t_send + 8 * 10 / 115200)
    assert link.sample_stamp(0.0, 1.0) == 0.5  # a clock the send was not seen on: midpoint
    even = rtu_link("/dev/null-nothing", baudrate=9600, parity="E", stopbits=1)
    assert even.byte_time_s == pytest.approx(11 / 9600)
    tcp = tcp_link("127.0.0.1", 1)
    tcp._trace(True, bytes(12))
    assert tcp.sample_stamp(1.0, 2.0) == 1.5


def test_cli_fits_both_time_bases(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``benchctl analyze --reference … --device … --timebase fitted --reference-timebase
    fitted``: both streams' jittery stamps fitted; the JSON states the time bases and the
    timing contribution; as given, the summary warns."""
    import json

    from benchctl.cli import main

    _, x, _, y, jr, jd = jittered_streams(1e-3)
    np.savetxt(tmp_path / "ref.csv", np.column_stack([jr, x]), delimiter=",",
               header="time,angle", comments="", fmt="%.12f")
    np.savetxt(tmp_path / "dev.csv", np.column_stack([jd, y]), delimiter=",",
               header="time,angle", comments="", fmt="%.12f")
    args = ["analyze", "--reference", str(tmp_path / "ref.csv"), "--device",
            str(tmp_path / "dev.csv"), "--lines", "off"]
    assert main([*args, "--timebase", "fitted", "--reference-timebase", "fitted", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["timing"]["device_timebase"] == out["timing"]["reference_timebase"] == "fitted"
    assert out["sigma"] == pytest.approx(0.027, rel=0.002)
    assert out["timing"]["timing_share"] < 0.001
    assert main([*args, "--timebase", "given", "--reference-timebase", "given"]) == 0
    text = capsys.readouterr().out
    assert "timing: device given" in text and "warning: timing:" in text
    assert main([*args, "--json"]) == 0  # no option: the jitter is seen, both fitted
    out = json.loads(capsys.readouterr().out)
    assert out["timing"]["device_timebase"] == out["timing"]["reference_timebase"] == "fitted"
    assert out["sigma"] == pytest.approx(0.027, rel=0.002)


def test_stamps_on_a_grid_take_the_short_way_to_the_same_slots() -> None:
    """Stamps that step evenly (a CSV's times, a fitted clock) skip the drop-and-burst search:
    the same slots and clock as the search finds, one robust fit instead of several."""
    from benchctl.analysis import clockfit as tb

    grid = 1000.0 + np.arange(20_000) * 0.01
    assert tb._uniform(grid)
    k, clk = tb.fit_slots(grid)
    k_full, clk_full = tb.refine_slots(grid, tb.first_slots(grid))
    assert np.array_equal(k, k_full) and np.array_equal(k, np.arange(grid.size))
    assert (clk.t0, clk.dt, clk.error_rms) == (clk_full.t0, clk_full.dt, clk_full.error_rms)
    # one dropped sample or 1 % jitter: not a grid, the full search runs (and finds the drop)
    dropped = np.delete(grid, 500)
    assert not tb._uniform(dropped)
    k, _clk = tb.fit_slots(dropped)
    assert k[500] - k[499] == 2
    rng = np.random.default_rng(3)
    assert not tb._uniform(grid + rng.normal(0.0, 1e-4, grid.size))


@settings(max_examples=60)
@given(
    n=st.integers(min_value=16, max_value=400),
    nb=st.integers(min_value=2, max_value=8),
    q=st.sampled_from([0.5, 0.1, 0.05]),
    drop=st.floats(min_value=0.0, max_value=0.6),
    seed=st.integers(min_value=0, max_value=2**31 - 1),
)
def test_block_levels_are_the_sorted_blocks_quantiles(
    n: int, nb: int, q: float, drop: float, seed: int
) -> None:
    """Each block's level is the ``q`` quantile (linear between order statistics) of its kept
    residuals, exactly as a sort of every block gives it, whichever blocks are whole (their
    order statistics come from a partition) and whichever lose samples (a sort)."""
    from benchctl.analysis.clockfit import _block_levels

    rng = np.random.default_rng(seed)
    x = np.arange(n, dtype=float)
    r = rng.normal(size=n)
    r[rng.random(n) < 0.1] = 1.0  # ties
    keep = rng.random(n) >= drop
    size = -(-n // nb)
    kx, kl = _block_levels(x, r, keep, nb, q)
    want_x, want_l = [], []
    for b in range(nb):
        sl = slice(b * size, min(n, (b + 1) * size))
        kept = np.sort(r[sl][keep[sl]])
        if kept.size < max(8, size // 10) or sl.start >= n:
            continue
        pos = q * (kept.size - 1)
        lo = math.floor(pos)
        hi = min(lo + 1, kept.size - 1)
        want_l.append(kept[lo] + (pos - lo) * (kept[hi] - kept[lo]))
        want_x.append(float(np.mean(x[sl])))
    assert np.array_equal(kl, np.array(want_l))
    np.testing.assert_allclose(kx, want_x, rtol=0, atol=1e-9)
