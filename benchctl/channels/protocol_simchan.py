"""pyserial's handler for ``simchan://NAME`` URLs: a serial port that is an in-process link.

``serial.serial_for_url("simchan://slcan0", baudrate=..., timeout=...)`` opens the endpoint
registered as ``slcan0`` (:func:`benchctl.channels.register`). Reads honour ``timeout`` on
the link's clock; baud rate and line settings are accepted and ignored (the link models its own
byte time).
"""

from __future__ import annotations

from typing import Any

import serial

from benchctl.channels import Endpoint, lookup


class Serial(serial.SerialBase):
    """A pyserial port over an in-process :class:`~benchctl.channels.Endpoint`."""

    _ep: Endpoint | None = None

    def open(self) -> None:
        if self._port is None:
            raise serial.SerialException("simchan: no port given")
        self._ep = lookup(str(self._port))
        self.is_open = True

    def close(self) -> None:
        self.is_open = False
        self._ep = None

    def _reconfigure_port(self, *args: Any, **kwargs: Any) -> None:
        return None

    def _endpoint(self) -> Endpoint:
        if not self.is_open or self._ep is None:
            raise serial.PortNotOpenError()
        return self._ep

    @property
    def in_waiting(self) -> int:
        return self._endpoint().in_waiting

    def read(self, size: int = 1) -> bytes:
        ep = self._endpoint()
        out = bytearray()
        clock = ep.clock
        end = None if self._timeout is None else clock.monotonic() + self._timeout
        while len(out) < size:
            left = None if end is None else max(0.0, end - clock.monotonic())
            got = ep.read(size - len(out), left)
            if not got:
                if ep.closed and not ep.in_waiting and not out:
                    raise serial.SerialException(f"{ep.name}: device disconnected")
                break
            out += got
            if left == 0.0:
                break
        return bytes(out)

    def read_within(self, timeout: float | None) -> bytes:
        """Every byte that has arrived, waiting up to ``timeout`` (None: for ever) for the first:
        a reader on simulated time wakes once per frame, not once per port timeout."""
        ep = self._endpoint()
        got = ep.read(1 << 16, timeout)
        if not got and ep.closed and not ep.in_waiting:
            raise serial.SerialException(f"{ep.name}: device disconnected")
        return got

    def write(self, data: Any) -> int:
        ep = self._endpoint()
        try:
            return ep.write(bytes(data))
        except OSError as e:
            raise serial.SerialException(str(e)) from None

    def flush(self) -> None:
        self._endpoint()

    def reset_input_buffer(self) -> None:
        self._endpoint().reset_input()

    def reset_output_buffer(self) -> None:
        self._endpoint()

    def fileno(self) -> int:
        raise OSError("simchan: an in-process link has no file descriptor")
