"""Operator prompts on the terminal: a y/N question answered by one line, within a timeout.

An :data:`Asker` takes the question and answers yes (True) or no (False); the plan runner
(``benchctl.plan.runner``) asks its setup and cleanup prompts through one.
:func:`terminal_asker` is the terminal's, when stdin and stderr are terminals.
"""

from __future__ import annotations

import io
import os
import select
import sys
import time
from collections.abc import Callable
from typing import Any

from benchctl.plan.schema import DEFAULT_PROMPT_TIMEOUT_S

# an operator prompt: the question → yes (True) or no (False); it raises EOFError when its input
# ended, TimeoutError when no answer came in time, KeyboardInterrupt on a signal
Asker = Callable[[str], bool]


def terminal_asker(stdin: Any = None, stderr: Any = None,
                   timeout_s: float | None = DEFAULT_PROMPT_TIMEOUT_S) -> Asker | None:
    """A y/N question on the terminal, or None when stdin or stderr is not a terminal.

    The answer is one line: ``y``/``yes`` is yes, anything else no. No line within
    ``timeout_s`` raises ``TimeoutError``; the end of the input (Ctrl-D, a closed terminal)
    ``EOFError``; a signal raises where it is (the caller's handler: ``KeyboardInterrupt``)."""
    i = stdin if stdin is not None else sys.stdin
    o = stderr if stderr is not None else sys.stderr
    try:
        if not (i.isatty() and o.isatty()):
            return None
    except (AttributeError, ValueError):
        return None

    def ask(text: str) -> bool:
        try:
            o.write(f"{text} [y/N]: ")
            o.flush()
        except OSError as e:  # a terminal hung up: nobody can answer
            raise EOFError(f"the terminal cannot be written: {e.strerror}") from None
        line = _read_line(i, timeout_s)
        return line.strip().lower() in ("y", "yes")

    return ask


def _read_line(stream: Any, timeout_s: float | None) -> str:
    """One line from ``stream`` within ``timeout_s`` (``TimeoutError``), ``EOFError`` at its end.

    Read from the file descriptor (``select`` for the timeout); a stream without one (a test's
    StringIO) is read as it is."""
    try:
        fd = stream.fileno()
    except (AttributeError, ValueError, io.UnsupportedOperation):
        line = str(stream.readline())
        if not line:
            raise EOFError("end of input") from None
        return line
    # the operator's terminal: a host wait (select) on the host's time, whatever the run's clock
    deadline = None if timeout_s is None else time.monotonic() + timeout_s  # noqa: TID251
    buf = b""
    while b"\n" not in buf:
        left = None if deadline is None else deadline - time.monotonic()  # noqa: TID251
        if left is not None and left <= 0:
            raise TimeoutError(f"no answer within {timeout_s:g} s")
        try:
            ready, _, _ = select.select([fd], [], [], left)
            chunk = os.read(fd, 1024) if ready else None
        except OSError as e:  # a terminal hung up (EIO): its input has ended
            raise EOFError(f"the terminal cannot be read: {e.strerror}") from None
        if chunk is None:
            continue
        if not chunk:
            raise EOFError("end of input")
        buf += chunk
    return buf.split(b"\n", 1)[0].decode("utf-8", errors="replace")


__all__ = ["Asker", "terminal_asker"]
