"""A pseudo-terminal a simulated device serves: the driver opens ``path``, the device the master.

The slave is set raw and kept open by the simulator (so the driver may close and reopen it);
``close`` hangs the line up (the driver's next read fails: a dropped link). Output that the
driver does not read fills a bounded buffer, like a device's transmit FIFO; beyond it whole
writes are refused and counted in ``overflows`` instead of blocking the simulator. Not
thread-safe for writing: one thread writes and flushes.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tty
from pathlib import Path

from benchctl.errors import DeviceError


class PtyPort:
    """The master side of a pty, non-blocking, with a bounded output buffer.

    Parameters
    ----------
    link_path : Path, optional
        Also make ``link_path`` a symlink to the slave (replacing an older symlink, never a
        regular file), so a config can name a stable path.
    out_buffer_bytes : int
        Pending output beyond this is refused (``write`` returns False).
    """

    def __init__(self, link_path: Path | None = None, *, out_buffer_bytes: int = 16384) -> None:
        self.link_path = link_path
        self._limit = out_buffer_bytes
        self._pending = bytearray()
        self.overflows = 0
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        self.master_fd: int | None = master
        self._slave_fd: int | None = slave
        self.path = os.ttyname(slave)
        if link_path is not None:
            try:
                if link_path.is_symlink():
                    link_path.unlink()
                link_path.parent.mkdir(parents=True, exist_ok=True)
                link_path.symlink_to(self.path)
            except OSError as e:
                self.close()
                raise DeviceError(f"{link_path}: cannot link to the simulator's pty: {e}") from e

    @property
    def closed(self) -> bool:
        return self.master_fd is None

    @property
    def has_pending(self) -> bool:
        return bool(self._pending)

    def read(self) -> bytes:
        """What the driver wrote (may be empty)."""
        if self.master_fd is None:
            return b""
        try:
            return os.read(self.master_fd, 4096)
        except BlockingIOError:
            return b""
        except OSError as e:
            if e.errno == errno.EIO:  # no reader on the slave side
                return b""
            raise

    def write(self, data: bytes) -> bool:
        """Queue ``data`` whole and send what the pty takes; False (and counted) if full."""
        if self.master_fd is None:
            return False
        if len(self._pending) + len(data) > self._limit:
            self.overflows += 1
            self.flush()
            return False
        self._pending.extend(data)
        self.flush()
        return True

    def flush(self) -> None:
        """Send pending output as far as the pty accepts it now."""
        while self._pending and self.master_fd is not None:
            try:
                n = os.write(self.master_fd, self._pending)
            except BlockingIOError:
                return
            except OSError as e:
                if e.errno == errno.EIO:
                    return
                raise
            del self._pending[:n]

    def close(self) -> None:
        """Hang up: close both ends and remove the symlink (idempotent)."""
        for name in ("master_fd", "_slave_fd"):
            fd = getattr(self, name)
            if fd is not None:
                setattr(self, name, None)
                with contextlib.suppress(OSError):
                    os.close(fd)
        if self.link_path is not None and self.link_path.is_symlink():
            with contextlib.suppress(OSError):
                if os.readlink(self.link_path) == self.path:
                    self.link_path.unlink()
