"""The simulated stand when it is held up itself (not scheduled on a loaded host computer).

- its watchdog counts the host's heartbeat silence, not its own hold-up: the host's heartbeats
  waited unread in its socket meanwhile (a stand's controller would have read them);
- it answers every request, several arriving in one read included — a client that gave up on
  the reply of the held-up simulator sends its request again, and both copies are read at
  once; pymodbus's server answered only the first of two, none of two trajectory-push-sized
  writes (it throws its buffer away past 264 bytes), and lost any request behind the one it
  answered (sending a reply empties its buffer).

The hold-up is made by holding the simulator's state lock (its physics thread and its request
handling both wait on it), then advancing its physics as its physics thread does on waking —
on simulated time (the stand over an in-process link); several requests in one read of a real
socket on the host's time (``realtime``).
"""

from __future__ import annotations

import socket
import struct
import time

import pytest
from stand_rig import LIMITS, MAP, simulated

from benchctl.clock.virtual import VirtualClock
from benchctl.config import SimStandConfig
from benchctl.devices.modbus.regmap import pdu_address
from benchctl.devices.modbus.regmap_load import load_register_map
from benchctl.sim.stand import SIM_HOLDUP_S, SimStand

WATCHDOG_S = 0.6


def test_the_watchdog_does_not_count_the_simulators_own_hold_up(vclock: VirtualClock) -> None:
    with simulated(SimStandConfig(watchdog_s=WATCHDOG_S), "tcp", vclock) as (sim, stand):
        stand.enable()
        stand.heartbeat()
        with sim._lock:  # the simulator held up for twice its watchdog, heartbeats waiting
            vclock.sleep(2 * WATCHDOG_S)
            sim._advance(vclock.monotonic())  # as its physics thread, first on waking
            assert sim._fault_code == 0, "the simulator's own hold-up counted as silence"
        stand.heartbeat()
        assert not stand.read_status().fault
        # the host's own silence still trips it, in its time
        t_last = vclock.monotonic()
        while not stand.read_status().fault:
            assert vclock.monotonic() - t_last < WATCHDOG_S + 2.0, "the watchdog never fired"
            vclock.sleep(0.02)
        assert vclock.monotonic() - t_last >= WATCHDOG_S - 0.05


def test_repeated_hold_ups_do_not_hide_a_silent_host(vclock: VirtualClock) -> None:
    """Only the time the simulator was held up is discounted, not the silence around it."""
    with simulated(SimStandConfig(watchdog_s=WATCHDOG_S), "tcp", vclock) as (sim, stand):
        stand.enable()
        stand.heartbeat()
        t_last = vclock.monotonic()
        held = 0.0
        while not stand.read_status().fault:
            assert vclock.monotonic() - t_last < 5 * WATCHDOG_S, "a silent host hidden"
            with sim._lock:
                vclock.sleep(1.5 * SIM_HOLDUP_S)
                sim._advance(vclock.monotonic())
            held += 1.5 * SIM_HOLDUP_S
            vclock.sleep(0.1)
        silent = vclock.monotonic() - t_last
        assert silent - held >= WATCHDOG_S - 0.1  # the host's silence, not less


def _mbap(tid: int, pdu: bytes) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, 1) + pdu


def _replies(c: socket.socket, n: int, timeout_s: float = 5.0) -> list[tuple[int, int]]:
    """(transaction id, function code) of the next ``n`` replies, or of all within the time."""
    buf, out = b"", []
    deadline = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < deadline:
        c.settimeout(max(0.01, deadline - time.monotonic()))
        try:
            chunk = c.recv(4096)
        except TimeoutError:
            break
        if not chunk:
            break
        buf += chunk
        while len(buf) >= 6 and len(buf) >= 6 + int.from_bytes(buf[4:6], "big"):
            size = 6 + int.from_bytes(buf[4:6], "big")
            out.append((int.from_bytes(buf[:2], "big"), buf[7]))
            buf = buf[size:]
    return out


@pytest.mark.realtime  # several requests in one read of a real socket
def test_every_request_of_one_read_is_answered_in_order() -> None:
    m = load_register_map(MAP)
    table = pdu_address(m.axes["roll"].table_address)
    feedback, count = m.feedback_span()
    read = bytes([3]) + struct.pack(">HH", pdu_address(feedback), count)
    n = 99  # registers: a write as long as a trajectory push of 24 points on two axes
    write = bytes([16]) + struct.pack(">HHB", table, n, 2 * n) + b"\x00\x00" * n
    with SimStand(SimStandConfig(), limits=LIMITS, register_map=MAP) as sim, \
            socket.create_connection(("127.0.0.1", sim.port)) as c:
        # a request and its copy sent again, in one read: both answered
        c.sendall(_mbap(1, read) + _mbap(1, read))
        assert _replies(c, 2) == [(1, 3), (1, 3)]
        # two long writes together (beyond pymodbus's 264-byte buffer), then a read behind them
        c.sendall(_mbap(2, write) + _mbap(2, write) + _mbap(3, read))
        assert _replies(c, 3) == [(2, 16), (2, 16), (3, 3)]
        # and the next request alone is answered as its own (nothing left behind)
        c.sendall(_mbap(4, read))
        assert _replies(c, 1) == [(4, 3)]
        assert _replies(c, 1, timeout_s=0.3) == []
