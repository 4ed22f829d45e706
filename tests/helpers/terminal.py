"""A pseudo-terminal for a test: this process's stdin and stderr put on a pty's slave end, so a
command that asks on the terminal (it looks for a tty) asks there; the test writes the answers
and reads the questions on the master end."""

from __future__ import annotations

import contextlib
import fcntl
import os
import pty
import struct
import termios
from collections.abc import Iterator

import pytest


@contextlib.contextmanager
def on_terminal(monkeypatch: pytest.MonkeyPatch, *, stdout: bool = False,
                size: tuple[int, int] | None = None) -> Iterator[int]:
    """This process's stdin and stderr (and stdout with ``stdout``) on a pseudo-terminal of
    ``size`` (columns, rows; ``COLUMNS``/``LINES`` unset); yields its master end."""
    master, slave = pty.openpty()
    if size is not None:
        fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", size[1], size[0], 0, 0))
        monkeypatch.delenv("COLUMNS", raising=False)
        monkeypatch.delenv("LINES", raising=False)
    tin = open(slave, encoding="utf-8", closefd=False)  # noqa: SIM115
    tout = open(slave, "w", encoding="utf-8", closefd=False)  # noqa: SIM115
    monkeypatch.setattr("sys.stdin", tin)
    monkeypatch.setattr("sys.stderr", tout)
    if stdout:
        monkeypatch.setattr("sys.stdout", tout)
    try:
        yield master
    finally:
        tin.close()
        tout.close()
        os.close(slave)
        os.close(master)
