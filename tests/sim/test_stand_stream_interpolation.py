"""The simulated drive's stream interpolation (``sim.stand.stream_interpolation``).

A stand in stream mode is sent one setpoint per period. A drive that steps to each one makes
its servo follow a staircase: with this servo (8 Hz, ζ 0.8) each 20 ms step of a ramp at a few
degrees per second asks for ω_n²·Δx, far beyond the limits the ramp itself keeps. A drive in
cyclic synchronous position mode moves linearly from one setpoint to the next over the
interval between them: the same ramp moves the stand within its limits. The product's own
ramp to zero, from a stand left at 8° (simulated time, the real Modbus driver).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from live_bench import LIMITS, live_bench

from benchctl.clock.virtual import VirtualClock
from benchctl.devices.modbus.stand import open_stand
from benchctl.harmonics import HarmonicTable


def _ramp_peaks(tmp_path: Path, vclock: VirtualClock, interpolate: bool) -> dict[str, float]:
    sim = {"stream_interpolation": interpolate, "accel_limit_deg_s2": 5000.0,
           "rate_limit_deg_s": 500.0}
    with live_bench(tmp_path, sim_stand=sim, clock=vclock,
                    stand={"setpoint_rate_hz": 50}) as bench:
        bench.stand.place({"roll": 8.0, "pitch": -5.0})
        stand = open_stand(bench.cfg.stand, clock=vclock)
        try:
            stand.connect()
            stand.enable()
            bench.stand.peaks(reset=True)
            stand.ramp_to_zero()
            s = stand.read_sample()
            assert max(abs(v) for v in s.angle_deg.values()) <= bench.cfg.stand.zero_tolerance_deg
        finally:
            stand.close()
        peaks = bench.stand.peaks()
    return {k: max(p[k] for p in peaks.values()) for k in ("rate_deg_s", "accel_deg_s2")}


def test_an_interpolating_drive_ramps_within_the_limits(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    p = _ramp_peaks(tmp_path, vclock, interpolate=True)
    assert p["rate_deg_s"] <= LIMITS["rate_deg_s"]
    assert p["accel_deg_s2"] <= LIMITS["accel_deg_s2"]


def test_a_stepping_drive_follows_the_staircase_beyond_them(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    p = _ramp_peaks(tmp_path, vclock, interpolate=False)
    assert p["accel_deg_s2"] > 2 * LIMITS["accel_deg_s2"]


@pytest.mark.parametrize("interpolate", [True, False])
def test_the_drive_ends_on_the_last_setpoint(
    tmp_path: Path, vclock: VirtualClock, interpolate: bool
) -> None:
    with live_bench(tmp_path, sim_stand={"stream_interpolation": interpolate},
                    clock=vclock) as bench:
        stand = open_stand(bench.cfg.stand, clock=vclock)
        try:
            stand.connect()
            stand.enable()
            for k in range(1, 101):  # 0 → 1° in 100 setpoints at 1°/s, then held
                stand.heartbeat()
                stand.send_setpoint({"roll": 0.01 * k, "pitch": 0.0})
                vclock.sleep(0.01)
            vclock.sleep(1.0)
            stand.heartbeat()
            assert stand.read_sample().angle_deg["roll"] == pytest.approx(1.0, abs=2e-3)
        finally:
            stand.close()


@pytest.mark.parametrize("mode", ["table", "stream"])
def test_the_ramp_after_a_stop_waits_for_the_stand_to_brake(
    tmp_path: Path, vclock: VirtualClock, mode: str
) -> None:
    """A stop (the shutdown's first step) brakes the stand within its limits, and it takes no
    setpoint until at rest: a ramp planned from the braking state would meet the stand where
    it stopped with a step (campaign seed 412: 138 deg/s² against 60). The ramp to zero waits
    for rest, then plans from there."""
    sim = {"stream_interpolation": True, "accel_limit_deg_s2": 5000.0,
           "rate_limit_deg_s": 500.0}
    with live_bench(tmp_path, sim_stand=sim, clock=vclock) as bench:
        stand = open_stand(bench.cfg.stand, clock=vclock)
        try:
            stand.connect()
            stand.enable()
            if mode == "table":  # 4° at 0.5 Hz: 12.6°/s, 39°/s² (the limits: 40, 200)
                tab = HarmonicTable(np.array([0.5]), np.array([4.0]), np.array([0.0]),
                                    duration_s=60.0, fade_in_s=2.0, fade_out_s=2.0)
                stand.upload_table({"roll": tab})
                stand.start_table()
            else:  # a stream up to 10°/s at 100°/s²
                x = v = 0.0
                for _ in range(80):
                    v = min(v + 1.0, 10.0)
                    x += v * 0.01
                    stand.heartbeat()
                    stand.send_setpoint({"roll": x, "pitch": 0.0})
                    vclock.sleep(0.01)
            t_end = vclock.monotonic() + (3.3 if mode == "table" else 0.0)
            while vclock.monotonic() < t_end:
                stand.heartbeat()
                vclock.sleep(0.05)
            s = stand.read_sample()
            assert abs(s.rate_deg_s["roll"]) > 5.0  # moving fast when it is told to stop
            if mode == "table":
                assert bench.stand.peaks(following="stream")["roll"]["rate_deg_s"] == 0.0
                assert bench.stand.peaks(following="profile")["roll"]["rate_deg_s"] > 5.0
            bench.stand.peaks(reset=True)
            stand.stop()
            stand.ramp_to_zero()
            assert abs(stand.read_sample().angle_deg["roll"]) <= bench.cfg.stand.zero_tolerance_deg
        finally:
            stand.close()
        p = bench.stand.peaks()["roll"]
        if mode == "stream":  # the peaks of what it played by itself and what it was sent
            assert bench.stand.peaks(following="profile")["roll"]["accel_deg_s2"] == 0.0
    assert p["rate_deg_s"] <= LIMITS["rate_deg_s"]
    assert p["accel_deg_s2"] <= LIMITS["accel_deg_s2"]
