"""Interoperability: what the simulated stand answers to requests a real Modbus master may send.

Raw frames, byte-exact, in the spirit of PyMeasure's expected_protocol: Modbus TCP ADUs over a
plain socket to a ``SimStand`` on 127.0.0.1, and RTU frames (with their CRC) over its pty. The
expected replies are written out from the Modbus Application Protocol V1.1b3: an exception
response is the request's function code | 0x80 and one exception code — 01 ILLEGAL FUNCTION for
a function code outside the register map, 02 ILLEGAL DATA ADDRESS outside the map, 03 ILLEGAL
DATA VALUE for a bad quantity, byte count or PDU length. Another unit id: exception 0x0B on TCP,
silence on RTU (unit id 0: a broadcast write, acted on, never answered). Then the driver's view
(``ModbusException`` with function and exception code) and ``ModbusStand.reset_fault`` waiting
for a stand that clears its fault on a later scan.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import socket
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, cast

import pytest
from repo_paths import ROOT
from wire import rtu

from benchctl.channels import Endpoint, free_name, register, unregister
from benchctl.clock import REAL, Clock, RealClock
from benchctl.clock.virtual import VirtualClock
from benchctl.config import SimStandConfig, StandLimits
from benchctl.devices.base import StandLimitsView
from benchctl.devices.modbus.link import ModbusLink, rtu_link, tcp_link
from benchctl.devices.modbus.regmap import RegisterMap, pdu_address
from benchctl.devices.modbus.regmap_load import load_register_map
from benchctl.devices.modbus.stand import ModbusStand
from benchctl.errors import DeviceTimeout, ModbusException, StandFault
from benchctl.sim.stand import SimStand

# real sockets and pseudo-terminals, timed on the host's clock: run alone (realtime tier); the
# RTU silences (another unit id, a broadcast) on simulated time over an in-process line
REALTIME = pytest.mark.realtime

MAP = ROOT / "drivers" / "stand_generic.yaml"
LIMITS = StandLimits(angle_deg=20.0, rate_deg_s=30.0, accel_deg_s2=200.0)
REPLY_S = 5.0  # generous: the machine is loaded
SILENCE_S = 1.0  # how long "no reply" is listened for
TID = 0x1234
H = bytes.fromhex
IDENTITY_READ = H("03 0000 0002")  # FC3, the first two identity registers: vendor "benc"
IDENTITY_REPLY = H("03 04 6265 6E63")
HB_ECHO_READ = H("03 00CA 0001")  # FC3 at 202: the heartbeat echo


def mbap(pdu: bytes, unit: int = 1, tid: int = TID) -> bytes:
    return (
        tid.to_bytes(2, "big")
        + b"\x00\x00"
        + (len(pdu) + 1).to_bytes(2, "big")
        + bytes([unit])
        + pdu
    )


def test_crc_helper_matches_the_specification_example() -> None:
    assert rtu(H("03 0000 000A")) == H("01 03 0000 000A C5CD")


@pytest.fixture(autouse=True)
def no_server_complaints(caplog: pytest.LogCaptureFixture) -> Iterator[None]:
    """Nothing the stand is sent here may make the server log a warning, an error or a traceback."""
    caplog.set_level(logging.WARNING)
    yield
    bad = [f"{r.name} {r.levelname}: {r.getMessage()}" for r in caplog.records]
    assert not bad, bad


@pytest.fixture(scope="module")
def tcp_sim() -> Iterator[SimStand]:
    with SimStand(SimStandConfig(), limits=LIMITS, register_map=MAP, transport="tcp") as sim:
        yield sim


@pytest.fixture(scope="module")
def rtu_sim() -> Iterator[SimStand]:
    with SimStand(SimStandConfig(), limits=LIMITS, register_map=MAP, transport="rtu") as sim:
        yield sim


@pytest.fixture
def rtu_line_sim(vclock: VirtualClock) -> Iterator[SimStand]:
    """The stand on an RTU line of its own on simulated time (an in-process link): what must
    not be answered is listened for SILENCE_S at no cost."""
    with SimStand(SimStandConfig(), limits=LIMITS, register_map=MAP, transport="channel",
                  framing="rtu", clock=vclock) as sim:
        yield sim


# -- Modbus TCP -------------------------------------------------------------------------------
def recv_exactly(sock: socket.socket, n: int, deadline: float) -> bytes:
    buf = b""
    while len(buf) < n:
        left = deadline - time.monotonic()
        if left <= 0:
            break
        sock.settimeout(left)
        try:
            chunk = sock.recv(n - len(buf))
        except TimeoutError:
            break
        if not chunk:
            break
        buf += chunk
    return buf


def tcp_exchange(sim: SimStand, adu: bytes) -> bytes:
    """Send one ADU on a fresh connection; the whole reply ADU (header + length), or what came."""
    with socket.create_connection(("127.0.0.1", sim.port), timeout=REPLY_S) as sock:
        sock.sendall(adu)
        deadline = time.monotonic() + REPLY_S
        head = recv_exactly(sock, 6, deadline)
        if len(head) < 6:
            return head
        return head + recv_exactly(sock, int.from_bytes(head[4:6], "big"), deadline)


# (request PDU, expected reply PDU), unit id 1
TCP_CASES = {
    # 01 ILLEGAL FUNCTION: every function code outside the map (holding registers 3/6/16/23)
    "fc0": ("00", "80 01"),
    "fc1 read coils": ("01 0000 0001", "81 01"),
    "fc2 read discrete inputs": ("02 0000 0001", "82 01"),
    "fc4 read input registers": ("04 0000 0001", "84 01"),
    "fc5 write single coil": ("05 0000 FF00", "85 01"),
    "fc7 read exception status (serial line only)": ("07", "87 01"),
    "fc8 diagnostics, return query data (serial line only)": ("08 0000 1234", "88 01"),
    "fc11 get comm event counter (serial line only)": ("0B", "8B 01"),
    "fc15 write multiple coils": ("0F 0000 0001 01 01", "8F 01"),
    "fc17 report server id (serial line only)": ("11", "91 01"),
    "fc22 mask write register": ("16 0064 FFFF 0000", "96 01"),
    "fc24 read FIFO queue": ("18 0000", "98 01"),
    "fc43 read device identification": ("2B 0E 01 00", "AB 01"),
    "fc65 (no such function)": ("41 0000", "C1 01"),
    # 03 ILLEGAL DATA VALUE: quantity, byte count, PDU length
    "fc3 count 0": ("03 0000 0000", "83 03"),
    "fc3 count 126 > 125": ("03 0000 007E", "83 03"),
    "fc3 count 121 > the map's max_read_registers 120": ("03 0000 0079", "83 03"),
    "fc3 PDU too short": ("03 0000", "83 03"),
    "fc6 PDU too long": ("06 0065 0001 00", "86 03"),
    "fc16 count 0": ("10 012C 0000 00", "90 03"),
    "fc16 count 124 > 123": ("10 012C 007C F8" + "00" * 248, "90 03"),
    "fc16 byte count != 2 x count": ("10 012C 0002 02 0000", "90 03"),
    "fc16 fewer bytes than the byte count": ("10 012C 0002 04 0000", "90 03"),
    "fc23 read count 0": ("17 0000 0000 012C 0001 02 0000", "97 03"),
    "fc23 write count 0": ("17 0000 0001 012C 0000 00", "97 03"),
    "fc23 write count 122 > 121": ("17 0000 0001 012C 007A F4" + "00" * 244, "97 03"),
    "fc23 byte count != 2 x write count": ("17 0000 0001 012C 0002 02 0000", "97 03"),
    # 02 ILLEGAL DATA ADDRESS: outside the map, in a gap of it, or read-only for a write
    "fc3 beyond the map": ("03 9000 0001", "83 02"),
    "fc3 in a gap of the map": ("03 001E 0001", "83 02"),
    "fc3 running off the identity block": ("03 001C 0002", "83 02"),
    "fc3 past address 65535": ("03 FFFF 0002", "83 02"),
    "fc6 to a read-only register": ("06 00C8 0001", "86 02"),
    "fc6 beyond the map": ("06 9000 0001", "86 02"),
    "fc16 beyond the map": ("10 9000 0001 02 0000", "90 02"),
    "fc23 write beyond the map": ("17 0000 0001 9000 0001 02 0000", "97 02"),
    "fc23 read beyond the map": ("17 9000 0001 012C 0002 04 00000000", "97 02"),
    # and what the map has, answered
    "fc3 identity": (IDENTITY_READ.hex(), IDENTITY_REPLY.hex()),
}


@REALTIME
@pytest.mark.parametrize(("request_pdu", "reply_pdu"), TCP_CASES.values(), ids=TCP_CASES.keys())
def test_tcp_reply_bytes(tcp_sim: SimStand, request_pdu: str, reply_pdu: str) -> None:
    got = tcp_exchange(tcp_sim, mbap(H(request_pdu)))
    assert got.hex(" ") == mbap(H(reply_pdu)).hex(" ")


@REALTIME
@pytest.mark.parametrize(
    ("unit", "request_pdu", "reply_pdu"),
    [
        (2, IDENTITY_READ.hex(), "83 0B"),
        (0, IDENTITY_READ.hex(), "83 0B"),
        (247, "01 0000 0001", "81 0B"),
        (255, "06 0065 4321", "86 0B"),
    ],
)
def test_tcp_other_unit_id_is_gateway_target_failed_to_respond(
    tcp_sim: SimStand, unit: int, request_pdu: str, reply_pdu: str
) -> None:
    before = tcp_exchange(tcp_sim, mbap(HB_ECHO_READ))
    got = tcp_exchange(tcp_sim, mbap(H(request_pdu), unit=unit))
    assert got.hex(" ") == mbap(H(reply_pdu), unit=unit).hex(" ")
    assert tcp_exchange(tcp_sim, mbap(HB_ECHO_READ)) == before  # not acted on


@REALTIME
def test_tcp_fc23_with_a_read_beyond_the_map_writes_nothing(tcp_sim: SimStand) -> None:
    """Both spans are checked before anything is written (pymodbus alone writes, then refuses)."""
    before = tcp_exchange(tcp_sim, mbap(HB_ECHO_READ))
    assert before != mbap(H("03 02 5A5A"))
    assert tcp_exchange(tcp_sim, mbap(H("17 9000 0001 0065 0001 02 5A5A"))) == mbap(H("97 02"))
    assert tcp_exchange(tcp_sim, mbap(HB_ECHO_READ)) == before


@REALTIME
def test_tcp_fc23_refused_when_the_map_has_no_read_write_multiple(tmp_path: Path) -> None:
    rmap = tmp_path / "no_fc23.yaml"
    text = MAP.read_text()
    assert "read_write_multiple: true" in text
    rmap.write_text(text.replace("read_write_multiple: true", "read_write_multiple: false"))
    fc23 = H("17 0000 0002 012C 0002 04 00000000")
    with SimStand(SimStandConfig(), limits=LIMITS, register_map=rmap) as sim:
        assert tcp_exchange(sim, mbap(fc23)) == mbap(H("97 01"))
        assert tcp_exchange(sim, mbap(IDENTITY_READ)) == mbap(IDENTITY_REPLY)


@REALTIME
def test_tcp_requests_on_one_connection_after_refusals(tcp_sim: SimStand) -> None:
    """A refused request leaves the connection usable (pipelined on one socket, tids kept)."""
    with socket.create_connection(("127.0.0.1", tcp_sim.port), timeout=REPLY_S) as sock:
        for tid, pdu, reply in [
            (1, H("04 0000 0001"), H("84 01")),
            (2, H("03 0000 0000"), H("83 03")),
            (3, IDENTITY_READ, IDENTITY_REPLY),
        ]:
            sock.sendall(mbap(pdu, tid=tid))
            want = mbap(reply, tid=tid)
            got = recv_exactly(sock, len(want), time.monotonic() + REPLY_S)
            assert got.hex(" ") == want.hex(" ")


# -- Modbus RTU over the pty ------------------------------------------------------------------
class Line:
    """The master's end of the stand's serial line: its pty (a file descriptor, the host's
    time) or, on simulated time, the host end of its in-process link."""

    def __init__(self, fd: int | None = None, endpoint: Endpoint | None = None) -> None:
        self.fd, self.endpoint = fd, endpoint
        self.clock: Clock = endpoint.clock if endpoint is not None else REAL

    def write(self, data: bytes) -> None:
        if self.endpoint is not None:
            self.endpoint.write(data)
        else:
            assert self.fd is not None
            os.write(self.fd, data)

    def read_some(self, within_s: float) -> bytes:
        """What has come, waiting up to ``within_s`` for a first byte (b"": nothing)."""
        if self.endpoint is not None:
            return self.endpoint.read(512, within_s)
        assert self.fd is not None
        if not select.select([self.fd], [], [], within_s)[0]:
            return b""
        return os.read(self.fd, 512)


@contextlib.contextmanager
def rtu_port(sim: SimStand) -> Iterator[Line]:
    if sim.client_endpoint is not None:  # an in-process link (simulated time)
        yield Line(endpoint=sim.client_endpoint)
        return
    assert sim.serial_port is not None
    fd = os.open(sim.serial_port, os.O_RDWR | os.O_NOCTTY)
    try:
        tty.setraw(fd)
        yield Line(fd=fd)
    finally:
        os.close(fd)


def rtu_read(line: Line, n: int, within_s: float) -> bytes:
    """Bytes received within ``within_s`` (returns early once ``n`` have come)."""
    buf = b""
    clock = line.clock
    deadline = clock.monotonic() + within_s
    while len(buf) < n:
        left = deadline - clock.monotonic()
        got = line.read_some(left) if left > 0 else b""
        if not got:
            break
        buf += got
    return buf


def rtu_exchange(line: Line, frame: bytes, reply_len: int) -> bytes:
    line.write(frame)
    return rtu_read(line, reply_len, REPLY_S)


def rtu_silent(line: Line, frame: bytes) -> bytes:
    """Send a frame and return whatever comes back within SILENCE_S (expected: nothing)."""
    line.write(frame)
    return rtu_read(line, 1, SILENCE_S)


RTU_CASES = {
    "fc4 read input registers": ("04 0000 0001", "84 01"),
    "fc7 read exception status": ("07", "87 01"),
    "fc8 diagnostics, return query data": ("08 0000 1234", "88 01"),
    "fc17 report server id": ("11", "91 01"),
    "fc65 (no such function)": ("41 0000", "C1 01"),
    "fc3 count 0": ("03 0000 0000", "83 03"),
    "fc16 byte count != 2 x count": ("10 012C 0002 02 0000", "90 03"),
    "fc3 beyond the map": ("03 9000 0001", "83 02"),
    "fc3 identity": (IDENTITY_READ.hex(), IDENTITY_REPLY.hex()),
}


@REALTIME
@pytest.mark.parametrize(("request_pdu", "reply_pdu"), RTU_CASES.values(), ids=RTU_CASES.keys())
def test_rtu_reply_bytes(rtu_sim: SimStand, request_pdu: str, reply_pdu: str) -> None:
    want = rtu(H(reply_pdu))
    with rtu_port(rtu_sim) as fd:
        got = rtu_exchange(fd, rtu(H(request_pdu)), len(want))
        got += rtu_read(fd, 1, 0.05)  # nothing more follows
    assert got.hex(" ") == want.hex(" ")


@pytest.mark.parametrize("unit", [2, 247, 255])
def test_rtu_other_unit_id_is_silence(rtu_line_sim: SimStand, unit: int) -> None:
    with rtu_port(rtu_line_sim) as fd:
        before = rtu_exchange(fd, rtu(HB_ECHO_READ), 7)
        assert rtu_silent(fd, rtu(IDENTITY_READ, unit=unit)) == b""
        assert rtu_silent(fd, rtu(H("06 0065 4321"), unit=unit)) == b""
        assert rtu_silent(fd, rtu(H("41 0000"), unit=unit)) == b""  # not even an exception
        # the line is still served, and the write to the other unit was not acted on
        assert rtu_exchange(fd, rtu(HB_ECHO_READ), 7) == before


def test_rtu_broadcast_write_is_acted_on_and_not_answered(rtu_line_sim: SimStand) -> None:
    with rtu_port(rtu_line_sim) as fd:
        assert rtu_silent(fd, rtu(H("06 0065 2468"), unit=0)) == b""  # heartbeat 0x2468
        assert rtu_silent(fd, rtu(IDENTITY_READ, unit=0)) == b""  # a broadcast read: ignored
        want = rtu(H("03 02 2468"))
        assert rtu_exchange(fd, rtu(HB_ECHO_READ), len(want)).hex(" ") == want.hex(" ")


# -- the driver's view: ModbusLink errors -----------------------------------------------------
def link_to(sim: SimStand, device_id: int = 1) -> ModbusLink:
    if sim.client_endpoint is not None:  # an in-process RTU line (simulated time)
        url = register(free_name("sim-stand"), sim.client_endpoint)
        link = rtu_link(url, device_id=device_id, timeout_s=REPLY_S, retries=0, clock=sim.clock)
    elif sim.transport == "tcp":
        link = tcp_link("127.0.0.1", sim.port, device_id=device_id, timeout_s=REPLY_S, retries=0)
    else:
        assert sim.serial_port is not None
        link = rtu_link(sim.serial_port, device_id=device_id, timeout_s=REPLY_S, retries=0)
    link.connect()
    return link


@REALTIME
@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_link_raises_modbus_exception_with_function_and_exception_code(
    request: pytest.FixtureRequest, transport: str
) -> None:
    sim: SimStand = request.getfixturevalue(f"{transport}_sim")
    link = link_to(sim)
    try:
        cases: list[tuple[Any, int, int]] = [
            (lambda: link.read_registers(0x9000, 1), 3, 2),
            (lambda: link.read_registers(0, 121), 3, 3),  # above the map's 120, within 125
            (lambda: link.write_registers(0x9000, [0]), 16, 2),
            (lambda: link.write_register(200, 1), 6, 2),  # the status word is read-only
        ]
        for call, fc, code in cases:
            with pytest.raises(ModbusException) as err:
                call()
            assert (err.value.function_code, err.value.exception_code) == (fc, code)
        assert link.read_registers(0, 2) == [0x6265, 0x6E63]
    finally:
        link.close()


@REALTIME
def test_link_to_another_unit_tcp_is_exception_0x0b(tcp_sim: SimStand) -> None:
    link = link_to(tcp_sim, device_id=2)
    try:
        with pytest.raises(ModbusException) as err:
            link.read_registers(0, 2)
        assert (err.value.function_code, err.value.exception_code) == (3, 0x0B)
        assert "gateway target device failed to respond" in str(err.value)
    finally:
        link.close()


def test_link_to_another_unit_rtu_times_out(
    rtu_line_sim: SimStand, caplog: pytest.LogCaptureFixture
) -> None:
    link = link_to(rtu_line_sim, device_id=2)
    try:
        with pytest.raises(DeviceTimeout):
            link.read_registers(0, 2)
    finally:
        link.close()
        unregister(link.endpoint.split()[1].rsplit("@", 1)[0])
    caplog.clear()  # the pymodbus *client* logs its own "no response" error; that is expected


# -- reset_fault waits for the stand's next scan ----------------------------------------------
class LatchedFaultLink:
    """A stand behind a fake link with a latched fault: a fault reset takes effect only after
    ``clear_after`` further status reads (as a stand acting on its next scan), or never."""

    endpoint = "fake-stand"

    def __init__(self, regmap: RegisterMap, code: int, clear_after: int | None) -> None:
        self.map = regmap
        self.code = code
        self.clear_after = clear_after
        self.reads_after_reset: int | None = None  # None until the reset is written
        self.writes: list[tuple[int, int]] = []

    def connect(self) -> None:
        pass

    def close(self) -> None:
        pass

    def write_register(self, address: int, value: int) -> None:
        self.writes.append((address, value))
        m = self.map
        if (
            address == pdu_address(m.control_word.address)
            and value >> m.control_bits["fault_reset"] & 1
        ):
            self.reads_after_reset = 0

    def read_registers(self, address: int, count: int) -> list[int]:
        m = self.map
        if self.reads_after_reset is not None:
            self.reads_after_reset += 1
            if self.clear_after is not None and self.reads_after_reset > self.clear_after:
                self.code = 0
        words = [0] * count
        bits = ["fault"] if self.code else ["ready"]
        for f, v in (
            (m.status_word, m.word_from_bits(m.status_bits, bits)),
            (m.fault_code, self.code),
        ):
            i = pdu_address(f.address) - address
            if 0 <= i < count:
                words[i : i + f.n_registers] = m.encode(f, v)
        return words


class _ReadClock(RealClock):
    """The real clock whose ``monotonic`` is the test's function."""

    def __init__(self, read: Callable[[], float]) -> None:
        self.read = read

    def monotonic(self) -> float:
        return self.read()


def stand_on(link: LatchedFaultLink, clock: Callable[[], float]) -> ModbusStand:
    return ModbusStand(
        cast(ModbusLink, link),
        link.map,
        limits=StandLimitsView(30.0, 20.0, 100.0),
        clock=_ReadClock(clock),
    )


def test_reset_fault_waits_until_the_stand_clears_it() -> None:
    link = LatchedFaultLink(load_register_map(MAP), code=10, clear_after=3)
    # a frozen clock: the deadline never passes, only the stand clearing the fault ends the wait
    stand = stand_on(link, clock=lambda: 0.0)
    stand.reset_fault(timeout_s=1.0)
    assert link.reads_after_reset == 4  # three reads still faulted, the fourth clear, then done
    m = link.map
    assert link.writes == [(m.control_word.address, 1 << m.control_bits["fault_reset"])]


def test_reset_fault_raises_with_the_code_if_still_faulted_after_the_bound() -> None:
    link = LatchedFaultLink(load_register_map(MAP), code=42, clear_after=None)
    now = [0.0]

    def clock() -> float:  # every look at the clock is 0.1 s later
        now[0] += 0.1
        return now[0]

    stand = stand_on(link, clock)
    with pytest.raises(StandFault) as err:
        stand.reset_fault(timeout_s=1.0)
    assert err.value.code == 42 and "42" in str(err.value)
    assert link.reads_after_reset is not None and 1 < link.reads_after_reset < 20
    assert now[0] >= 1.0  # it gave up only after the bound, on the stand's clock
