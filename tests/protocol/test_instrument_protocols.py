"""Byte-exact protocol tests of the instrument drivers and the slcan adapter.

The drivers run on their real transports (python-can's slcan over a pseudo-terminal, pyserial
on a pseudo-terminal); the test writes exact bytes on the other end, as a device would.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Iterator
from pathlib import Path

import can
import pytest
from repo_paths import ROOT
from wire import read_all, wait_until

from benchctl.config import InstrumentConfig
from benchctl.devices.base import AngleSensor, InstrumentSample
from benchctl.devices.instrument import open_instrument
from benchctl.devices.nmea0183 import parse_line
from benchctl.devices.reader import BadFrame
from benchctl.errors import ConfigError
from benchctl.sim.pty_port import PtyPort
from benchctl.sim.slcan import SlcanAdapter, frame_line, parse_frame

DRIVERS = ROOT / "drivers"


@pytest.fixture
def pty() -> Iterator[PtyPort]:
    p = PtyPort()
    yield p
    p.close()


def _xor(body: str) -> str:
    c = 0
    for ch in body:
        c ^= ord(ch)
    return f"{c:02X}"


# ---------------------------------------------------------------- slcan adapter (LAWICEL)
def test_slcan_adapter_commands() -> None:
    sent: list[can.Message] = []
    a = SlcanAdapter(500_000, sent.append)
    # what python-can sends on open: C, S6, an empty line, then O twice
    assert [a.feed(c) for c in (b"C\r", b"S6\r", b"\r", b"O\r", b"O\r")] == [b"\r"] * 5
    assert a.forwarding
    assert a.feed(b"S4\r") == b"\a"  # bitrate only while closed
    assert a.feed(b"V\r") == b"V1013\r"
    assert a.feed(b"N\r") == b"NSIM1\r"
    assert a.feed(b"t60A") == b""  # a command split across reads
    assert a.feed(b"84008100000000000\r") == b"z\r"
    assert sent[-1].arbitration_id == 0x60A and bytes(sent[-1].data) == bytes.fromhex(
        "4008100000000000")
    assert a.feed(b"T0CF013FE1AA\r") == b"Z\r"
    assert sent[-1].is_extended_id and sent[-1].arbitration_id == 0x0CF013FE
    assert a.feed(b"t60A9\r") == b"\a"  # DLC 9
    assert a.feed(b"t60A2AA\r") == b"\a"  # 2 bytes announced, 1 given
    assert a.feed(b"Q\r") == b"\a"
    assert a.feed(b"C\rL\r") == b"\r\r"
    assert a.feed(b"t60A0\r") == b"\a"  # listen-only: no transmit


def test_slcan_frame_lines_and_bitrate() -> None:
    msg = can.Message(arbitration_id=0x18A, is_extended_id=False, data=bytes.fromhex("E80318FC"))
    assert frame_line(msg) == b"t18A4E80318FC\r"
    ext = can.Message(arbitration_id=0x09F11911, is_extended_id=True, data=b"\x01\x02")
    assert frame_line(ext) == b"T09F1191120102\r"
    assert frame_line(msg, timestamp_ms=61_234) == b"t18A4E80318FC04D2\r"
    assert parse_frame("t18A4E80318FC") is not None
    assert parse_frame("t18AGE80318FC") is None
    a = SlcanAdapter(500_000, lambda m: None)
    assert a.line_for(msg, 0.0) is None  # closed
    a.feed(b"S5\rO\r")  # 250 kbit/s on a 500 kbit/s bus: nothing but error frames
    assert a.line_for(msg, 0.0) is None
    a.feed(b"C\rS6\rZ1\rO\r")
    assert a.line_for(msg, 1.5) == b"t18A4E80318FC05DC\r"


@pytest.mark.parametrize(("stamps", "z"), [(True, b"Z1"), (False, b"Z0")])
def test_python_can_open_and_close_bytes(pty: PtyPort, stamps: bool, z: bytes) -> None:
    """The exact bytes python-can's slcan sends on open and on shutdown, with our timestamp
    command while the channel is still closed (LAWICEL takes ``Z`` only then)."""
    cfg = InstrumentConfig(driver="nmea2000", interface="slcan", channel=pty.path,
                           dbc=DRIVERS / "nmea2000_attitude.dbc", adapter_timestamps=stamps)
    dev = open_instrument(cfg)
    assert read_all(pty, b"O\rO\r") == b"C\rS6\r\r" + z + b"\rO\rO\r"
    dev.close()
    assert read_all(pty, b"C\r") == b"C\r"


# ---------------------------------------------------------------- CAN drivers over slcan
def _run_can(pty: PtyPort, cfg: InstrumentConfig, lines: list[bytes], n_expected: int,
             log: Path | None = None) -> tuple[list[InstrumentSample], dict[str, int], int]:
    dev = open_instrument(cfg, can_log_path=log)
    got: list[InstrumentSample] = []
    errors: list[BaseException] = []
    try:
        read_all(pty, b"O\rO\r")
        dev.start(got.append, errors.append)
        for line in lines:
            assert pty.write(line)
        wait_until(lambda: dev.stats.good + dev.stats.bad_total >= n_expected)
        time.sleep(0.1)  # nothing more may arrive
    finally:
        dev.close()
    assert errors == []
    return got, dict(dev.stats.bad), dev.stats.good


def test_canopen_tpdo_bytes(pty: PtyPort) -> None:
    cfg = InstrumentConfig(driver="canopen", interface="slcan", channel=pty.path, node_id=10,
                           eds=DRIVERS / "cia410_inclinometer.eds")
    lines = [
        b"t18A4E80318FC\r",  # 6010h = 1000, 6020h = −1000 at 0.01°: pitch +10°, roll −10°
        b"t18A3E80318\r",  # 3 bytes: length
        b"t18A4FF7F0000\r",  # 0x7FFF: overflow marker → range
        b"t18A43075E803\r",  # 30000 · 0.01° = 300° > 180° → range
        b"t18B4E80318FC\r",  # node 11's TPDO1: unknown id
        b"t18A4G80318FC\r",  # not hex: the adapter line is garbled → decode
        b"t18A40100FFFF\r",  # pitch 0.01°, roll −0.01°
    ]
    got, bad, good = _run_can(pty, cfg, lines, 7)
    assert good == 2
    assert bad == {"length": 1, "range": 2, "id": 1, "decode": 1}
    assert got[0].angle_deg == {"roll": -10.0, "pitch": 10.0}
    assert got[1].angle_deg == pytest.approx({"roll": -0.01, "pitch": 0.01}, abs=1e-12)
    assert got[0].counter is None and got[0].device_time_s is None


def test_adapter_timestamps_reach_the_samples_unwrapped(pty: PtyPort) -> None:
    """Frames with a Z1 timestamp give their samples ``adapter_time_s``: the adapter's ms clock
    in seconds, continuous across its wrap at 60 000 ms; a service frame between two samples
    counts too, and a frame without a timestamp gives None."""
    cfg = InstrumentConfig(driver="canopen", interface="slcan", channel=pty.path, node_id=10,
                           eds=DRIVERS / "cia410_inclinometer.eds")
    lines = [
        b"t18A4E80318FCEA4C\r",  # 59 980 ms
        b"t70A105EA56\r",  # heartbeat (operational) at 59 990 ms: a service frame
        b"t18A40100FFFF0004\r",  # 4 ms after the wrap: 60 004 ms
        b"t18A40100FFFF\r",  # no timestamp
    ]
    got, bad, good = _run_can(pty, cfg, lines, 3)
    assert good == 3 and bad == {}
    assert got[0].adapter_time_s == pytest.approx(59.980, abs=1e-12)
    assert got[1].adapter_time_s == pytest.approx(60.004, abs=1e-12)
    assert got[2].adapter_time_s is None


def test_j1939_ssi_bytes(pty: PtyPort) -> None:
    cfg = InstrumentConfig(driver="j1939", interface="slcan", channel=pty.path,
                           dbc=DRIVERS / "j1939_slope.dbc", source_address=0x80)
    # pitch 32500 · 0.002 − 64 = +1.0°, roll 31800 → −0.4°, pitch rate n/a, FOM ok/ok/na/na,
    # latency 20 · 0.5 ms = 10 ms
    good_line = b"T0CF013808F47E387CFFFFF014\r"
    lines = [
        good_line,
        b"T18F013808F47E387CFFFFF014\r",  # priority 6: still PGN 61459 → accepted
        b"T0CF013818F47E387CFFFFF014\r",  # source 0x81, config wants 0x80: id
        b"T0CF014808F47E387CFFFFF014\r",  # PGN 61460: id
        b"T0CF013807F47E387CFFFFF0\r",  # 7 bytes: length
        b"T0CF01380800FF387CFFFFF014\r",  # pitch 0xFF00 not available: range
        b"T0CF013808F47E387CFFFFF814\r",  # pitch FOM = 10 error: status
        b"t0CF8F47E387CFFFFF014\r",  # an 11-bit frame: id
    ]
    got, bad, good = _run_can(pty, cfg, lines, 8)
    assert good == 2
    assert bad == {"id": 3, "length": 1, "range": 1, "status": 1}
    s = got[0]
    assert s.angle_deg == pytest.approx({"pitch": 1.0, "roll": -0.4}, abs=1e-9)
    assert s.device_time_s == pytest.approx(s.t_host - 0.010, abs=1e-12)


def test_nmea2000_attitude_bytes_and_raw_log(pty: PtyPort, tmp_path: Path) -> None:
    cfg = InstrumentConfig(driver="nmea2000", interface="slcan", channel=pty.path,
                           dbc=DRIVERS / "nmea2000_attitude.dbc")
    # SID 7, yaw n/a, pitch 1745 · 1e-4 rad, roll −5236 · 1e-4 rad
    lines = [
        b"T09F11911807FF7FD1068CEBFF\r",
        b"T09F11911808FF7FD106FF7FFF\r",  # roll 0x7FFF not available: range
        b"T09F11911808FF7FD1060080FF\r",  # roll −32768 beyond −π: range
        b"T09F11911708FF7FD1068CEB\r",  # 7 bytes: length
        b"T09F11A11809FF7FD1068CEBFF\r",  # PGN 127258: id
        b"T0DF11922809FF7F00000000FF\r",  # priority 3, source 0x22, SID 9: 0°, 0°
    ]
    log = tmp_path / "raw.asc"
    got, bad, good = _run_can(pty, cfg, lines, 6, log=log)
    assert good == 2
    assert bad == {"range": 2, "length": 1, "id": 1}
    assert got[0].counter == 7 and got[1].counter == 9
    assert got[0].angle_deg["pitch"] == pytest.approx(math.degrees(0.1745), abs=1e-9)
    assert got[0].angle_deg["roll"] == pytest.approx(math.degrees(-0.5236), abs=1e-9)
    frames = list(can.LogReader(str(log)))
    assert [f.arbitration_id for f in frames] == [
        0x09F11911, 0x09F11911, 0x09F11911, 0x09F11911, 0x09F11A11, 0x0DF11922]
    assert bytes(frames[0].data) == bytes.fromhex("07FF7FD1068CEBFF")


def test_nmea2000_one_axis_ignores_the_other(pty: PtyPort) -> None:
    cfg = InstrumentConfig(driver="nmea2000", interface="slcan", channel=pty.path, axes=("roll",),
                           dbc=DRIVERS / "nmea2000_attitude.dbc")
    got, bad, good = _run_can(pty, cfg, [b"T09F11911807FF7FFF7F8CEBFF\r"], 1)
    assert good == 1 and bad == {}
    assert list(got[0].angle_deg) == ["roll"]


# ---------------------------------------------------------------- NMEA 0183
KNOWN_PASHR = "$PASHR,085335.000,224.19,T,-01.26,+00.83,+00.00,0.101,0.113,0.267,1,0*06"


def test_nmea_sentences_decode() -> None:
    assert _xor(KNOWN_PASHR[1:-3]) == "06"
    a = parse_line(KNOWN_PASHR)
    assert a.angle_deg == {"roll": -1.26, "pitch": 0.83}
    assert a.device_time_s == pytest.approx(8 * 3600 + 53 * 60 + 35.0)
    body = "PHTRO,1.50,P,2.25,T"  # bow down 1.5°, port up 2.25°
    a = parse_line(f"${body}*{_xor(body)}")
    assert a.angle_deg == {"pitch": -1.5, "roll": 2.25}
    body = "HEXDR,A,-3.5,D,PTCH,A,12.25,D,ROLL"
    a = parse_line(f"${body}*{_xor(body)}")
    assert a.angle_deg == {"pitch": -3.5, "roll": 12.25} and a.talker == "HE"


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        (KNOWN_PASHR[:-2] + "07", "checksum"),
        (KNOWN_PASHR[:-3], "checksum"),  # no checksum
        ("$PHTRO,1.50,M,2.25*" + _xor("PHTRO,1.50,M,2.25"), "length"),
        ("$PHTRO,1.50,M,,B*" + _xor("PHTRO,1.50,M,,B"), "range"),  # roll not available
        ("$PHTRO,91.00,M,2.00,B*" + _xor("PHTRO,91.00,M,2.00,B"), "range"),
        ("$GPGGA,1,2*" + _xor("GPGGA,1,2"), "id"),
        ("$PHTRO,1.50,X,2.00,B*" + _xor("PHTRO,1.50,X,2.00,B"), "decode"),
        ("$" + "PHTRO," + "1" * 90 + "*00", "length"),
    ],
)
def test_nmea_bad_lines(line: str, reason: str) -> None:
    with pytest.raises(BadFrame) as e:
        parse_line(line)
    assert e.value.reason == reason


def test_nmea_driver_bytes(pty: PtyPort) -> None:
    cfg = InstrumentConfig(driver="nmea0183", serial_port=pty.path, sentence="PHTRO")
    dev = open_instrument(cfg)
    got: list[InstrumentSample] = []
    errors: list[BaseException] = []
    good = "$PHTRO,1.50,M,2.25,B*" + _xor("PHTRO,1.50,M,2.25,B")
    try:
        dev.start(got.append, errors.append)
        for chunk in (
            good[:9].encode(), (good[9:] + "\r\n").encode(),  # a line split across reads
            (KNOWN_PASHR + "\r\n").encode(),  # another sentence than configured: id
            b"$PHTRO,1.50,M,2.25,B*00\r\n",  # bad checksum
            b"\xff\xfe\r\n",  # not ASCII: decode
            (good + "\r\n").encode(),
        ):
            pty.write(chunk)
            time.sleep(0.02)
        wait_until(lambda: dev.stats.good + dev.stats.bad_total >= 5)
    finally:
        dev.close()
    assert errors == []
    assert dev.stats.good == 2
    assert dev.stats.bad == {"id": 1, "checksum": 1, "decode": 1}
    assert got[0].angle_deg == {"pitch": 1.5, "roll": -2.25}


def test_unknown_driver_and_leaks_fds(pty: PtyPort) -> None:
    from benchctl.devices.instrument import _load

    with pytest.raises(ConfigError, match="unknown"):
        _load("modbus")
    before = len(os.listdir("/proc/self/fd"))
    cfg = InstrumentConfig(driver="nmea0183", serial_port=pty.path)
    for _ in range(3):
        dev = open_instrument(cfg)
        assert isinstance(dev, AngleSensor)
        dev.start(lambda s: None, lambda e: None)
        dev.close()
        dev.close()  # idempotent
    assert len(os.listdir("/proc/self/fd")) == before
