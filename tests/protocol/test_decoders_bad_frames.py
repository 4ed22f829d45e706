"""A bad frame is a counted bad frame, always.

Every decoder turns any input into a sample or a counted bad frame (``FrameStats.count_bad``),
never an exception that would end a run; a real link failure is still a lost link.

- property tests (hypothesis, bounded example counts): arbitrary text lines and bytes to the
  NMEA 0183 driver per sentence type, arbitrary bytes to the slcan line reader and to the
  ``SlcanBus`` (over pyserial's ``loop://``), arbitrary CAN ids / DLC / data / flags to the
  CANopen (TPDO, EMCY, heartbeat, SDO), J1939 and NMEA 2000 drivers through the CAN reader's
  own poll; no exception escapes and the counts add up;
- byte-exact examples of the known failures, through the real transports (a pty).

One file (about 670 lines) on purpose: every decoder against the same contract (a sample or a
counted bad frame), the property tests and the byte-exact examples side by side.
"""

from __future__ import annotations

import random
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import can
import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from repo_paths import ROOT
from wire import read_all, wait_until

from benchctl.config import InstrumentConfig
from benchctl.devices.base import InstrumentSample
from benchctl.devices.can.canopen_incl import CanopenInclinometer
from benchctl.devices.can.j1939 import J1939SlopeSensor
from benchctl.devices.can.nmea2000 import Nmea2000Attitude
from benchctl.devices.can.slcan import MAX_LINE, SlcanBus, SlcanLineError, parse_line
from benchctl.devices.instrument import open_instrument
from benchctl.devices.nmea0183 import Nmea0183Instrument, with_checksum
from benchctl.devices.nmea0183 import parse_line as parse_nmea
from benchctl.devices.reader import BAD_REASONS, BadFrame, LinkLost, SensorReader
from benchctl.sim.instrument import damage_bytes
from benchctl.sim.pty_port import PtyPort

DRIVERS = ROOT / "drivers"
NODE = 10
PROPS = settings(max_examples=200, deadline=None,
                 suppress_health_check=[HealthCheck.too_slow])


# ------------------------------------------------------------------------------ helpers
def counted(dev: SensorReader) -> int:
    """Inputs the driver has accounted for: samples, bad frames, service frames."""
    return dev.stats.good + dev.stats.bad_total + dev.service_frames


def handle_all(dev: SensorReader, items: list[Any]) -> None:
    """What the reader thread does with what ``_poll`` returned (``SensorReader._run``), except
    that an exception other than ``BadFrame`` escapes here and fails the test."""
    for item in items:
        try:
            dev._handle(item, time.monotonic())
        except BadFrame as b:
            assert b.reason in BAD_REASONS
            dev.stats.count_bad(b.reason)


class FakePort:
    """A serial port that hands out what the test gave it (for the NMEA 0183 driver's poll)."""

    def __init__(self) -> None:
        self.data = bytearray()

    @property
    def in_waiting(self) -> int:
        return len(self.data)

    def read(self, n: int) -> bytes:
        out = bytes(self.data[:n])
        del self.data[:n]
        return out

    def close(self) -> None:
        pass


class FakeBus:
    """A CAN bus whose ``recv`` returns the queued frames or raises the queued exceptions."""

    def __init__(self) -> None:
        self.queue: list[can.Message | BaseException] = []

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if not self.queue:
            return None
        item = self.queue.pop(0)
        if isinstance(item, BaseException):
            raise item
        return item

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass

    def shutdown(self) -> None:
        pass


def poll_all(dev: Any, bus: FakeBus) -> None:
    """Run the CAN reader's poll and handle until the fake bus is empty."""
    while bus.queue:
        handle_all(dev, [item for item, _ in dev._poll()])


def nmea_cfg(sentence: str | None = None, **kw: Any) -> InstrumentConfig:
    return InstrumentConfig(driver="nmea0183", serial_port="fake", sentence=sentence, **kw)


def can_cfg(driver: str, **kw: Any) -> InstrumentConfig:
    extra: dict[str, Any] = {
        "canopen": {"eds": DRIVERS / "cia410_inclinometer.eds", "node_id": NODE},
        "j1939": {"dbc": DRIVERS / "j1939_slope.dbc"},
        "nmea2000": {"dbc": DRIVERS / "nmea2000_attitude.dbc"},
    }[driver]
    return InstrumentConfig(driver=driver, interface="virtual", channel="bad-frames",
                            **{**extra, **kw})


@contextmanager
def can_driver(driver: str, **kw: Any) -> Iterator[tuple[Any, FakeBus]]:
    cls = {"canopen": CanopenInclinometer, "j1939": J1939SlopeSensor,
           "nmea2000": Nmea2000Attitude}[driver]
    bus = FakeBus()
    dev = cls(bus, can_cfg(driver, **kw), owns_bus=False)  # type: ignore[arg-type]
    try:
        yield dev, bus
    finally:
        dev.close()


@pytest.fixture
def pty() -> Iterator[PtyPort]:
    p = PtyPort()
    yield p
    p.close()


# ------------------------------------------------------------------------------ strategies
def _field() -> st.SearchStrategy[str]:
    """A field of a sentence: mostly plausible, sometimes anything printable."""
    number = st.floats(allow_nan=True, allow_infinity=True, width=32).map(lambda v: f"{v:.2f}")
    return st.one_of(
        st.just(""),
        number,
        st.integers(-1000, 1000).map(str),
        st.sampled_from(["T", "M", "P", "B", "A", "D", "PTCH", "PITCH", "ROLL", "R", "POS",
                         "HPR", "nan", "inf", "1e5", "+", "-", ".", "1_0", " 1"]),
        st.from_regex(r"\A[0-9]{4,7}(\.[0-9]{0,4})?\Z"),  # times of day, valid or not
        st.text(alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E), max_size=8),
    )


def sentence_body(kind: str) -> st.SearchStrategy[str]:
    """``kind``'s name and any fields."""
    head = {"PASHR": st.just("PASHR"), "PHTRO": st.just("PHTRO"),
            "XDR": st.sampled_from(["IIXDR", "HEXDR", "YXXDR"])}[kind]
    return st.builds(lambda h, f: ",".join([h, *f]), head, st.lists(_field(), max_size=13))


def near_valid_body(kind: str) -> st.SearchStrategy[str]:
    """``kind`` with its fields in place, each plausible or not."""
    num = st.one_of(st.floats(-200, 200).map(lambda v: f"{v:+.2f}"), _field())
    rest = st.lists(_field(), max_size=6)
    if kind == "PASHR":
        tod = st.one_of(st.just(""), st.from_regex(r"\A[0-9]{6}(\.[0-9]{1,3})?\Z"), _field())
        return st.builds(lambda t, h, r, pi, x: ",".join(["PASHR", t, h, "T", r, pi, *x]),
                         tod, num, num, num, rest)
    if kind == "PHTRO":
        return st.builds(lambda pi, m, r, b, x: ",".join(["PHTRO", pi, m, r, b, *x]),
                         num, st.sampled_from(["M", "P", "X", ""]), num,
                         st.sampled_from(["B", "T", "Y", ""]), st.lists(_field(), max_size=1))
    def quad(*names: str) -> st.SearchStrategy[tuple[str, ...]]:
        return st.tuples(st.sampled_from(["A", "A", "A", "C", ""]), num,
                         st.sampled_from(["D", "D", "D", "R"]), st.sampled_from(names))

    return st.builds(
        lambda t, qs, x: ",".join([f"{t}XDR", *[f for q in qs for f in q], *x]),
        st.sampled_from(["II", "HE"]),
        st.tuples(quad("PTCH", "PITCH"), quad("ROLL", "roll"), quad("HEAD", "PTCH", "")).map(
            lambda qs: list(qs[:2]) + list(qs[2:] if qs[2][3] else [])),
        st.lists(_field(), max_size=1),
    )


def lines_with_checksum(kind: str) -> st.SearchStrategy[str]:
    """Sentences of ``kind`` with a valid checksum and any fields: they reach the parser."""
    return st.one_of(near_valid_body(kind), sentence_body(kind)).map(with_checksum)


any_text = st.text(max_size=100)
ascii_text = st.text(alphabet=st.characters(max_codepoint=0x7F), max_size=100)


# ------------------------------------------------------------------------------ NMEA 0183
def _check_nmea_lines(dev: Nmea0183Instrument, kind: str) -> None:
    @PROPS
    @given(lines=st.lists(st.one_of(lines_with_checksum(kind), any_text, ascii_text),
                          min_size=1, max_size=8))
    def check(lines: list[str]) -> None:
        before = counted(dev)
        items = [ln.encode("utf-8", errors="surrogatepass") for ln in lines]
        handle_all(dev, items)
        assert counted(dev) - before == len(items)

    check()


@pytest.mark.parametrize("kind", ["PASHR", "PHTRO", "XDR"])
@pytest.mark.parametrize("configured", [False, True], ids=["any-sentence", "this-sentence"])
def test_nmea_any_sentence_is_a_sample_or_a_counted_bad_frame(kind: str, configured: bool) -> None:
    dev = Nmea0183Instrument(FakePort(), nmea_cfg(kind if configured else None))
    _check_nmea_lines(dev, kind)
    dev.close()
    assert dev.stats.good > 0 and dev.stats.bad_total > 0  # both ends were reached


@PROPS
@given(line=st.one_of(lines_with_checksum("PASHR"), lines_with_checksum("PHTRO"),
                      lines_with_checksum("XDR"), any_text),
       sentence=st.sampled_from([None, "PASHR", "PHTRO", "XDR"]))
def test_nmea_parse_line_raises_only_bad_frame(line: str, sentence: str | None) -> None:
    try:
        a = parse_nmea(line, sentence=sentence)
    except BadFrame as b:
        assert b.reason in BAD_REASONS
        return
    assert set(a.angle_deg) <= {"roll", "pitch"}
    assert all(abs(v) <= 180.0 for v in a.angle_deg.values())
    assert a.device_time_s is None or 0.0 <= a.device_time_s < 86401.0


def test_nmea_any_bytes_on_the_serial_line() -> None:
    """Arbitrary byte chunks (line ends included) through the driver's own poll and handle:
    every line it splits off is counted once, garbage without a line end counted too."""
    port = FakePort()
    dev = Nmea0183Instrument(port, nmea_cfg())
    good = b"$PHTRO,1.50,M,2.25,B*" + with_checksum("PHTRO,1.50,M,2.25,B")[-2:].encode()

    @PROPS
    @given(chunks=st.lists(st.one_of(st.binary(max_size=120), st.just(b"\r\n"),
                                     st.just(good + b"\r\n")), max_size=10))
    def check(chunks: list[bytes]) -> None:
        for chunk in chunks:
            port.data += chunk
            bad_before = dev.stats.bad_total
            before = counted(dev)
            items = [item for item, _ in dev._poll()]
            overflow = dev.stats.bad_total - bad_before  # garbage without a line end
            handle_all(dev, items)
            assert counted(dev) - before == len(items) + overflow

    check()
    dev.close()


# known failures, byte-exact (every checksum valid: the lines reach the parsers)
PASHR_LEAP = "$PASHR,235960.000,224.19,T,-01.26,+00.83,+00.00,0.101,0.113,0.267,1,0*05"


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("$PASHR*58", "length"),  # was IndexError inside pynmea2
        ("$PASHR,245960.000,224.19,T,-01.26,+00.83*28", "range"),  # hour 24
        ("$PASHR,2359.000,224.19,T,-01.26,+00.83*29", "decode"),  # not hhmmss
        ("$PASHR,POS,224.19,T,-01.26,+00.83*76", "id"),  # another Ashtech sentence
        ("$IIXDR*4E", "length"),
        ("$PHTRO,inf,M,1.00,T*36", "decode"),  # float() would take it
        ("$PHTRO,1e1,M,1.00,T*32", "decode"),  # no exponents in NMEA 0183
        ("$IIXDR,A,1*,D,PTCH*5F", "decode"),  # pynmea2 cannot split it
        ("$PHTRO,1.00,M,\x001.00,T*48", "decode"),  # a control character
    ],
)
def test_nmea_known_bad_lines(line: str, reason: str) -> None:
    assert line == with_checksum(line[1:line.rindex("*")])
    with pytest.raises(BadFrame) as e:
        parse_nmea(line)
    assert e.value.reason == reason


def test_pashr_leap_second_is_a_sample() -> None:
    """23:59:60.000 UTC (a leap second) was an AttributeError from pynmea2's time parsing."""
    assert with_checksum(PASHR_LEAP[1:-3]) == PASHR_LEAP
    a = parse_nmea(PASHR_LEAP)
    assert a.angle_deg == {"roll": -1.26, "pitch": 0.83}
    assert a.device_time_s == 86400.0


def test_nmea_driver_counts_the_known_failures_over_a_pty(pty: PtyPort) -> None:
    cfg = InstrumentConfig(driver="nmea0183", serial_port=pty.path)
    dev = open_instrument(cfg)
    got: list[InstrumentSample] = []
    errors: list[BaseException] = []
    good = with_checksum("PHTRO,1.50,M,2.25,B")
    try:
        dev.start(got.append, errors.append)
        for chunk in (
            b"$PASHR*58\r\n",  # length
            PASHR_LEAP.encode() + b"\r\n",  # a sample
            b"$PASHR,245960.000,224.19,T,-01.26,+00.83*28\r\n",  # range
            b"$PHTRO,1.50,M,\xc3\xa9,B*00\r\n",  # UTF-8 beyond ASCII: decode
            b"\x00\x07\x1b[2J\r\n",  # control characters: decode
            good.encode() + b"\r\n",
        ):
            assert pty.write(chunk)
        wait_until(lambda: dev.stats.good >= 2)
    finally:
        dev.close()
    assert errors == []
    assert dev.stats.bad == {"length": 1, "range": 1, "decode": 2}
    assert got[0].device_time_s == 86400.0 and got[1].angle_deg == {"pitch": 1.5, "roll": -2.25}


# ------------------------------------------------------------------------------ slcan lines
HEXCHARS = "0123456789ABCDEFabcdef"
slcan_like = st.builds(
    lambda k, body: (k + body).encode("ascii"),
    st.sampled_from(["t", "T", "r", "R", "z", "Z", "d", "x", ""]),
    st.text(alphabet=HEXCHARS + "GZ ", max_size=34),
)


@PROPS
@given(line=st.one_of(st.binary(max_size=80), slcan_like))
def test_slcan_parse_line_is_a_frame_an_answer_or_a_line_error(line: bytes) -> None:
    try:
        msg = parse_line(line)
    except SlcanLineError as e:
        assert isinstance(e, ValueError) and e.line == line
        return
    if msg is None:
        assert line in (b"", b"z", b"Z")
        return
    assert line.isascii() and line[:1] in (b"t", b"T", b"r", b"R")
    assert msg.arbitration_id <= (0x1FFFFFFF if msg.is_extended_id else 0x7FF)
    assert 0 <= msg.dlc <= 8 and len(msg.data) == (0 if msg.is_remote_frame else msg.dlc)


def test_slcan_parse_line_examples() -> None:
    m = parse_line(b"t18A4E80318FC")
    assert m is not None and m.arbitration_id == 0x18A and bytes(m.data) == bytes.fromhex(
        "E80318FC")
    m = parse_line(b"t18A4E80318FC04D2")  # with a Z1 timestamp
    assert m is not None and bytes(m.data) == bytes.fromhex("E80318FC")
    m = parse_line(b"R0CF013802")
    assert m is not None and m.is_remote_frame and m.is_extended_id and m.dlc == 2
    for bad in (b"t18A4E803", b"t18A4E80318FC0", b"t18A9" + b"00" * 9, b"t8004E80318FC",
                b"T2000000000", b"t18A4\xff\xfe0318FC", b"t18A4E803 8FC", b"t-1A0", b"t+1A0",
                b"t18\xd9\xa3" + b"E80318FC", b"F00", b"V1013", b"d18A4E80318FC"):
        with pytest.raises(SlcanLineError):
            parse_line(bad)


@contextmanager
def loop_bus() -> Iterator[SlcanBus]:
    bus = SlcanBus("loop://", bitrate=500000, sleep_after_open=0)
    try:
        bus.flush()  # what it sent on open (C, S6, O) came back on the loop
        yield bus
    finally:
        bus.shutdown()


def recv_outcomes(bus: SlcanBus) -> list[str]:
    """Read until nothing is left: "frame" per message, "bad" per SlcanLineError."""
    out: list[str] = []
    for _ in range(10_000):
        try:
            msg = bus.recv(timeout=0)
        except SlcanLineError:
            out.append("bad")
            continue
        if msg is None:
            return out
        out.append("frame")
    raise AssertionError("never ran dry")


def expected_outcomes(data: bytes) -> list[str]:
    """What every CR- or BEL-terminated line of ``data`` must give (``parse_line``'s rules)."""
    out: list[str] = []
    line = b""
    for b in data:
        if b not in (0x0D, 0x07):
            line += bytes([b])
            continue
        if b == 0x07:
            if line:
                out.append("bad")
        else:
            try:
                if parse_line(line) is not None:
                    out.append("frame")
            except SlcanLineError:
                out.append("bad")
        line = b""
    return out


def test_slcan_bus_any_bytes_on_the_serial_line() -> None:
    frame = st.sampled_from([b"t18A4E80318FC", b"T0CF013808F47E387CFFFFF014", b"z", b"",
                             b"t70A105", b"r18A4"])
    with loop_bus() as bus:

        @PROPS
        @given(parts=st.lists(st.tuples(st.one_of(frame, st.binary(max_size=40), slcan_like),
                                        st.sampled_from([b"\r", b"\a", b""])), max_size=8))
        def check(parts: list[tuple[bytes, bytes]]) -> None:
            data = b"".join(a + b for a, b in parts) + b"\r"  # the last line ends too
            bus.serialPortOrig.write(data)
            assert recv_outcomes(bus) == expected_outcomes(data)

        check()


def test_slcan_bus_drops_garbage_without_a_line_end() -> None:
    with loop_bus() as bus:
        bus.serialPortOrig.write(b"\x80" * (MAX_LINE + 1))
        with pytest.raises(SlcanLineError, match="no CR"):
            bus.recv(timeout=0)
        bus.serialPortOrig.write(b"t18A4E80318FC\r")
        msg = bus.recv(timeout=0)
        assert msg is not None and msg.arbitration_id == 0x18A


# ------------------------------------------------------------------------------ CAN drivers
def _ids(driver: str) -> st.SearchStrategy[int]:
    if driver == "canopen":
        special = [0x180 + NODE, 0x80 + NODE, 0x700 + NODE, 0x580 + NODE, 0x600 + NODE, 0x80,
                   0x000, 0x7FF, 0x181]
        return st.one_of(st.sampled_from(special), st.integers(0, 0x7FF),
                         st.integers(-5, 2**32))
    pgn = 61459 if driver == "j1939" else 127257
    return st.one_of(
        st.builds(lambda p, sa: p << 26 | pgn << 8 | sa, st.integers(0, 7), st.integers(0, 255)),
        st.integers(0, 0x1FFFFFFF), st.integers(-5, 2**32),
    )


def frames(driver: str) -> st.SearchStrategy[can.Message]:
    data = st.one_of(st.binary(min_size=8, max_size=8), st.binary(max_size=64),
                     st.sampled_from([b"\xff\x7f\xff\x7f", b"\x00\x80\x00\x80", b"\x05",
                                      b"\x00", b"\x7f", b"\x85", b"\x33"]))
    return st.builds(
        lambda cid, ext, d, remote, error: can.Message(
            arbitration_id=cid, is_extended_id=ext, data=d, dlc=len(d), is_remote_frame=remote,
            is_error_frame=error, check=False),
        _ids(driver), st.booleans(), data,
        st.sampled_from([False] * 9 + [True]), st.sampled_from([False] * 9 + [True]),
    )


@pytest.mark.parametrize("driver", ["canopen", "j1939", "nmea2000"])
def test_can_any_frame_is_a_sample_a_counted_bad_frame_or_a_service_frame(driver: str) -> None:
    kw: dict[str, Any] = {"source_address": 0x80} if driver == "j1939" else {}
    with can_driver(driver, **kw) as (dev, bus):

        @PROPS
        @given(msgs=st.lists(frames(driver), min_size=1, max_size=10))
        def check(msgs: list[can.Message]) -> None:
            before = counted(dev)
            bus.queue.extend(msgs)
            poll_all(dev, bus)
            assert counted(dev) - before == len(msgs)

        check()
        assert dev.stats.bad_total > 0
        assert set(dev.stats.bad) <= set(BAD_REASONS)


def _tpdo(pitch: int, roll: int) -> bytes:
    return pitch.to_bytes(2, "little", signed=True) + roll.to_bytes(2, "little", signed=True)


@pytest.mark.parametrize("driver", ["canopen", "j1939", "nmea2000"])
def test_can_any_payload_of_the_right_id_and_length(driver: str) -> None:
    """Arbitrary bytes of the exact length on the exact id reach the deepest decoding."""
    cid, n = {"canopen": (0x180 + NODE, 4), "j1939": (0x0CF01380, 8),
              "nmea2000": (0x09F11980, 8)}[driver]
    with can_driver(driver) as (dev, bus):

        @PROPS
        @given(payloads=st.lists(st.binary(min_size=n, max_size=n), min_size=1, max_size=10))
        def check(payloads: list[bytes]) -> None:
            before = counted(dev)
            bus.queue.extend(can.Message(arbitration_id=cid, is_extended_id=driver != "canopen",
                                         data=p) for p in payloads)
            poll_all(dev, bus)
            assert counted(dev) - before == len(payloads)

        check()
        assert dev.stats.good > 0


@pytest.mark.parametrize(
    ("cid", "data", "outcome"),
    [
        (0x80 + NODE, b"\x10\x81\x01", "length"),  # EMCY, DLC 3: was struct.error
        (0x80 + NODE, b"", "length"),  # EMCY, DLC 0
        (0x80 + NODE, bytes.fromhex("1081010000000000"), "service"),  # EMCY 8110h, register 1
        (0x700 + NODE, b"", "length"),  # heartbeat, DLC 0: was struct.error
        (0x700 + NODE, b"\x05\x00", "length"),  # heartbeat, DLC 2
        (0x700 + NODE, b"\x33", "range"),  # no NMT state
        (0x700 + NODE, b"\x85", "service"),  # node guarding answer: operational, toggle set
        (0x580 + NODE, bytes.fromhex("43001000"), "length"),  # SDO answer, DLC 4
        (0x580 + NODE, bytes.fromhex("4300100092010000"), "service"),
        (0x180 + NODE, bytes.fromhex("E80318FC00"), "length"),  # TPDO, DLC 5
        (0x180 + NODE, bytes.fromhex("0080E803"), "range"),  # INTEGER16 minimum: overflow
        (0x180 + NODE, bytes.fromhex("E80318FC"), "good"),
        (0x600 + NODE, bytes(8), "id"),  # an SDO request (another master's): not ours to read
    ],
)
def test_canopen_service_frames_of_any_dlc(cid: int, data: bytes, outcome: str) -> None:
    with can_driver("canopen") as (dev, bus):
        bus.queue.append(can.Message(arbitration_id=cid, is_extended_id=False, data=data))
        poll_all(dev, bus)
        got = ("good" if dev.stats.good else "service" if dev.service_frames
               else next(iter(dev.stats.bad)))
        assert got == outcome
        assert counted(dev) == 1


J1939_SSI = bytes.fromhex("F47E387CFFFFF014")  # pitch +1.0°, roll −0.4°, FOM ok, 10 ms
N2K_ATT = bytes.fromhex("07FF7FD1068CEBFF")  # SID 7, pitch 0.1745 rad, roll −0.5236 rad


@pytest.mark.parametrize(
    ("driver", "cid", "ext", "data", "outcome"),
    [
        ("j1939", 0x0CF01380, True, J1939_SSI, "good"),
        ("j1939", 0x0CF01380, True, b"", "length"),
        ("j1939", 0x0CF01380, True, J1939_SSI[:7], "length"),
        ("j1939", 0x0CF01380, True, J1939_SSI + b"\x00", "length"),  # DLC 9 (FD length 9+)
        ("j1939", 0x0CF01380, True, J1939_SSI * 8, "length"),  # 64 bytes (CAN FD)
        ("j1939", 0x2CF01380, True, J1939_SSI, "id"),  # beyond 29 bits, the PGN bits match
        ("j1939", 0x380, False, J1939_SSI, "id"),  # 11-bit
        ("j1939", -0x0CF01380, True, J1939_SSI, "id"),
        ("nmea2000", 0x09F11980, True, N2K_ATT, "good"),
        ("nmea2000", 0x09F11980, True, N2K_ATT[:3], "length"),
        ("nmea2000", 0xE9F11980, True, N2K_ATT, "id"),
        ("nmea2000", 0x09F11980, True, bytes.fromhex("07FF7FFF7F8CEBFF"), "range"),
    ],
)
def test_dbc_frames_of_any_id_and_dlc(driver: str, cid: int, ext: bool, data: bytes,
                                      outcome: str) -> None:
    with can_driver(driver) as (dev, bus):
        bus.queue.append(can.Message(arbitration_id=cid, is_extended_id=ext, data=data,
                                     dlc=len(data), check=False))
        poll_all(dev, bus)
        assert counted(dev) == 1
        assert (dev.stats.good == 1) if outcome == "good" else (dev.stats.bad == {outcome: 1})


def test_can_remote_and_error_frames_are_counted() -> None:
    with can_driver("nmea2000") as (dev, bus):
        bus.queue += [
            can.Message(arbitration_id=0x09F11980, is_remote_frame=True, dlc=8),
            can.Message(is_error_frame=True),
        ]
        poll_all(dev, bus)
        assert dev.stats.bad == {"id": 1, "decode": 1}


def _operation_error(cause: BaseException) -> can.CanOperationError:
    try:
        try:
            raise cause
        except BaseException as c:
            raise can.CanOperationError("Could not read from serial device") from c
    except can.CanOperationError as e:
        return e


def test_can_reader_tells_line_noise_from_a_lost_link() -> None:
    noise = [
        _operation_error(UnicodeDecodeError("utf-8", b"\xff", 0, 1, "invalid start byte")),
        SlcanLineError("not a frame", b"?"),
        ValueError("non-hexadecimal number found in fromhex() arg"),  # python-can's parser
        IndexError("string index out of range"),
    ]
    with can_driver("j1939") as (dev, bus):
        bus.queue += noise
        poll_all(dev, bus)
        assert dev.stats.bad == {"decode": len(noise)}
        for gone in (_operation_error(serial.SerialException("device reports readiness to "
                                                             "read but returned no data")),
                     _operation_error(OSError(5, "Input/output error")), OSError(19, "No such "
                                                                                 "device")):
            bus.queue.append(gone)
            with pytest.raises(LinkLost):
                dev._poll()


def _can_on_pty(pty: PtyPort, dev: Any, lines: list[bytes], n: int) -> list[BaseException]:
    errors: list[BaseException] = []
    try:
        read_all(pty, b"O\rO\r")
        dev.start(lambda s: None, errors.append)
        for line in lines:
            assert pty.write(line)
        wait_until(lambda: counted(dev) >= n)
        # nothing more arrives: the last frame is a good one and is counted last
    finally:
        dev.close()
    return errors


SLCAN_NOISE = [
    b"t18A4\xff\xfe0318FC\r",  # not UTF-8: python-can raised CanOperationError (a "lost link")
    b"\x00\x1b[A\xc3\xa9\r",  # control characters, UTF-8 beyond ASCII
    b"t18A4E803\r",  # hex digits missing
    b"#garbage\r",  # an unknown line: python-can dropped it without a word
]
CANOPEN_SERVICE = [
    b"t08A3108101\r",  # EMCY, DLC 3
    b"t70A0\r",  # heartbeat, DLC 0
    b"t70A20500\r",  # heartbeat, DLC 2
    b"t58A443001000\r",  # SDO answer, DLC 4
    b"t70A105\r",  # heartbeat: operational (a service frame)
]
GOOD_TPDO = b"t18A4E80318FC\r"


def test_canopen_known_failures_over_slcan_on_a_pty(pty: PtyPort) -> None:
    cfg = InstrumentConfig(driver="canopen", interface="slcan", channel=pty.path, node_id=NODE,
                           eds=DRIVERS / "cia410_inclinometer.eds")
    dev = open_instrument(cfg)
    lines = [GOOD_TPDO, *SLCAN_NOISE, *CANOPEN_SERVICE, GOOD_TPDO]
    errors = _can_on_pty(pty, dev, lines, len(lines))
    assert errors == []
    assert dev.stats.good == 2 and dev.service_frames == 1
    assert dev.stats.bad == {"decode": 4, "length": 4}


def test_stock_python_can_slcan_recovers_from_a_non_utf8_line(pty: PtyPort) -> None:
    """A bus opened by python-can itself (not ``open_instrument``) handed to a driver: the line
    python-can cannot decode is one ``decode`` bad frame, and the next lines are read again."""
    bus = can.Bus(interface="slcan", channel=pty.path, bitrate=500000, sleep_after_open=0)
    cfg = InstrumentConfig(driver="canopen", interface="slcan", channel=pty.path, node_id=NODE,
                           eds=DRIVERS / "cia410_inclinometer.eds")
    dev = CanopenInclinometer(bus, cfg)
    errors = _can_on_pty(pty, dev, [SLCAN_NOISE[0], GOOD_TPDO, GOOD_TPDO], 3)
    assert errors == []
    assert dev.stats.good == 2 and dev.stats.bad == {"decode": 1}


# ------------------------------------------------------------------------------ sim garbling
@PROPS
@given(seed=st.integers(0, 2**32),
       line=st.sampled_from([b"t18A4E80318FC\r", b"T09F1198008FF7FD1068CEBFF\r",
                             (PASHR_LEAP + "\r\n").encode(), b"z\r"]))
def test_sim_byte_damage_is_one_line_and_never_valid(seed: int, line: bytes) -> None:
    """The simulator's ``garbled how=bytes``: the line end kept, none inside, a byte beyond
    ASCII, so the slcan reader and the NMEA driver both count it (``decode``)."""
    out = damage_bytes(line, random.Random(seed))
    end = b"\r\n" if line.endswith(b"\r\n") else b"\r"
    assert out.endswith(end)
    body = out[: -len(end)]
    assert not any(b in b"\r\n\a" for b in body)
    assert not body.isascii()
    assert len(line) - len(end) - 3 <= len(body) <= len(line) - len(end) + 3
    with pytest.raises(SlcanLineError):
        parse_line(body)
    dev = Nmea0183Instrument(FakePort(), nmea_cfg())
    handle_all(dev, [body])
    assert dev.stats.bad == {"decode": 1}
