"""Open a python-can bus from an instrument config: the one place that knows interface quirks.

``slcan`` opens ``benchctl.devices.can.slcan.SlcanBus`` (python-can's slcan bus with a receive
side that turns every adapter line into a frame, an answer or a ``decode`` bad frame, never a
lost link); every other interface is python-can's own ``can.Bus``.
"""

from __future__ import annotations

import contextlib
import os
from typing import Any

import can

from benchctl.clock import REAL, Clock
from benchctl.config import InstrumentConfig
from benchctl.devices.can.slcan import SlcanBus
from benchctl.errors import DeviceError

#: python-can waits this long after opening a real slcan adapter (many reset on open).
SLCAN_DEFAULT_SLEEP_S = 2.0


def _is_pty(channel: str) -> bool:
    """True if ``channel`` (possibly a symlink, possibly ``path@baud``) is a pseudo-terminal or
    an in-process link (``simchan://``): nothing there resets on open."""
    if channel.startswith("simchan://"):
        return True
    path = os.path.realpath(channel.split("@", 1)[0])
    return path.startswith("/dev/pts/")


def can_bus_kwargs(cfg: InstrumentConfig) -> dict[str, Any]:
    """Keyword arguments for ``can.Bus`` from ``cfg`` (interface, channel, bitrate, options).

    For ``slcan`` the serial baud rate is ``cfg.baudrate``, the wait after opening is
    ``cfg.sleep_after_open_s``, or 0 for a pseudo-terminal and 2 s otherwise, and
    ``adapter_timestamps`` is ``cfg.adapter_timestamps`` (``SlcanBus``: ``Z1``).
    """
    if not cfg.interface or cfg.channel is None:
        raise DeviceError(f"instrument driver {cfg.driver}: needs interface and channel for CAN")
    kwargs: dict[str, Any] = {"interface": cfg.interface, "channel": cfg.channel,
                              "bitrate": cfg.bitrate}
    if cfg.interface == "slcan":
        sleep = cfg.sleep_after_open_s
        if sleep is None:
            sleep = 0.0 if _is_pty(cfg.channel) else SLCAN_DEFAULT_SLEEP_S
        kwargs["sleep_after_open"] = sleep
        kwargs["tty_baudrate"] = cfg.baudrate
        kwargs["adapter_timestamps"] = cfg.adapter_timestamps
    kwargs.update(cfg.can_options)
    return kwargs


def open_can_bus(cfg: InstrumentConfig, *, clock: Clock = REAL) -> can.BusABC:
    """Open the CAN bus ``cfg`` names; a failure raises ``DeviceError`` naming the channel.
    ``clock`` stamps the frames of our slcan bus (python-can's own buses stamp on the real
    time)."""
    kwargs = can_bus_kwargs(cfg)
    try:
        if kwargs["interface"] == "slcan":
            return SlcanBus(clock=clock, **{k: v for k, v in kwargs.items() if k != "interface"})
        return can.Bus(**kwargs)
    except (can.CanError, OSError, ValueError, ImportError) as e:
        raise DeviceError(
            f"instrument CAN bus interface={cfg.interface!r} channel={cfg.channel!r} "
            f"bitrate={cfg.bitrate}: cannot open: {e}"
        ) from e


def shutdown_bus(bus: can.BusABC) -> None:
    """Shut ``bus`` down, releasing its port even when the link is already gone.

    python-can's slcan ``shutdown`` writes ``C`` before closing its serial port; on a hung-up
    line that write raises and the port (and its pipes) would stay open, so close it here.
    """
    try:
        bus.shutdown()
    except Exception:
        port = getattr(bus, "serialPortOrig", None)  # python-can slcan's serial port
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        raise
