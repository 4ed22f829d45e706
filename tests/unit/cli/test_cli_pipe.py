"""A reader that goes away (`benchctl history | head`) ends the command quietly: no traceback,
no "unexpected BrokenPipeError" line, whatever the command was writing."""

from __future__ import annotations

import io

import pytest

from benchctl.cli import main


class _ClosedPipe(io.TextIOBase):
    """stdout whose reader has gone: every write and flush raises BrokenPipeError."""

    def writable(self) -> bool:
        return True

    def write(self, s: str) -> int:
        raise BrokenPipeError(32, "Broken pipe")

    def flush(self) -> None:
        raise BrokenPipeError(32, "Broken pipe")

    def fileno(self) -> int:
        raise io.UnsupportedOperation("no file descriptor")


def test_closed_pipe_ends_quietly(monkeypatch: pytest.MonkeyPatch,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.setattr("sys.stdout", _ClosedPipe())
    rc = main(["schema", "record"])
    err = capsys.readouterr().err
    assert "unexpected" not in err and "Traceback" not in err and "BrokenPipe" not in err, err
    assert rc == 2
