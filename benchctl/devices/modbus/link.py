"""The one module that imports the pymodbus client: a Modbus link whose errors raise.

pymodbus returns error responses as values (``isError()``) and renamed its keywords between
releases (``slave=`` → ``device_id=`` in 3.10); this wrapper stops that churn here. Every call is
synchronous and serialised by a lock, so one link can be shared by a streaming thread and a
supervisor thread.

Error mapping:

- an exception response → :class:`benchctl.errors.ModbusException` (function and exception code)
- no reply within the timeout (after the configured retries) → :class:`DeviceTimeout`
- bytes came back but no valid frame (bad CRC, truncated frame, garbage) → :class:`ProtocolError`
- the connection dropped or cannot be opened → :class:`ConnectionLost`

With ``wire_trace`` every frame sent and received is logged at DEBUG on the logger
``benchctl.wire``.

Sample stamps (``sample_stamp``): on TCP the midpoint of request and reply; on RTU the moment
the request's last byte reached the device, ``t_send + request bytes × byte time`` (``t_send``
the host's clock as the frame was handed to the serial port, the byte time
``(1 start + 8 data + parity + stop bits) / baud``): a device answers with the state it has
when the request is complete, and the midpoint would sit late by half the difference of the
reply's and the request's wire time, plus the client's polling for the reply's end.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable, Sequence
from typing import Any

from pymodbus import FramerType
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ConnectionException, ModbusIOException
from pymodbus.exceptions import ModbusException as PymodbusError
from pymodbus.pdu import ExceptionResponse

from benchctl.clock import REAL, Clock
from benchctl.errors import ConnectionLost, DeviceTimeout, ModbusException, ProtocolError

log = logging.getLogger(__name__)
wire_log = logging.getLogger("benchctl.wire")

#: a host or serial port starting so names an in-process link (``benchctl.channels``): the same
#: pymodbus client and framing, the bytes carried in-process on the run's clock
CHANNEL_SCHEME = "simchan://"
MAX_RTU_FRAME = 256  # bytes: the longest Modbus RTU frame (address, PDU of 253, CRC)

EXCEPTION_NAMES = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge",
    6: "server device busy",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}


class _SerialClient(ModbusSerialClient):
    """pymodbus's serial client with a reply wait that a host stall cannot make lose a reply.

    pymodbus judges the reply timeout on the wall clock and, once it has run out, gives up
    without another look at the line: a reply that arrived while this process was held up past
    the time it had left was then thrown away by the retry (its ``send`` empties the input
    first) and the request sent again — without a retry left the exchange failed on "no reply"
    with the reply waiting. Here the timeout ends the wait only when nothing has arrived by
    then: a reply whose bytes are waiting is read to its end, complete when the count of
    waiting bytes has not changed over one poll (pymodbus's own rule, every 4 characters'
    time). A line that keeps sending (noise) still ends the wait, one longest frame after the
    timeout. ``clock``: the line's time (the real one for a serial port; an in-process line's
    on simulated time, ``channel_client.ChannelSerialClient``).
    """

    def __init__(self, *args: Any, clock: Clock = REAL, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._clock = clock

    def _wait_for_data(self) -> int:
        clock = self._clock
        deadline = clock.monotonic() + float(self.comm_params.timeout_connect or 0.0)
        hard_end = math.inf
        size = 0
        while True:
            available = int(self._in_waiting())
            if size and available == size:
                return size  # nothing new over one poll: the frame is complete
            size = available
            now = clock.monotonic()
            if now >= deadline:
                if not size:
                    return 0  # silence up to the timeout, and after any stall: no reply
                if hard_end == math.inf:  # bytes after the timeout: one longest frame more
                    hard_end = now + (MAX_RTU_FRAME + 4) * self._t0 + 2 * self._recv_interval
                elif now >= hard_end:
                    return size
            clock.sleep(self._recv_interval)


class ModbusLink:
    """A synchronous Modbus client link (TCP or RTU) for one device id.

    Build one with :func:`tcp_link` or :func:`rtu_link`. Addresses passed here are PDU
    addresses (0-based); :func:`benchctl.devices.modbus.regmap.pdu_address` produces them.
    """

    def __init__(
        self,
        make_client: Callable[[Callable[[bool, bytes], bytes]], Any],
        *,
        device_id: int,
        endpoint: str,
        timeout_s: float,
        wire_trace: bool = False,
        byte_time_s: float | None = None,
        reply_poll_s: float = 0.0,
        clock: Clock = REAL,
    ) -> None:
        self.clock = clock
        self.device_id = device_id
        self.endpoint = endpoint
        self.timeout_s = timeout_s
        self.wire_trace = wire_trace
        #: seconds per character on a serial line (RTU); None on TCP
        self.byte_time_s = byte_time_s
        #: the least time the client takes to see a reply complete after its last byte (RTU)
        self.reply_poll_s = reply_poll_s
        self._lock = clock.rlock()
        self._rx: list[bytes] = []  # raw receive buffers seen during the current exchange
        self._sent = threading.local()  # per thread: (monotonic time, bytes) of its last send
        self._client = make_client(self._trace)

    # -- tracing ------------------------------------------------------------------------
    def _trace(self, sending: bool, data: bytes) -> bytes:
        if sending and data:
            self._sent.last = (self.clock.monotonic(), len(data))
        if not sending and data:
            self._rx.append(bytes(data))
        if self.wire_trace and data:
            wire_log.debug("%s %s %s", self.endpoint, "->" if sending else "<-", data.hex(" "))
        return data

    # -- connection ---------------------------------------------------------------------
    def connect(self) -> None:
        with self._lock:
            if not self._client.connect():
                raise ConnectionLost(f"{self.endpoint}: cannot connect")

    def close(self) -> None:
        with self._lock:
            self._client.close()

    @property
    def connected(self) -> bool:
        return bool(self._client.connected)

    def sample_stamp(self, t0: float, t1: float) -> float:
        """When the device took the state its reply to this thread's last exchange carries.

        ``t0``/``t1``: the caller's clock before and after the exchange. TCP (or a send not
        seen between them): the midpoint ``(t0 + t1)/2``; RTU: the end of the request on the
        wire, ``t_send + request bytes × byte time``.
        """
        last = getattr(self._sent, "last", None)
        if self.byte_time_s is None or last is None or not t0 <= last[0] <= t1:
            return 0.5 * (t0 + t1)
        return min(t1, last[0] + last[1] * self.byte_time_s)

    def sample_window(self, t0: float, t1: float) -> tuple[float, float]:
        """(earliest, latest) host time the device can have taken the state its reply to this
        thread's last exchange carries: TCP (or a send not seen) ``(t0, t1)``; RTU from the
        end of the request on the wire to the start of the reply (``t1 − reply bytes × byte
        time − reply_poll_s``, the client's own least delay in seeing the reply complete):
        both frames' wire times are no time the device can have read its state in."""
        last = getattr(self._sent, "last", None)
        if self.byte_time_s is None or last is None or not t0 <= last[0] <= t1:
            return t0, t1
        lo = min(t1, last[0] + last[1] * self.byte_time_s)
        reply = sum(len(b) for b in self._rx)
        return lo, max(lo, t1 - reply * self.byte_time_s - self.reply_poll_s)

    # -- requests -----------------------------------------------------------------------
    def read_registers(self, address: int, count: int) -> list[int]:
        """Read ``count`` holding registers (function code 3) from PDU ``address``."""
        rsp = self._call(
            3,
            f"read {count} registers at {address}",
            lambda: self._client.read_holding_registers(
                address, count=count, device_id=self.device_id
            ),
        )
        regs = list(rsp.registers)
        if len(regs) != count:
            raise ProtocolError(
                f"{self.endpoint}: asked for {count} registers at {address}, got {len(regs)}"
            )
        return regs

    def write_registers(self, address: int, values: Sequence[int]) -> None:
        """Write holding registers (function code 16) from PDU ``address``."""
        vals = [int(v) for v in values]
        self._call(
            16,
            f"write {len(vals)} registers at {address}",
            lambda: self._client.write_registers(address, vals, device_id=self.device_id),
        )

    def write_register(self, address: int, value: int) -> None:
        """Write one holding register (function code 6)."""
        self._call(
            6,
            f"write register {address}",
            lambda: self._client.write_register(address, int(value), device_id=self.device_id),
        )

    def read_write_registers(
        self, read_address: int, read_count: int, write_address: int, values: Sequence[int]
    ) -> list[int]:
        """One FC23 transaction: write ``values`` at ``write_address``, then read registers."""
        vals = [int(v) for v in values]
        rsp = self._call(
            23,
            f"write {len(vals)} at {write_address} and read {read_count} at {read_address}",
            lambda: self._client.readwrite_registers(
                read_address=read_address,
                read_count=read_count,
                write_address=write_address,
                values=vals,
                device_id=self.device_id,
            ),
        )
        regs = list(rsp.registers)
        if len(regs) != read_count:
            raise ProtocolError(
                f"{self.endpoint}: asked for {read_count} registers at "
                f"{read_address}, got {len(regs)}"
            )
        return regs

    def _call(self, fc: int, what: str, fn: Callable[[], Any]) -> Any:
        """One exchange of function code ``fc``. A reply to another function code is a late
        reply to an earlier request (its master had timed out and sent again): it is dropped
        and the request sent once more (every request of this link is safe to repeat — a
        trajectory push repeating points the stand has queued is acknowledged, not applied
        twice); twice in a row is a ``ProtocolError``."""
        with self._lock:
            rsp = self._exchange(what, fn)
            if self._reply_fc(rsp) != fc:
                log.warning("%s: %s: dropped a late reply to function code %d", self.endpoint,
                            what, self._reply_fc(rsp))
                rsp = self._exchange(what, fn)
                if self._reply_fc(rsp) != fc:
                    raise ProtocolError(
                        f"{self.endpoint}: {what}: a reply to function code "
                        f"{self._reply_fc(rsp)} for a request of function code {fc}, twice"
                    )
            if isinstance(rsp, ExceptionResponse) or rsp.isError():
                code = int(getattr(rsp, "exception_code", 0))
                name = EXCEPTION_NAMES.get(code, "unknown exception")
                raise ModbusException(
                    fc,
                    code,
                    f"{self.endpoint}: {what}: Modbus exception {code} ({name}) "
                    f"in reply to function code {fc}",
                )
            return rsp

    @staticmethod
    def _reply_fc(rsp: Any) -> int:
        return int(getattr(rsp, "function_code", 0)) & 0x7F

    def _exchange(self, what: str, fn: Callable[[], Any]) -> Any:
        with self._lock:
            self._rx = []
            try:
                rsp = fn()
            except ConnectionException as e:
                self._client.close()
                raise ConnectionLost(
                    f"{self.endpoint}: connection lost during {what}: {e}"
                ) from None
            except OSError as e:  # e.g. a reset connection pymodbus did not wrap
                self._client.close()
                raise ConnectionLost(
                    f"{self.endpoint}: connection lost during {what}: {e}"
                ) from None
            except ModbusIOException as e:
                raise self._no_reply(what, e) from None
            except PymodbusError as e:
                raise ProtocolError(f"{self.endpoint}: {what}: {e}") from None
            return rsp

    def _no_reply(self, what: str, err: Exception) -> Exception:
        """Classify a failed exchange: silence is a timeout; bytes but no frame a protocol error."""
        seen = max(self._rx, key=len, default=b"")
        if seen:
            return ProtocolError(
                f"{self.endpoint}: {what}: invalid reply (bad CRC, truncated or malformed frame): "
                f"{seen.hex(' ')}"
            )
        return DeviceTimeout(f"{self.endpoint}: {what}: no reply within {self.timeout_s} s ({err})")


def tcp_link(
    host: str,
    port: int,
    *,
    device_id: int = 1,
    timeout_s: float = 0.5,
    retries: int = 1,
    wire_trace: bool = False,
    clock: Clock = REAL,
) -> ModbusLink:
    """A Modbus TCP link (MBAP framing) to ``host:port``; not yet connected. ``clock`` stamps
    the sends; a ``simchan://`` host is an in-process link whose waits are on its own clock
    (pymodbus's socket waits are on the real time)."""

    def make(trace: Callable[[bool, bytes], bytes]) -> Any:
        if host.startswith(CHANNEL_SCHEME):  # an in-process link to a simulated stand
            # here: channel_client builds on this module (a circle at import)
            from benchctl.channels import lookup
            from benchctl.devices.modbus.channel_client import ChannelTcpClient

            return ChannelTcpClient(lookup(host), timeout=timeout_s, retries=retries,
                                    trace_packet=trace)
        return ModbusTcpClient(
            host, port=port, timeout=timeout_s, retries=retries, trace_packet=trace
        )

    return ModbusLink(
        make,
        device_id=device_id,
        endpoint=f"modbus-tcp {host}:{port}",
        timeout_s=timeout_s,
        wire_trace=wire_trace,
        clock=clock,
    )


def rtu_link(
    port: str,
    *,
    baudrate: int = 115200,
    parity: str = "N",
    stopbits: int = 1,
    device_id: int = 1,
    timeout_s: float = 0.5,
    retries: int = 1,
    wire_trace: bool = False,
    clock: Clock = REAL,
) -> ModbusLink:
    """A Modbus RTU link over a serial device path or pyserial URL; not yet connected.
    ``clock`` stamps the sends; a ``simchan://`` port is an in-process line whose waits are on
    its own clock (a serial port's, on the real time)."""

    def make(trace: Callable[[bool, bytes], bytes]) -> Any:
        line: dict[str, Any] = {"framer": FramerType.RTU, "baudrate": baudrate, "parity": parity,
                "stopbits": stopbits, "timeout": timeout_s, "retries": retries,
                "trace_packet": trace}
        if port.startswith(CHANNEL_SCHEME):  # an in-process line to a simulated stand
            # here: channel_client builds on this module (a circle at import)
            from benchctl.channels import lookup
            from benchctl.devices.modbus.channel_client import ChannelSerialClient

            return ChannelSerialClient(lookup(port), **line)
        return _SerialClient(port, **line)

    bits = 1 + 8 + (0 if parity.upper() == "N" else 1) + stopbits
    return ModbusLink(
        make,
        device_id=device_id,
        endpoint=f"modbus-rtu {port}@{baudrate}",
        timeout_s=timeout_s,
        wire_trace=wire_trace,
        byte_time_s=bits / baudrate,
        # pymodbus's serial client sees a reply complete when its count of waiting bytes has
        # not changed over one poll: every 4 characters' time (a frame bit count of 1 + 8 +
        # stop bits), at least 1 ms — so its read returns at least that long after the last byte
        reply_poll_s=max(4.0 * (1 + 8 + stopbits) / baudrate, 0.001),
        clock=clock,
    )
