"""The contract every device driver keeps, checked alike for each one the program can open.

Parametrised over the instrument drivers' registry (``benchctl.devices.instrument.DRIVERS``: a
driver added there is checked here without a line of this file changing) and over the stand's
two links (Modbus TCP, Modbus RTU). Each driver runs on its real transport code against the
simulators, on simulated time over in-process links (the bytes are the protocol's own):

- it implements its capability protocol (``AngleSensor``, ``Stand``: checked at run time);
- ``connect`` fills its identity (vendor, model, the protocol it spoke);
- a bad frame is counted by its reason and skipped, the reader goes on, and the error callback
  is never called for it (instruments); a bad reply is an error of the one exception tree and
  the next exchange works (the stand);
- ``close`` twice is safe, before ``connect`` as after a whole session.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from live_bench import live_bench

from benchctl.clock.virtual import VirtualClock
from benchctl.devices.base import (
    AngleSensor,
    DeviceIdentity,
    InstrumentSample,
    Stand,
    TrajectoryStand,
)
from benchctl.devices.instrument import DRIVERS, open_instrument
from benchctl.devices.modbus.stand import open_stand
from benchctl.errors import BenchError
from benchctl.faultspec import GARBLING, transport

INSTRUMENT_DRIVERS = sorted(DRIVERS)


def _identity_filled(ident: DeviceIdentity, protocol_word: str) -> None:
    assert isinstance(ident, DeviceIdentity)
    assert ident.vendor.strip() and ident.model.strip(), ident
    assert protocol_word.lower() in ident.protocol.lower(), ident


@pytest.mark.parametrize("driver", INSTRUMENT_DRIVERS)
def test_instrument_driver_keeps_the_contract(
    driver: str, tmp_path: Path, vclock: VirtualClock
) -> None:
    with live_bench(tmp_path, instrument=driver, clock=vclock) as b:
        never_connected = open_instrument(b.cfg.instrument, clock=vclock)
        never_connected.close()
        never_connected.close()  # twice, never connected: nothing raised

        sensor = open_instrument(b.cfg.instrument, clock=vclock)
        assert isinstance(sensor, AngleSensor)
        assert sensor.axes and set(sensor.axes) <= {"roll", "pitch"}
        _identity_filled(sensor.connect(), "nmea" if driver.startswith("nmea") else driver)

        samples: list[InstrumentSample] = []
        errors: list[BaseException] = []
        good0 = sensor.stats.good  # the frames connect() read (an identity from the first)
        sensor.start(samples.append, errors.append)
        vclock.sleep(0.5)
        good_before = len(samples)
        assert good_before >= 20, (driver, good_before)  # 100 Hz for 0.5 s
        assert sensor.stats.bad_total == 0, sensor.stats.bad

        # every frame damaged for 0.3 s, each way this transport can be damaged in turn
        for how in GARBLING[transport(driver)]:
            b.instrument.inject("garbled", fraction=1.0, how=how)
            vclock.sleep(0.3)
            b.instrument.clear_faults()
        garbled = b.instrument.counts["garbled"]
        assert garbled > 0
        vclock.sleep(0.5)
        assert errors == [], errors  # a bad frame is not a fault of the reader
        assert sensor.stats.bad_total > 0, (driver, sensor.stats)
        assert all(isinstance(r, str) and r for r in sensor.stats.bad), sensor.stats.bad
        assert len(samples) >= good_before + 20  # and it goes on reading good ones
        assert sensor.stats.good - good0 == len(samples)  # each good frame: one sample

        sensor.stop()
        sensor.close()
        sensor.close()  # twice, after a whole session: nothing raised
        assert errors == []


@pytest.mark.parametrize("link", ["tcp", "rtu"])
def test_stand_driver_keeps_the_contract(link: str, tmp_path: Path, vclock: VirtualClock) -> None:
    with live_bench(tmp_path, transport=link, clock=vclock) as b:
        never_connected = open_stand(b.cfg.stand, clock=vclock)
        never_connected.close()
        never_connected.close()

        stand = open_stand(b.cfg.stand, clock=vclock)
        assert isinstance(stand, Stand)
        assert isinstance(stand, TrajectoryStand)  # the Modbus driver has the buffered mode's queue
        assert stand.axes == tuple(b.cfg.stand.axes)
        _identity_filled(stand.connect(), "modbus")
        first = stand.read_sample()
        assert set(first.angle_deg) == set(stand.axes)

        b.stand.inject("modbus_exception", code=4, count=1)  # one reply is an exception
        with pytest.raises(BenchError) as bad:
            stand.read_sample()
        assert "exception" in str(bad.value).lower() or "04" in str(bad.value), bad.value
        after = stand.read_sample()  # the next exchange works
        assert after.t_host > first.t_host

        stand.close()
        stand.close()
