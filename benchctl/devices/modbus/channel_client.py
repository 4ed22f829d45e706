"""pymodbus's sync clients over an in-process link: the stand driver on simulated time.

The clients are pymodbus's own (``ModbusTcpClient``, ``ModbusSerialClient``: their framing,
transaction ids, retries and error paths are the ones a run on hardware takes); only the byte
transport is replaced — the socket, or the serial port — by a
:class:`benchctl.channels.Endpoint`, and their waits go through the endpoint's clock:

- TCP: ``recv`` returns what has arrived, waiting up to the reply timeout for the first byte
  (pymodbus's own ``recv`` selects on a socket for the same);
- RTU: the link's serial client (``link._SerialClient``: a reply is complete when the count of
  waiting bytes did not change over one poll, and the timeout ends the wait only when nothing
  has arrived) on the endpoint's clock.
"""

from __future__ import annotations

from typing import Any

from pymodbus.client import ModbusTcpClient
from pymodbus.exceptions import ConnectionException

from benchctl.channels import Endpoint
from benchctl.devices.modbus.link import _SerialClient


class ChannelTcpClient(ModbusTcpClient):
    """``ModbusTcpClient`` whose socket is an in-process endpoint (MBAP framing unchanged)."""

    def __init__(self, endpoint: Endpoint, **kwargs: Any) -> None:
        super().__init__("simchan", port=0, **kwargs)
        self._ep = endpoint

    def connect(self) -> bool:
        if self._ep.closed:
            return False
        self.socket = self._ep  # type: ignore[assignment]  # an endpoint stands for the socket
        return True

    def close(self) -> None:
        self.socket = None

    def send(self, request: bytes, addr: tuple[Any, ...] | None = None) -> int:
        if not self.socket:
            raise ConnectionException(str(self))
        try:
            return self._ep.write(request)
        except OSError:
            self.close()
            raise ConnectionException(str(self)) from None

    def recv(self, size: int | None) -> bytes:
        if not self.socket:
            raise ConnectionException(str(self))
        data = self._ep.read(size or 4096, self.comm_params.timeout_connect or 0)
        if not data and self._ep.closed:
            self.close()
            raise ConnectionException(f"{self}: connection closed by the stand")
        return data

    def is_socket_open(self) -> bool:
        return self.socket is not None


class ChannelSerialClient(_SerialClient):
    """The link's RTU client (pymodbus's, with its reply wait that a stall cannot make lose a
    reply) whose serial port is an in-process endpoint, waiting on the endpoint's clock."""

    def __init__(self, endpoint: Endpoint, **kwargs: Any) -> None:
        super().__init__("simchan", clock=endpoint.clock, **kwargs)
        self._ep = endpoint

    def connect(self) -> bool:
        if self._ep.closed:
            return False
        self.socket = _PortView(self._ep)
        return True


class _PortView:
    """The few pyserial calls pymodbus's serial client makes, on an endpoint."""

    def __init__(self, ep: Endpoint) -> None:
        self._ep = ep
        self.inter_byte_timeout: float | None = None

    @property
    def in_waiting(self) -> int:
        return self._ep.in_waiting

    @property
    def is_open(self) -> bool:
        return not self._ep.closed

    def read(self, size: int) -> bytes:
        return self._ep.read(size, 0.0)

    def write(self, data: bytes) -> int:
        return self._ep.write(bytes(data))

    def close(self) -> None:
        return None
