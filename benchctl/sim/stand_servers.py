"""The simulated stand's servers on the host's time: Modbus TCP on a socket, RTU on a pty.

Both hand every request byte to the stand's one entry point,
:class:`benchctl.sim.stand_wire.StandWire` (one per TCP connection, one for the serial line), and
write back what it answers — the same path the in-process link takes on simulated time. These
are real sockets and pseudo-terminals, so their threads and waits are the operating system's
(they serve a stand that runs on the host's time).

- :class:`TcpStandServer`: listens on ``host:port`` (port 0: a free one, in :attr:`port`); while
  the stand's ``drop_connection`` fault lasts, every connection is closed, and any new one as
  soon as it sends a request.
- :class:`RtuStandServer`: a pty pair, the client opening :attr:`client_path` (symlinked at
  ``link_path``); each request is taken after its bytes' serial time on the line (10 bits a
  byte), each reply written after its own; while the line is dead every byte is lost.
"""

from __future__ import annotations

import contextlib
import os
import selectors
import socket
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path

from benchctl.sim.stand_firmware import StandFirmware
from benchctl.sim.stand_wire import StandWire


class TcpStandServer:
    """Modbus TCP for a simulated stand: MBAP frames to and from :class:`StandWire`."""

    def __init__(self, stand: StandFirmware, host: str, port: int) -> None:
        self.stand = stand
        self._sock = socket.create_server((host, port), reuse_port=False)
        self._sock.setblocking(False)
        self.port = int(self._sock.getsockname()[1])
        self._wake_r, self._wake_w = os.pipe()
        self._stopping = False
        self._drop = threading.Event()  # a socket server: host time
        self._conns: dict[socket.socket, StandWire] = {}
        self._thread = threading.Thread(
            target=self._run, name="sim-stand-modbus", daemon=True
        )

    def start(self) -> None:
        self._thread.start()

    def drop_all(self) -> None:
        """Close every client connection now (the ``drop_connection`` fault)."""
        self._drop.set()
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"d")

    def stop(self) -> None:
        self._stopping = True
        with contextlib.suppress(OSError):
            os.write(self._wake_w, b"x")
        if self._thread.is_alive():
            self._thread.join(timeout=5)
        for c in list(self._conns):
            c.close()
        self._conns.clear()
        self._sock.close()
        for fd in (self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _close(self, sel: selectors.BaseSelector, conn: socket.socket) -> None:
        with contextlib.suppress(KeyError, ValueError):
            sel.unregister(conn)
        self._conns.pop(conn, None)
        conn.close()

    def _run(self) -> None:
        with selectors.DefaultSelector() as sel:
            sel.register(self._sock, selectors.EVENT_READ)
            sel.register(self._wake_r, selectors.EVENT_READ)
            while not self._stopping:
                for key, _ in sel.select():
                    obj = key.fileobj
                    if obj == self._wake_r:
                        with contextlib.suppress(OSError):
                            os.read(self._wake_r, 64)
                        if self._drop.is_set():
                            self._drop.clear()
                            for c in list(self._conns):
                                self._close(sel, c)
                        continue
                    if obj is self._sock:
                        with contextlib.suppress(BlockingIOError, OSError):
                            conn, _ = self._sock.accept()
                            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                            self._conns[conn] = StandWire(self.stand, "tcp")
                            sel.register(conn, selectors.EVENT_READ)
                        continue
                    assert isinstance(obj, socket.socket)
                    self._serve(sel, obj)

    def _serve(self, sel: selectors.BaseSelector, conn: socket.socket) -> None:
        try:
            data = conn.recv(4096)
        except OSError:
            data = b""
        if not data:
            self._close(sel, conn)
            return
        if self.stand.dropped():
            self._close(sel, conn)
            return
        reply = self._conns[conn].feed(data)
        if reply:
            try:
                conn.sendall(reply)
            except OSError:
                self._close(sel, conn)


class RtuStandServer:
    """Modbus RTU for a simulated stand on a pseudo-terminal: an RS-485 line without hardware."""

    def __init__(
        self,
        stand: StandFirmware,
        byte_time_s: float,
        dead: Callable[[], bool],
        link_path: Path | None,
    ) -> None:
        self.stand = stand
        self.byte_time_s = byte_time_s
        self._dead = dead
        self._wire = StandWire(stand, "rtu")
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # the slave stays open here so the master never sees EIO
        tty.setraw(self._master)
        self.client_path = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        self.link_path = link_path
        if link_path is not None:
            link_path.parent.mkdir(parents=True, exist_ok=True)
            with contextlib.suppress(FileNotFoundError):
                link_path.unlink()
            link_path.symlink_to(self.client_path)
        self._stopping = False
        self._thread = threading.Thread(  # a pty server: host time
            target=self._run, name="sim-stand-modbus", daemon=True
        )

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stopping = True
        if self._thread.is_alive():
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")
            self._thread.join(timeout=5)
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            with contextlib.suppress(OSError):
                os.close(fd)
        if self.link_path is not None and self.link_path.is_symlink():
            with contextlib.suppress(FileNotFoundError):
                self.link_path.unlink()

    def _run(self) -> None:
        with selectors.DefaultSelector() as sel:
            sel.register(self._master, selectors.EVENT_READ)
            sel.register(self._wake_r, selectors.EVENT_READ)
            while not self._stopping:
                for key, _ in sel.select():
                    if key.fd == self._wake_r:
                        return
                    try:
                        data = os.read(self._master, 4096)
                    except OSError:
                        continue
                    if not data or self._dead():
                        continue
                    if self.byte_time_s > 0:  # the request's time on the line
                        time.sleep(len(data) * self.byte_time_s)
                    reply = self._wire.feed(data)
                    if not reply or self._dead():
                        continue
                    if self.byte_time_s > 0:
                        time.sleep(len(reply) * self.byte_time_s)
                    with contextlib.suppress(OSError):
                        os.write(self._master, reply)
