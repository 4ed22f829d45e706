"""Shared helpers of the byte-level tests: Modbus RTU framing, waiting on a pty."""

from __future__ import annotations

import select
import time
from collections.abc import Callable

from benchctl.sim.pty_port import PtyPort


def crc16_modbus(frame: bytes) -> bytes:
    """CRC-16/MODBUS (poly 0xA001 reflected, init 0xFFFF), low byte first on the wire."""
    crc = 0xFFFF
    for b in frame:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc.to_bytes(2, "little")


def rtu(pdu: bytes, unit: int = 1) -> bytes:
    """An RTU frame: unit id, PDU, CRC."""
    return bytes([unit]) + pdu + crc16_modbus(bytes([unit]) + pdu)


def wait_until(cond: Callable[[], bool], timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met within the deadline")
        time.sleep(0.01)


def read_all(port: PtyPort, until: bytes, timeout: float = 5.0) -> bytes:
    """What the pty's far end sends until ``until`` appears (or the timeout)."""
    got = b""
    deadline = time.monotonic() + timeout
    assert port.master_fd is not None
    while until not in got and time.monotonic() < deadline:
        select.select([port.master_fd], [], [], 0.05)
        got += port.read()
    return got
