"""A pseudo-terminal for a test: this process's stdin and stderr put on a pty's slave end, so a
command that asks on the terminal (it looks for a tty) asks there; the test writes the answers
and reads the questions on the master end."""

from __future__ import annotations

import contextlib
import os
import pty
from collections.abc import Iterator

import pytest


@contextlib.contextmanager
def on_terminal(monkeypatch: pytest.MonkeyPatch) -> Iterator[int]:
    """This process's stdin and stderr on a pseudo-terminal; yields its master end."""
    master, slave = pty.openpty()
    tin = open(slave, encoding="utf-8", closefd=False)  # noqa: SIM115
    tout = open(slave, "w", encoding="utf-8", closefd=False)  # noqa: SIM115
    monkeypatch.setattr("sys.stdin", tin)
    monkeypatch.setattr("sys.stderr", tout)
    try:
        yield master
    finally:
        tin.close()
        tout.close()
        os.close(slave)
        os.close(master)
