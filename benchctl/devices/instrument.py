"""Open the instrument a config names: a registry of drivers by name, imported only when asked.

``open_instrument(cfg)`` opens the transport (a python-can bus for ``canopen``, ``j1939``,
``nmea2000``; a serial port for ``nmea0183``) and hands it to the driver, which then owns it
(``close`` releases it). It does not connect: call ``connect()`` for the identity, then
``start(on_sample, on_error)``.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchctl.clock import REAL, Clock
from benchctl.config import InstrumentConfig
from benchctl.devices.base import AngleSensor
from benchctl.devices.can.bus import open_can_bus, shutdown_bus
from benchctl.devices.nmea0183 import open_serial
from benchctl.errors import ConfigError, DeviceError

#: driver name -> (module, class); the module is imported when the driver is used
DRIVERS: dict[str, tuple[str, str]] = {
    "canopen": ("benchctl.devices.can.canopen_incl", "CanopenInclinometer"),
    "j1939": ("benchctl.devices.can.j1939", "J1939SlopeSensor"),
    "nmea2000": ("benchctl.devices.can.nmea2000", "Nmea2000Attitude"),
    "nmea0183": ("benchctl.devices.nmea0183", "Nmea0183Instrument"),
}


def _load(driver: str) -> Callable[..., Any]:
    try:
        module, cls = DRIVERS[driver]
    except KeyError:
        raise ConfigError(
            f"instrument.driver = {driver!r}: unknown, expected one of {sorted(DRIVERS)}"
        ) from None
    try:
        return getattr(importlib.import_module(module), cls)
    except ImportError as e:
        raise DeviceError(
            f"instrument driver {driver!r} needs a library that is not installed: {e}"
        ) from e


def open_instrument(
    cfg: InstrumentConfig, *, can_log_path: Path | None = None, clock: Clock = REAL
) -> AngleSensor:
    """Open the transport and build the driver for ``cfg.driver``.

    Parameters
    ----------
    cfg : InstrumentConfig
        The instrument section of the bench config.
    can_log_path : Path, optional
        For CAN drivers, write every received frame there (``.blf``, ``.asc`` …).
    clock : Clock
        The run's clock (``benchctl.clock``): receipt times, the reader thread, its waits.

    Returns
    -------
    AngleSensor
        Not yet connected.
    """
    cls = _load(cfg.driver)
    if cfg.driver == "nmea0183":
        port = open_serial(cfg)
        try:
            return cls(port, cfg, clock=clock)
        except BaseException:
            port.close()
            raise

    bus = open_can_bus(cfg, clock=clock)
    try:
        return cls(bus, cfg, can_log_path=can_log_path, clock=clock)
    except BaseException:
        shutdown_bus(bus)
        raise
