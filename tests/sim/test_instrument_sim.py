"""Back-to-back: each instrument driver against the simulated instrument.

On simulated time (the ``vclock`` fixture): the simulator and the driver over an in-process link
(``simchan://``: pyserial, python-can's slcan bus and the NMEA reader open it as they open a
pty), the same code on both ends, its rates and timeouts exact. Over a real pseudo-terminal
(``realtime``): a dropped link, which closes the pty and its symlink and leaves no descriptor
open (the drivers over real ptys at their full rates: the end-to-end runs of
tests/e2e/test_run_e2e.py)."""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from repo_paths import ROOT

from benchctl.channels import free_name, unregister
from benchctl.clock import REAL, Clock
from benchctl.clock.virtual import VirtualClock
from benchctl.config import InstrumentConfig, SimInstrumentConfig
from benchctl.devices.base import AngleSensor, InstrumentSample
from benchctl.devices.instrument import open_instrument
from benchctl.errors import ConfigError, ConnectionLost, DeviceTimeout
from benchctl.sim.instrument import SimInstrument

DRIVERS = ROOT / "drivers"

ROLL_OFFSET, ROLL_AMP, ROLL_F = 2.0, 5.0, 0.5
PITCH = -3.0


class SineRoll:
    """Roll 2 + 5 sin(2π 0.5 t) deg, pitch −3 deg: a closed-form stand motion."""

    def true_angles(self, t: float) -> dict[str, float]:
        return {"roll": ROLL_OFFSET + ROLL_AMP * math.sin(2 * math.pi * ROLL_F * t),
                "pitch": PITCH}


class Static:
    def true_angles(self, t: float) -> dict[str, float]:
        return {"roll": 1.25, "pitch": -0.5}


def instrument_cfg(driver: str, **kw: Any) -> InstrumentConfig:
    base: dict[str, Any] = {"driver": driver}
    if driver == "nmea0183":
        base["serial_port"] = "set-by-the-simulator"
    else:
        base.update(interface="slcan", channel="set-by-the-simulator")
    if driver == "canopen":
        base["eds"] = DRIVERS / "cia410_inclinometer.eds"
    if driver == "j1939":
        base["dbc"] = DRIVERS / "j1939_slope.dbc"
    if driver == "nmea2000":
        base["dbc"] = DRIVERS / "nmea2000_attitude.dbc"
    base.update(kw)
    return InstrumentConfig(**base)


class Collector:
    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.samples: list[InstrumentSample] = []
        self.errors: list[BaseException] = []

    def wait(self, cond: Callable[[], bool], timeout: float = 5.0) -> float:
        """Wait on the collector's clock until ``cond()``; the seconds it took."""
        clock = self.clock
        t0 = clock.monotonic()
        while not cond():
            if clock.monotonic() - t0 > timeout:
                raise AssertionError(f"not within {timeout} s; errors {self.errors}")
            clock.sleep(0.01)
        return clock.monotonic() - t0


def simulator(model: SimInstrumentConfig, cfg: InstrumentConfig, motion: Any, clock: Clock,
              link_path: Path | None = None) -> SimInstrument:
    """The simulated instrument: on a virtual ``clock`` over an in-process link, else a pty."""
    return SimInstrument(model, cfg, motion, link_path=link_path, clock=clock,
                         channel=free_name("sim-instrument") if clock.virtual else None)


def stop(sim: SimInstrument) -> None:
    sim.stop()
    if sim.channel_name is not None:
        unregister(sim.channel_name)


@contextmanager
def back_to_back(
    driver: str, model: SimInstrumentConfig, motion: Any = None, *, clock: Clock,
    log: Path | None = None, **kw: Any,
) -> Iterator[tuple[SimInstrument, AngleSensor, Collector]]:
    sim = simulator(model, instrument_cfg(driver, **kw), motion or SineRoll(), clock)
    sim.inject("silent")  # pyserial flushes input on open: start counting from a clean line
    sim.start()
    dev = None
    try:
        dev = open_instrument(sim.instrument_config(), can_log_path=log, clock=clock)
        sim.clear_faults()
        dev.connect()
        col = Collector(clock)
        dev.start(col.samples.append, col.errors.append)
        yield sim, dev, col
    finally:
        if dev is not None:
            dev.close()
        stop(sim)
    assert sim.error is None


def drain(sim: SimInstrument, dev: AngleSensor, col: Collector) -> None:
    """Silence the simulator and wait until the driver has seen every frame it sent: the
    counts equal (the simulator counts a frame just after writing it, so on a loaded machine
    the driver may read it first: "at least as many" could end the wait one count early)."""
    sim.inject("silent")
    col.wait(lambda: dev.stats.good + dev.stats.bad_total == sim.counts["sent"])


@pytest.mark.parametrize(
    ("driver", "extra"),
    [("canopen", {}), ("j1939", {}), ("nmea2000", {}), ("nmea0183", {}),
     ("nmea0183", {"sentence": "XDR"})],
)
def test_rate_gain_bias_noise(driver: str, extra: dict, vclock: VirtualClock) -> None:
    gain, bias, noise, rate = 0.97, 0.3, 0.05, 100.0
    model = SimInstrumentConfig(gain=gain, bias_deg=bias, noise_deg=noise, latency_s=0.01,
                                rate_hz=rate, seed=11)
    with back_to_back(driver, model, clock=vclock, **extra) as (sim, dev, col):
        col.wait(lambda: len(col.samples) >= 250)
        drain(sim, dev, col)
        s = list(col.samples)
        assert col.errors == []
        assert dev.stats.bad == {}
        assert dev.stats.good == sim.counts["sent"]  # no loss
        skipped = sim.counts["skipped"]
    t = np.array([x.t_host for x in s])
    roll = np.array([x.angle_deg["roll"] for x in s])
    pitch = np.array([x.angle_deg["pitch"] for x in s])
    # rate: the simulator's own clock, seen through host receipt times (10 %: a stall of the
    # shared machine at either end of ≈2.5 s shifts it by a few %)
    assert (len(t) - 1) / (t[-1] - t[0]) == pytest.approx(rate, rel=0.10)
    # pitch is static: mean = g·(−3) + b, spread = noise ⊕ wire resolution
    expected_var = sim.model.expected_error_variance([], [], resolution_deg=sim.wire_resolution_deg)
    n = len(pitch)
    assert np.std(pitch, ddof=1) == pytest.approx(math.sqrt(expected_var), rel=0.2)  # SE ≈ 4.5 %
    # roll: amplitude and offset by least squares on the instrument's own output grid (every
    # sample arrived, none skipped: sample i was taken at t_first + i / rate_hz); receipt times
    # would carry the shared machine's stalls into the fit
    assert skipped == 0
    tg = np.arange(n) / rate
    w = 2 * math.pi * ROLL_F
    x = np.c_[np.sin(w * tg), np.cos(w * tg), np.ones_like(tg)]
    (a, b, c), *_ = np.linalg.lstsq(x, roll, rcond=None)
    se = noise * math.sqrt(2 / n)  # LS standard error of a sine coefficient
    assert math.hypot(a, b) / ROLL_AMP == pytest.approx(gain, abs=5 * se / ROLL_AMP + 1e-3)
    g_static = (c - np.mean(pitch)) / (ROLL_OFFSET - PITCH)
    assert g_static == pytest.approx(gain, abs=0.01)
    assert c - gain * ROLL_OFFSET == pytest.approx(bias, abs=0.02)
    if driver == "nmea2000":
        sid = np.array([x.counter for x in s])
        assert np.all(np.diff(sid) % 253 == 1)  # consecutive sequence ids: nothing lost
    if driver == "j1939":
        lat = np.array([x.t_host - x.device_time_s for x in s if x.device_time_s is not None])
        np.testing.assert_allclose(lat, 0.010, atol=1e-9)
    if driver == "nmea0183" and not extra:
        dt = np.diff([x.device_time_s for x in s if x.device_time_s is not None])
        np.testing.assert_allclose(dt, 1 / rate, atol=1.5e-3)  # ms timestamps of PASHR


@pytest.mark.parametrize(
    ("driver", "how", "reason"),
    [
        ("canopen", "length", "length"),
        ("canopen", "range", "range"),
        ("canopen", "id", "id"),
        ("canopen", "bytes", "decode"),  # arbitrary bytes on the slcan line
        ("j1939", "line", "decode"),
        ("j1939", "range", "range"),
        ("nmea2000", "length", "length"),
        ("nmea2000", "id", "id"),
        ("nmea0183", "checksum", "checksum"),
        ("nmea0183", "truncated", "checksum"),
        ("nmea0183", "range", "range"),
        ("nmea0183", "bytes", "decode"),
    ],
)
def test_garbled_frames_counted_and_skipped(
    driver: str, how: str, reason: str, vclock: VirtualClock
) -> None:
    model = SimInstrumentConfig(rate_hz=200.0, seed=2)
    with back_to_back(driver, model, Static(), clock=vclock) as (sim, dev, col):
        sim.inject("garbled", fraction=0.3, how=how)
        col.wait(lambda: sim.counts["garbled"] >= 40)
        drain(sim, dev, col)
        assert col.errors == []
        garbled, sent = sim.counts["garbled"], sim.counts["sent"]
        bad, good = dict(dev.stats.bad), dev.stats.good
        assert good + sum(bad.values()) == sent
        assert bad == {reason: garbled}
        # nothing garbled passed as data: every sample is the static angle
        res = sim.wire_resolution_deg
        for smp in col.samples:
            assert smp.angle_deg["roll"] == pytest.approx(1.25, abs=res)
            assert smp.angle_deg["pitch"] == pytest.approx(-0.5, abs=res)


@pytest.mark.parametrize("driver", ["nmea0183", "nmea2000"])
def test_silent_instrument_reported_then_recovers(driver: str, vclock: VirtualClock) -> None:
    """A serial driver and a CAN one (python-can's slcan bus counts its receive timeout on
    the run's clock: the reader's silence check after each empty ``recv`` comes on time)."""
    model = SimInstrumentConfig(rate_hz=100.0)
    with back_to_back(driver, model, clock=vclock, silence_timeout_s=0.3) as (sim, _dev, col):
        col.wait(lambda: len(col.samples) >= 10)
        sim.inject("silent")
        took = col.wait(lambda: len(col.errors) >= 1, timeout=3.0)
        assert isinstance(col.errors[0], DeviceTimeout)
        assert 0.1 < took < 2.0  # silence_timeout_s = 0.3 after the last sample, not at once
        n = len(col.samples)
        sim.clear_faults()
        col.wait(lambda: len(col.samples) >= n + 10)
        assert len(col.errors) == 1


@pytest.mark.parametrize("driver", ["j1939", "nmea0183"])
def test_stuck_instrument_repeats_its_last_value(driver: str, vclock: VirtualClock) -> None:
    model = SimInstrumentConfig(rate_hz=100.0, noise_deg=0.2, seed=4)
    with back_to_back(driver, model, clock=vclock) as (sim, _dev, col):
        col.wait(lambda: len(col.samples) >= 20)
        before = [x.angle_deg["roll"] for x in col.samples]
        assert len(set(before)) > 10  # noisy while alive
        sim.inject("stuck")
        n = len(col.samples)

        def last_30_identical() -> bool:
            tail = col.samples[n:][-30:]
            return len(tail) == 30 and len({(x.angle_deg["roll"], x.angle_deg["pitch"])
                                            for x in tail}) == 1

        # with σ = 0.2° noise, 30 identical outputs in a row never happen while alive
        col.wait(last_30_identical)
        k = len(col.samples)
        col.wait(lambda: len(col.samples) >= k + 20)
        frozen = {x.angle_deg["roll"] for x in col.samples[k - 30:]}
        assert frozen == {col.samples[-1].angle_deg["roll"]}  # and it stays stuck
        assert col.errors == []


@pytest.mark.parametrize("link_kind", ["channel", pytest.param("pty", marks=pytest.mark.realtime)])
@pytest.mark.parametrize("driver", ["canopen", "nmea0183"])
def test_dropped_link_is_reported(
    driver: str, link_kind: str, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    """On an in-process link (simulated time), and on a real pty (``realtime``): the pty and
    its stable name (a symlink) gone, no descriptor left open."""
    clock: Clock = request.getfixturevalue("vclock") if link_kind == "channel" else REAL
    fds_before = len(os.listdir("/proc/self/fd"))
    link = tmp_path / "instrument"
    sim = simulator(SimInstrumentConfig(), instrument_cfg(driver), Static(), clock,
                    link_path=None if clock.virtual else link)
    sim.start()
    try:
        cfg = sim.instrument_config()
        if not clock.virtual:
            assert link.is_symlink() and str(link.resolve()) == sim.channel
            key = "serial_port" if driver == "nmea0183" else "channel"
            cfg = cfg.model_copy(update={key: str(link)})  # the stable name
        dev = open_instrument(cfg, clock=clock)
        try:
            ident = dev.connect()
            col = Collector(clock)
            dev.start(col.samples.append, col.errors.append)
            col.wait(lambda: len(col.samples) >= 5)
            sim.inject("drop")
            took = col.wait(lambda: len(col.errors) >= 1, timeout=3.0)
            assert isinstance(col.errors[0], ConnectionLost)
            assert took < 2.0
            assert not link.exists()
        finally:
            dev.close()
    finally:
        stop(sim)
    assert len(os.listdir("/proc/self/fd")) == fds_before  # no pty, serial or pipe left open
    if driver == "canopen":
        assert ident.model == "SIM-INCL410" and ident.serial == "1"
        assert ident.firmware == "1.0.0" and ident.extra["resolution_deg"] == "0.01"


def test_canopen_connect_fails_cleanly_when_silent_or_wrong_bitrate(vclock: VirtualClock) -> None:
    for fault, kw in (("silent", {}), (None, {"bitrate": 250000})):
        sim = simulator(SimInstrumentConfig(), instrument_cfg("canopen"), Static(), vclock)
        sim.start()
        try:
            if fault:
                sim.inject(fault)
            cfg = sim.instrument_config().model_copy(update={"connect_timeout_s": 0.3, **kw})
            dev = open_instrument(cfg, clock=vclock)
            try:
                with pytest.raises(DeviceTimeout, match="SDO"):
                    dev.connect()
            finally:
                dev.close()
        finally:
            stop(sim)


@pytest.mark.parametrize(("serial_number", "reported"), [(None, "1"), (20260001, "20260001")])
def test_canopen_serial_number_read_over_sdo(
    serial_number: int | None, reported: str, vclock: VirtualClock
) -> None:
    """The driver reads 1018h sub 4 over SDO: the EDS's default, or the configured number."""
    model = SimInstrumentConfig(serial_number=serial_number)
    with back_to_back("canopen", model, Static(), clock=vclock) as (_, dev, col):
        col.wait(lambda: len(col.samples) >= 5)
        assert dev.identity is not None and dev.identity.serial == reported


def test_raw_can_log_blf_readable(tmp_path: Path, vclock: VirtualClock) -> None:
    log = tmp_path / "can.blf"
    model = SimInstrumentConfig(rate_hz=200.0)
    with back_to_back("nmea2000", model, Static(), clock=vclock, log=log) as (sim, dev, col):
        col.wait(lambda: len(col.samples) >= 50)
        drain(sim, dev, col)
        n = dev.stats.good
    frames = list(can.LogReader(str(log)))
    assert len(frames) == n
    assert all(f.arbitration_id == 0x09F11980 and f.is_extended_id for f in frames)


def test_inject_rejects_bad_faults() -> None:
    sim = SimInstrument(SimInstrumentConfig(), instrument_cfg("nmea0183"), Static())
    with pytest.raises(ConfigError, match="fault 'melt'"):
        sim.inject("melt")
    with pytest.raises(ConfigError, match="fraction"):
        sim.inject("garbled", fraction=1.5)
    with pytest.raises(ConfigError, match="how"):
        sim.inject("garbled", how="length")  # a CAN garbling on a serial talker
    sim.stop()  # never started: idempotent no-op
