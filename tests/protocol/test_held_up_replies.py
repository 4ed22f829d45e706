"""A host stall during a Modbus exchange costs the stall, never a reply timeout.

The client runs in a child process that this test stops (SIGSTOP) while it waits for a reply,
and the scripted peer answers while it is stopped — the reply arrives during the host's stall,
and the child is held up for twice its reply timeout. The order is fixed by the test (request
seen, child stopped, reply written, child continued), not left to the scheduler: what the
child does after it is continued is deterministic.

- Modbus TCP: the reply that arrived during the stall is read at once after it (the socket
  wait is the kernel's, restarted after the stop with the time it had left), and a late reply
  to an earlier try of a request (a transaction id already answered) is skipped without waiting
  out the timeout: both hold with pymodbus's own client, and are kept here as evidence;
- Modbus RTU: pymodbus's serial client judged its reply timeout on the wall clock and gave up
  without a last look at the line, so a reply that arrived during a stall longer than the time
  it had left was thrown away by the retry (``Cleanup recv buffer before send``) and the
  request sent again — without a retry left, the run ended on "no reply". The link now takes
  what arrived before it gives up (``link._SerialClient``).
"""

from __future__ import annotations

import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
import tty
from collections.abc import Callable

import pytest
from repo_paths import ROOT
from wire import rtu

from benchctl.devices.modbus.link import tcp_link

# real sockets and pseudo-terminals, a child stopped by a real SIGSTOP, timed on the host's
# clock: run alone (realtime tier)
pytestmark = pytest.mark.realtime

REPLY_S = 0.2  # the child's reply timeout
HOLD_S = 2 * REPLY_S  # how long the child is stopped, the reply arriving meanwhile
SETTLE_S = 0.05  # after the request is seen: the child is in its wait for the reply

CHILD = """
import json, sys, time
from benchctl.devices.modbus.link import rtu_link, tcp_link
kind, where, reply_s = sys.argv[1], sys.argv[2], float(sys.argv[3])
if kind == "tcp":
    link = tcp_link("127.0.0.1", int(where), timeout_s=reply_s, retries=1)
else:
    link = rtu_link(where, baudrate=115200, timeout_s=reply_s, retries=1)
link.connect()
for i in range(3):
    t0 = time.monotonic()
    try:
        out = {"value": link.read_registers(0, 2)[0]}
    except Exception as e:
        out = {"error": f"{type(e).__name__}: {e}"}
    out["rtt_s"] = time.monotonic() - t0
    print(json.dumps(out), flush=True)
link.close()
"""


class _Peer:
    """A scripted Modbus peer answering each FC3 request with its request count as the first
    register; the second request is answered while the client is stopped."""

    def __init__(self, read: Callable[[], bytes | None], write: Callable[[bytes, bytes], None]):
        self.read = read  # the next request frame, or None when the client hung up
        self.write = write  # (request, reply PDU) -> send the framed reply
        self.requests: list[bytes] = []
        self.stopped_for: float | None = None
        self.done = threading.Event()  # the child has exited

    def serve(self, child: subprocess.Popen[str]) -> None:
        while (req := self.read()) is not None:
            self.requests.append(req)
            n = len(self.requests)
            pdu = bytes([3, 4]) + n.to_bytes(2, "big") + b"\x00\x00"
            if n != 2:
                self.write(req, pdu)
                continue
            time.sleep(SETTLE_S)
            os.kill(child.pid, signal.SIGSTOP)
            t0 = time.monotonic()
            try:
                self.write(req, pdu)  # the reply arrives while the client is stopped
                time.sleep(HOLD_S)
            finally:
                os.kill(child.pid, signal.SIGCONT)
                self.stopped_for = time.monotonic() - t0


def _run_child(kind: str, where: str, peer: _Peer) -> list[dict[str, object]]:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, kind, where, str(REPLY_S)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    th = threading.Thread(target=peer.serve, args=(child,), daemon=True)
    th.start()
    try:
        out, err = child.communicate(timeout=60)
    finally:
        peer.done.set()
        if child.poll() is None:
            os.kill(child.pid, signal.SIGCONT)
            child.kill()
            child.wait()
    th.join(10)
    assert child.returncode == 0, err
    return [json.loads(line) for line in out.splitlines()]


def _check(results: list[dict[str, object]], peer: _Peer) -> None:
    assert peer.stopped_for is not None and peer.stopped_for >= HOLD_S
    assert [r.get("value") for r in results] == [1, 2, 3], results  # each its own reply
    assert len(peer.requests) == 3, "a request was sent again: the reply of the stall was lost"
    # the held-up exchange cost the stall and no reply timeout on top of it
    rtt = float(results[1]["rtt_s"])  # type: ignore[arg-type]
    assert rtt < peer.stopped_for + SETTLE_S + 0.5 * REPLY_S + 0.5, results


def test_tcp_a_reply_that_arrives_during_a_stall_is_taken_after_it() -> None:
    srv = socket.create_server(("127.0.0.1", 0))
    conn: list[socket.socket] = []

    def read() -> bytes | None:
        if not conn:
            conn.append(srv.accept()[0])
        head = _recv_exactly(conn[0], 6)
        if head is None:
            return None
        rest = _recv_exactly(conn[0], int.from_bytes(head[4:6], "big"))
        return None if rest is None else head + rest

    def write(req: bytes, pdu: bytes) -> None:
        conn[0].sendall(req[:4] + (len(pdu) + 1).to_bytes(2, "big") + req[6:7] + pdu)

    peer = _Peer(read, write)
    try:
        _check(_run_child("tcp", str(srv.getsockname()[1]), peer), peer)
    finally:
        for s in (*conn, srv):
            s.close()


def test_rtu_a_reply_that_arrives_during_a_stall_is_taken_after_it() -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)

    def read() -> bytes | None:
        buf = b""
        while len(buf) < 8:  # an FC3 request: unit, 03, address, count, CRC
            r, _, _ = select.select([master], [], [], 0.05)
            if peer.done.is_set():
                return None
            if not r:
                continue
            try:
                chunk = os.read(master, 8 - len(buf))
            except OSError:  # the client closed the line
                return None
            if not chunk:
                return None
            buf += chunk
        return buf

    def write(req: bytes, pdu: bytes) -> None:
        os.write(master, rtu(pdu, unit=req[0]))

    peer = _Peer(read, write)
    try:
        _check(_run_child("rtu", os.ttyname(slave), peer), peer)
    finally:
        os.close(master)
        os.close(slave)


def _recv_exactly(s: socket.socket, n: int) -> bytes | None:
    buf = b""
    while len(buf) < n:
        chunk = s.recv(n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return buf


def test_tcp_a_late_reply_to_an_earlier_try_is_skipped_without_waiting_out_the_timeout() -> None:
    """The first try of request 2 is answered after the client's timeout, and both tries are
    answered: the late first reply answers the retry, the retry's own reply (the same
    transaction id, answered already) is skipped by the next exchange, which takes its own."""
    srv = socket.create_server(("127.0.0.1", 0))
    seen: list[int] = []

    def serve() -> None:
        c, _ = srv.accept()
        with c:
            while (head := _recv_exactly(c, 6)) is not None:
                rest = _recv_exactly(c, int.from_bytes(head[4:6], "big"))
                assert rest is not None
                req = head + rest
                seen.append(int.from_bytes(head[:2], "big"))
                n = len(seen)
                pdu = bytes([3, 4]) + n.to_bytes(2, "big") + b"\x00\x00"
                if n == 2:
                    time.sleep(1.5 * REPLY_S)  # the client has given up on this try
                c.sendall(req[:4] + (len(pdu) + 1).to_bytes(2, "big") + req[6:7] + pdu)

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    link = tcp_link("127.0.0.1", srv.getsockname()[1], timeout_s=REPLY_S, retries=1)
    link.connect()
    try:
        got, rtts = [], []
        for _ in range(3):
            t0 = time.monotonic()
            got.append(link.read_registers(0, 2)[0])
            rtts.append(time.monotonic() - t0)
    finally:
        link.close()
        srv.close()
    th.join(5)
    assert seen[:3] == [1, 2, 2]  # request 2 tried twice
    assert got[0] == 1 and got[1] in (2, 3) and got[2] == 4  # never another request's reply
    assert rtts[1] < 2 * REPLY_S + 0.3 and rtts[2] < REPLY_S, rtts

