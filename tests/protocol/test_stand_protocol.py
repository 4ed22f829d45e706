"""Byte-exact protocol tests of the stand driver, in the spirit of PyMeasure's expected_protocol.

A scripted peer on a loopback socket (Modbus TCP) or a pseudo-terminal (Modbus RTU) holds ordered
pairs (bytes the driver must send, bytes answered). A test fails on a wrong request, on a pair left
unused, and on any byte the driver sends beyond the script (read until the driver closes).
The frames are written out by hand from the Modbus specification and the register map
(``drivers/stand_generic.yaml``); RTU CRCs come from a bitwise CRC-16/MODBUS written here.

Over the real socket and pty on the host's time (``realtime``); the replies a driver must wait
out (a bad CRC, a truncated frame) on simulated time, the peer on an in-process link
(``simchan://``, the ``vclock`` fixture), where the driver's reply timeout costs nothing.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import time
import tty
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest
from repo_paths import ROOT
from wire import rtu

from benchctl.channels import free_name, register, unregister
from benchctl.channels import link as channel_link
from benchctl.clock import REAL, Clock
from benchctl.clock.virtual import VirtualClock
from benchctl.devices.base import StandLimitsView
from benchctl.devices.modbus.link import ModbusLink, rtu_link, tcp_link
from benchctl.devices.modbus.regmap_load import load_register_map
from benchctl.devices.modbus.stand import ModbusStand
from benchctl.errors import DeviceTimeout, LimitError, ModbusException, ProtocolError, StandFault

# real sockets and pseudo-terminals, timed on the host's clock: run alone (realtime tier)
REALTIME = pytest.mark.realtime

MAP = ROOT / "drivers" / "stand_generic.yaml"
H = bytes.fromhex

# Feedback block 200..225 (26 registers): status ready|enabled, fault 0, heartbeat echo 7, pad,
# roll angle 1.5, rate -0.5, setpoint 1.5, fault 0, pad, pitch angle -2.0, rate 0.0, setpoint -2.0,
# fault 0 — float32 big-endian, high word first — pad, then the trajectory queue (220..225):
# level 0, next index 0 (uint32), played 0 (uint32), underruns 0.
FEEDBACK = H(
    "0003 0000 0007 0000 3FC00000 BF000000 3FC00000 0000 0000 C0000000 00000000 C0000000 0000"
    " 0000 0000 00000000 00000000 0000"
)
FAULTED = H("0009 000A 0007 0000") + FEEDBACK[8:]  # ready off, fault bit, fault code 10
READ_PDU = H("03 00C8 001A")  # FC3, address 200, 26 registers
READ_REPLY_PDU = H("03 34") + FEEDBACK  # 52 data bytes
SETPOINT_PDU = H("10 012C 0004 08 3FC00000 C0000000")  # FC16 at 300: roll 1.5, pitch -2.0
SETPOINT_REPLY_PDU = H("10 012C 0004")
HEARTBEAT_PDU = H("06 0065 0001")  # FC6 at 101, value 1


def mbap(tid: int, pdu: bytes, unit: int = 1) -> bytes:
    return (
        tid.to_bytes(2, "big")
        + b"\x00\x00"
        + (len(pdu) + 1).to_bytes(2, "big")
        + bytes([unit])
        + pdu
    )


def test_crc_helper_matches_the_specification_example() -> None:
    # Modbus over serial line guide: read 10 holding registers from 0 of slave 1 → CRC C5 CD
    assert rtu(H("03 0000 000A")) == H("01 03 0000 000A C5CD")


class ScriptedPeer:
    """The device end of a link, playing ordered (expected request, reply or None) pairs."""

    def __init__(self, pairs: Sequence[tuple[bytes, bytes | None]], clock: Clock = REAL) -> None:
        self.pairs = pairs
        self.clock = clock
        self.used = 0
        self.errors: list[str] = []
        self.leftover = b""
        self._thread = clock.thread(self._run, name="scripted-peer")

    # transport hooks ---------------------------------------------------------------------
    def _recv(self, n: int, deadline: float) -> bytes:
        raise NotImplementedError

    def _send(self, data: bytes) -> None:
        raise NotImplementedError

    def _close(self) -> None:
        raise NotImplementedError

    def _run(self) -> None:
        try:
            for req, reply in self.pairs:
                got = self._recv(len(req), self.clock.monotonic() + 5.0)
                if got != req:
                    self.errors.append(
                        f"pair {self.used}: expected {req.hex(' ')}, got {got.hex(' ')}"
                    )
                    return
                self.used += 1
                if reply:
                    self._send(reply)
            # until the driver closes
            self.leftover = self._recv(1 << 16, self.clock.monotonic() + 5.0)
        finally:
            self._close()

    def check(self) -> None:
        self._thread.join(timeout=10)
        assert not self._thread.is_alive()
        assert not self.errors, self.errors
        assert self.used == len(self.pairs), f"{len(self.pairs) - self.used} pairs unused"
        assert self.leftover == b"", (
            f"driver sent bytes beyond the script: {self.leftover.hex(' ')}"
        )


class TcpPeer(ScriptedPeer):
    def __init__(self, pairs: Sequence[tuple[bytes, bytes | None]]) -> None:
        super().__init__(pairs)
        self._srv = socket.create_server(("127.0.0.1", 0))
        self.port = self._srv.getsockname()[1]
        self._conn: socket.socket | None = None

    def start(self) -> None:
        self._thread.start()

    def _recv(self, n: int, deadline: float) -> bytes:
        if self._conn is None:
            self._srv.settimeout(5.0)
            self._conn, _ = self._srv.accept()
        buf = b""
        while len(buf) < n and time.monotonic() < deadline:
            self._conn.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                chunk = self._conn.recv(n - len(buf))
            except TimeoutError:
                break
            if not chunk:
                break
            buf += chunk
        return buf

    def _send(self, data: bytes) -> None:
        assert self._conn is not None
        self._conn.sendall(data)

    def _close(self) -> None:
        if self._conn is not None:
            self._conn.close()
        self._srv.close()


class PtyPeer(ScriptedPeer):
    def __init__(self, pairs: Sequence[tuple[bytes, bytes | None]]) -> None:
        super().__init__(pairs)
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        self.path = os.ttyname(self._slave)

    def start(self) -> None:
        os.close(self._slave)  # the driver holds the only slave: its close is our end of file
        self._slave = -1
        self._thread.start()

    def _recv(self, n: int, deadline: float) -> bytes:
        buf = b""
        while len(buf) < n:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._master], [], [], left)[0]:
                break
            try:
                chunk = os.read(self._master, n - len(buf))
            except OSError:  # EIO: the driver closed the port
                break
            if not chunk:
                break
            buf += chunk
        return buf

    def _send(self, data: bytes) -> None:
        os.write(self._master, data)

    def _close(self) -> None:
        os.close(self._master)
        if self._slave >= 0:
            os.close(self._slave)


class ChannelPeer(ScriptedPeer):
    """The device end of an in-process link (simulated time): the driver opens ``url``."""

    def __init__(self, pairs: Sequence[tuple[bytes, bytes | None]], clock: Clock,
                 byte_time_s: float) -> None:
        super().__init__(pairs, clock)
        host, self._ep = channel_link(clock, "scripted-peer", byte_time_s=byte_time_s)
        self.url = register(free_name("scripted-peer"), host)

    def start(self) -> None:
        self._thread.start()

    def _recv(self, n: int, deadline: float) -> bytes:
        buf = b""
        while len(buf) < n:
            left = deadline - self.clock.monotonic()
            chunk = self._ep.read(n - len(buf), left) if left > 0 else b""
            if not chunk:  # the deadline, or the driver closed the link
                break
            buf += chunk
        return buf

    def _send(self, data: bytes) -> None:
        self._ep.write(data)

    def _close(self) -> None:
        self._ep.close()
        unregister(self.url)


@contextlib.contextmanager
def expected_protocol(
    transport: str,
    pairs: Sequence[tuple[bytes, bytes | None]],
    timeout_s: float = 2.0,  # generous: a loaded machine
    register_map: Path = MAP,
    clock: Clock = REAL,
) -> Iterator[ModbusStand]:
    """A ``ModbusStand`` wired to a scripted peer; checks the script when the block ends. On a
    virtual ``clock`` the peer is on an in-process link, else a socket (tcp) or a pty (rtu)."""
    peer: TcpPeer | PtyPeer | ChannelPeer
    link: ModbusLink
    if clock.virtual:
        peer = ChannelPeer(pairs, clock, 0.0 if transport == "tcp" else 10 / 115200)
        if transport == "tcp":
            link = tcp_link(peer.url, 502, timeout_s=timeout_s, retries=0, clock=clock)
        else:
            link = rtu_link(peer.url, timeout_s=timeout_s, retries=0, clock=clock)
    elif transport == "tcp":
        peer = TcpPeer(pairs)
        link = tcp_link("127.0.0.1", peer.port, timeout_s=timeout_s, retries=0)
    else:
        peer = PtyPeer(pairs)
        link = rtu_link(peer.path, timeout_s=timeout_s, retries=0)
    stand = ModbusStand(
        link,
        load_register_map(register_map),
        limits=StandLimitsView(30.0, 20.0, 100.0),
        setpoint_period_s=0.01,
        clock=clock,
    )
    link.connect()
    peer.start()
    try:
        yield stand
    finally:
        stand.close()
        peer.check()


def frame(transport: str, tid: int, pdu: bytes) -> bytes:
    return mbap(tid, pdu) if transport == "tcp" else rtu(pdu)


@REALTIME
@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_read_sample_decodes_the_feedback_block(transport: str) -> None:
    pairs = [(frame(transport, 1, READ_PDU), frame(transport, 1, READ_REPLY_PDU))]
    with expected_protocol(transport, pairs) as stand:
        s = stand.read_sample()
    assert s.angle_deg == {"roll": 1.5, "pitch": -2.0}
    assert s.rate_deg_s == {"roll": -0.5, "pitch": 0.0}
    assert s.setpoint_deg == {"roll": 1.5, "pitch": -2.0}
    assert s.status.ready and s.status.enabled and not s.status.fault and s.status.heartbeat == 7
    assert s.rtt_s > 0


@REALTIME
@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_setpoint_is_one_fc16_write_after_reading_the_state(transport: str) -> None:
    pairs = [
        (frame(transport, 1, READ_PDU), frame(transport, 1, READ_REPLY_PDU)),
        (frame(transport, 2, SETPOINT_PDU), frame(transport, 2, SETPOINT_REPLY_PDU)),
        (frame(transport, 3, HEARTBEAT_PDU), frame(transport, 3, HEARTBEAT_PDU)),
    ]
    with expected_protocol(transport, pairs) as stand:
        stand.send_setpoint({"roll": 1.5, "pitch": -2.0})
        stand.heartbeat()


@REALTIME
@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_limit_breach_writes_nothing(transport: str) -> None:
    pairs = [(frame(transport, 1, READ_PDU), frame(transport, 1, READ_REPLY_PDU))]
    with expected_protocol(transport, pairs) as stand:
        with pytest.raises(LimitError, match=r"allowed 30\.0"):
            stand.send_setpoint({"roll": 31.0})
        with pytest.raises(LimitError, match="needs rate"):
            stand.send_setpoint({"roll": 2.0})  # 0.5° in one 10 ms period: 50°/s > 20°/s


@REALTIME
@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_exception_reply_raises_modbus_exception(transport: str) -> None:
    pairs = [
        (frame(transport, 1, READ_PDU), frame(transport, 1, READ_REPLY_PDU)),
        (frame(transport, 2, SETPOINT_PDU), frame(transport, 2, H("90 06"))),  # device busy
    ]
    with expected_protocol(transport, pairs) as stand, pytest.raises(ModbusException) as err:
        stand.send_setpoint({"roll": 1.5, "pitch": -2.0})
    assert (err.value.function_code, err.value.exception_code) == (16, 6)


@REALTIME
@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_device_fault_raises_stand_fault_with_code(transport: str) -> None:
    pairs = [(frame(transport, 1, READ_PDU), frame(transport, 1, H("03 34") + FAULTED))]
    with expected_protocol(transport, pairs) as stand, pytest.raises(StandFault) as err:
        stand.read_sample()
    assert err.value.code == 10


def test_rtu_bad_crc_is_a_protocol_error(vclock: VirtualClock) -> None:
    good = rtu(READ_REPLY_PDU)
    bad = good[:-2] + bytes([good[-2] ^ 0xFF, good[-1]])
    with (
        expected_protocol("rtu", [(rtu(READ_PDU), bad)], clock=vclock) as stand,
        pytest.raises(ProtocolError, match="invalid reply"),
    ):
        stand.read_sample()


@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_truncated_reply_is_a_protocol_error(transport: str, vclock: VirtualClock) -> None:
    whole = frame(transport, 1, READ_REPLY_PDU)
    pairs = [(frame(transport, 1, READ_PDU), whole[:20])]
    with (
        expected_protocol(transport, pairs, clock=vclock) as stand,
        pytest.raises(ProtocolError) as err,
    ):
        stand.read_sample()
    assert whole[:20].hex(" ") in str(err.value)


@REALTIME
@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_silence_is_a_device_timeout(transport: str) -> None:
    """Nothing is ever answered: a short reply timeout (0.5 s) cannot make this pass or fail
    by the machine's load."""
    t0 = time.monotonic()
    pairs = [(frame(transport, 1, READ_PDU), None)]
    with (
        expected_protocol(transport, pairs, timeout_s=0.5) as stand,
        pytest.raises(DeviceTimeout),
    ):
        stand.read_sample()
    assert time.monotonic() - t0 < 5.0


@REALTIME
@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_setpoint_and_read_is_one_fc23_transaction(transport: str) -> None:
    # FC23: read 26 at 200, write 4 at 300 (8 bytes): roll 1.5, pitch -2.0; reply: 52 bytes read
    fc23 = H("17 00C8 001A 012C 0004 08 3FC00000 C0000000")
    pairs = [
        (frame(transport, 1, READ_PDU), frame(transport, 1, READ_REPLY_PDU)),
        (frame(transport, 2, fc23), frame(transport, 2, H("17 34") + FEEDBACK)),
    ]
    with expected_protocol(transport, pairs) as stand:
        t_send, s = stand.send_setpoint_and_read({"roll": 1.5, "pitch": -2.0})
    assert s.angle_deg == {"roll": 1.5, "pitch": -2.0} and t_send <= s.t_host


@REALTIME
def test_setpoint_and_read_without_fc23_is_two_requests(tmp_path: Path) -> None:
    rmap = tmp_path / "no_fc23.yaml"
    rmap.write_text(
        MAP.read_text().replace("read_write_multiple: true", "read_write_multiple: false")
    )
    pairs = [
        (frame("tcp", 1, READ_PDU), frame("tcp", 1, READ_REPLY_PDU)),
        (frame("tcp", 2, SETPOINT_PDU), frame("tcp", 2, SETPOINT_REPLY_PDU)),
        (frame("tcp", 3, READ_PDU), frame("tcp", 3, READ_REPLY_PDU)),
    ]
    with expected_protocol("tcp", pairs, register_map=rmap) as stand:
        stand.send_setpoint_and_read({"roll": 1.5, "pitch": -2.0})
