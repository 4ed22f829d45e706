"""The stand's own clock dates the reference, where the stand's register map offers one.

- ``analysis.timebase.stand_clock``: a wrapping 10 µs clock at its own rate and offset, read in
  exchanges whose windows are late by random amounts (and sometimes by a stall), gives the
  host instants of the states to within the windows' tightest bounds; gaps longer than the
  wrap are counted right; windows that contradict the clock are found out.
- the register map's ``status.sample_time`` (optional; the generic map has it at 203);
- the simulated stand latches its clock with the state, inside each exchange's window (TCP:
  request sent to reply received; RTU: the end of the request on the wire to the start of the
  reply), on a real protocol exchange (the driver's pymodbus client and the simulator's wire, on
  simulated time over an in-process link that carries each framing's bytes);
- a recording with the stand's clock is dated by it (``reference_timebase`` ``stand``), every
  sample kept, a long round trip included; asked for the stamps, it gives them.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from live_bench import ROOT

from benchctl.analysis import analyze
from benchctl.analysis.timebase import stand_clock
from benchctl.channels import free_name, register, unregister
from benchctl.clock.virtual import VirtualClock
from benchctl.config import SimStandConfig, StandConfig, StandLimits
from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
from benchctl.devices.modbus.regmap_load import load_register_map, parse_register_map
from benchctl.devices.modbus.stand import open_stand
from benchctl.errors import ConfigError
from benchctl.recording import RecordingWriter, load_recording
from benchctl.sim.stand import SimStand

MAP = ROOT / "drivers/stand_generic.yaml"
WRAP = 0.65536
#: the in-process link's latency each way: for TCP about a loopback socket's (50 µs; the
#: windows then as narrow as over a real socket: a latch at the last physics tick instead of the
#: request's instant, or 0.1 ms off it, falls outside them); RTU the bench's default (0.5 ms),
#: its frames' byte times besides
LATENCY_S = {"tcp": 5e-5, "rtu": 0.0005}


def _clock(t: np.ndarray, offset: float, rate: float) -> np.ndarray:
    """A stand clock of 10 µs ticks wrapping at WRAP, at ``rate`` and ``offset`` to the host."""
    c = (t - offset) * rate
    return np.round((c % WRAP) / 1e-5) * 1e-5 % WRAP


def _exchanges(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True latch instants at 100 Hz with two gaps longer than the wrap, and each exchange's
    window: the request went out 0.1–3 ms before, the reply came 0.1–3 ms after (sometimes a
    stall of 0.3 s on either side)."""
    t = 50.0 + 0.01 * np.arange(n, dtype=float)
    t[n // 3 :] += 1.7  # gaps of 1.7 s and 3.1 s: more than two and four wraps
    t[2 * n // 3 :] += 3.1
    before = rng.uniform(1e-4, 3e-3, n) + np.where(rng.random(n) < 0.02, 0.3, 0.0)
    after = rng.uniform(1e-4, 3e-3, n) + np.where(rng.random(n) < 0.02, 0.3, 0.0)
    return t, t - before, t + after


def test_stand_clock_recovers_the_instants_across_wraps_and_stalls() -> None:
    rng = np.random.default_rng(11)
    t, lo, hi = _exchanges(rng, 6000)
    ts = _clock(t, offset=12.345, rate=1 + 40e-6)  # a stand clock 40 ppm fast
    got, err, info = stand_clock(ts, WRAP, lo, hi)
    assert info["consistent"]
    assert info["rate"] == pytest.approx(1 / (1 + 40e-6), rel=2e-6)
    # the windows' tightest bounds are 0.1 ms each side: the offset is found within them,
    # whatever the stalls and the wraps (10 µs ticks: ±5 µs more)
    assert np.max(np.abs(got - t)) < 1.2e-4
    assert err < 1e-4  # the stated error: the interval the windows leave, over √12
    # the earliest end instead: the latest of the requests' ends, 0.1 ms before the states
    early, _, _ = stand_clock(ts, WRAP, lo, hi, anchor="earliest")
    assert np.median(early - t) == pytest.approx(-1e-4, abs=5e-5)


def test_windows_that_contradict_the_clock_are_found_out() -> None:
    rng = np.random.default_rng(12)
    t, lo, hi = _exchanges(rng, 3000)
    ts = _clock(t, offset=3.0, rate=1.0)
    ts[1000:] = _clock(t[1000:] + 0.05, offset=3.0, rate=1.0)  # a clock that jumps 50 ms
    _, _, info = stand_clock(ts, WRAP, lo, hi)
    assert not info["consistent"]


def test_register_map_sample_time() -> None:
    m = load_register_map(MAP)
    assert m.sample_time is not None and m.sample_time.address == 203
    assert m.sample_time_wrap_s == pytest.approx(WRAP)
    assert m.feedback_span() == (200, 26)  # inside the block read every cycle
    raw: dict[str, Any] = yaml.safe_load(MAP.read_text())
    bad = copy.deepcopy(raw)
    bad["status"]["sample_time"] = {"address": 203, "type": "int16", "scale": 1e-5}
    with pytest.raises(ConfigError, match=r"status\.sample_time"):
        parse_register_map(bad, MAP)
    none = copy.deepcopy(raw)
    del none["status"]["sample_time"]
    m2 = parse_register_map(none, MAP)
    assert m2.sample_time is None and math.isnan(m2.sample_time_wrap_s)


@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_simulated_stand_latches_its_clock_inside_each_window(
    transport: str, vclock: VirtualClock
) -> None:
    """On simulated time over an in-process link carrying Modbus TCP (MBAP) or RTU frames:
    the driver's window (TCP: request sent to reply received; RTU: its frames' wire time left
    out) holds the instant the simulator latched its clock (``LATENCY_S``)."""
    clock = vclock
    limits = StandLimits(angle_deg=20.0, rate_deg_s=30.0, accel_deg_s2=200.0)
    with SimStand(SimStandConfig(watchdog_s=3.0), limits=limits, register_map=MAP,
                  transport="channel", framing=transport,  # type: ignore[arg-type]
                  channel_latency_s=LATENCY_S[transport], clock=clock) as sim:
        common = {"limits": limits, "register_map": MAP, "timeout_s": 2.0, "retries": 0}
        assert sim.client_endpoint is not None
        url = register(free_name("sim-stand"), sim.client_endpoint)
        where = {"serial_port": url} if transport == "rtu" else {"host": url}
        cfg = StandConfig.model_validate({"driver": f"modbus-{transport}", **where, **common})
        stand = open_stand(cfg, clock=clock)
        ident = stand.connect()
        try:
            assert float(ident.extra["sample_time_wrap_s"]) == pytest.approx(WRAP)
            rows = []
            for _ in range(200):
                s = stand.read_sample()
                assert s.t_stand is not None and s.t_window is not None
                rows.append((s.t_window[0], s.t_window[1], s.t_stand, s.rtt_s))
                clock.sleep(0.005)
        finally:
            stand.close()
            unregister(url)
    r = np.array(rows)
    # the simulator's clock counts from its start on the run's clock
    base = sim._t0
    wraps = np.rint(((0.5 * (r[:, 0] + r[:, 1]) - base) - r[:, 2]) / WRAP)
    latch = base + r[:, 2] + wraps * WRAP
    tick = 1e-5  # the clock's resolution
    inside = (r[:, 0] - tick <= latch) & (latch <= r[:, 1] + tick)
    assert inside.mean() >= 0.99, (r[~inside][:5], latch[~inside][:5])
    if transport == "rtu":  # the window leaves both frames' wire time out (115200 Bd)
        assert np.median(r[:, 1] - r[:, 0]) < np.median(r[:, 3])


def _write(path: Path, t: np.ndarray, lo: np.ndarray, hi: np.ndarray,
           ts: np.ndarray | None) -> None:
    meta = {"config": {"stand": {"driver": "modbus-tcp"}, "instrument": {"driver": "canopen"}},
            "devices": {"stand": {"extra": {"sample_time_wrap_s": repr(WRAP)}}}}
    w = RecordingWriter(path, ("roll",), meta)
    status = StandStatus(True, True, True, False, False, False)
    x = 3.0 * np.sin(2 * np.pi * 0.2 * t) + 1.0 * np.sin(2 * np.pi * 0.45 * t + 1.0)
    for i in range(t.size):
        stamp = 0.5 * (lo[i] + hi[i])
        w.write_stand(StandSample(
            float(stamp), float(hi[i] - lo[i]), {"roll": float(x[i])}, {"roll": 0.0},
            {"roll": 0.0}, status, t_stand=None if ts is None else float(ts[i]),
            t_window=(float(lo[i]), float(hi[i]))))
    td = t[10:-10:2]
    y = 3.0 * np.sin(2 * np.pi * 0.2 * (td - 0.02)) + 1.0 * np.sin(
        2 * np.pi * 0.45 * (td - 0.02) + 1.0)
    for i in range(td.size):
        w.write_instrument(InstrumentSample(float(td[i]) + 2e-4, {"roll": float(y[i])},
                                            adapter_time_s=float(td[i] - 40.0)))
    w.close("done", "test")


def test_recording_dated_by_the_stand_clock(tmp_path: Path) -> None:
    rng = np.random.default_rng(13)
    n = 4000
    t = 10.0 + 0.01 * np.arange(n, dtype=float)
    before = rng.uniform(1e-4, 4e-3, n)
    after = rng.uniform(1e-4, 1e-3, n)  # replies quicker than requests: stamps sit early
    before[::500] += 0.4  # stalled polls: far off midpoints, long round trips
    lo, hi = t - before, t + after
    ts = _clock(t, offset=2.0, rate=1.0)
    _write(tmp_path / "clock", t, lo, hi, ts)
    _write(tmp_path / "stamps", t, lo, hi, None)
    rec = load_recording(tmp_path / "clock")
    tr, xr, td, yd = rec.pair("roll")
    assert tr.timebase == "stand"  # type: ignore[attr-defined]
    assert tr.size == n  # every sample: the stalled polls are dated by the stand's clock
    assert np.max(np.abs(np.asarray(tr) - t)) < 1.5e-4
    by_clock = analyze(tr, xr, td, yd, lines="off")
    assert by_clock.timing["reference_timebase"] == "stand"
    assert by_clock.delay == pytest.approx(0.02, abs=3e-4)
    tr2, _, _, _ = rec.pair("roll", reference_timebase="stamp")
    assert tr2.timebase == "midpoint"  # type: ignore[attr-defined]
    # without the stand's clock: the stamps, their bias (1.5 ms early here) in the delay
    st = load_recording(tmp_path / "stamps")
    assert st.pair("roll")[0].timebase == "midpoint"  # type: ignore[attr-defined]
    by_stamps = analyze(*st.pair("roll"), lines="off")
    assert abs(by_stamps.delay - 0.02) > 5e-4
    from benchctl.errors import DataError

    with pytest.raises(DataError, match="no usable clock"):
        st.pair("roll", reference_timebase="stand")


def test_rtu_windows_are_anchored_at_the_request_end() -> None:
    """RTU: the stand takes its state as the request is complete — at the window's start,
    later only when the request reached it late (a host's or an adapter's send latency, up to
    1 ms here); the window runs on through the stand's turnaround (1.6 ms). Anchored at the
    window's middle the instants were 0.8 ms late, and moved with the send latency (seed 3012
    of the safety campaign: σ 0.3 % off its undisturbed twin); at the start, within 0.05 ms."""
    rng = np.random.default_rng(13)
    n = 4000
    send = 20.0 + 0.02 * np.arange(n)  # the host's end of the request on the wire
    t = send + rng.uniform(0.0, 1e-3, n)  # the request complete at the stand
    lo, hi = send, t + 1.6e-3
    ts = _clock(t, offset=7.0, rate=1.0)
    mid, _, _ = stand_clock(ts, WRAP, lo, hi)
    early, _, _ = stand_clock(ts, WRAP, lo, hi, anchor="earliest")
    assert np.median(mid - t) > 5e-4
    assert abs(float(np.median(early - t))) < 5e-5

