"""A plan's operator prompts answered on the station panel: the question published on the run's
live channel (``benchctl.web.live``), the answer a file the panel writes.

``PanelAsker`` is an ``Asker`` of ``benchctl.plan.prompts``: it publishes ``prompt`` (again every
``REPEAT_S`` while it waits: a datagram may be dropped, a browser may connect late) and waits
for ``<answers>/prompt-<id>.answer`` — ``yes`` or ``no``, written whole by the panel (a rename)
— for the plan's ``prompt_timeout_s``; no answer by then raises ``TimeoutError`` (unanswered:
the plan's rules apply). A signal raises where it is, as at the terminal. The wait is on the
host's time (``select`` on no file: a sleep a signal interrupts), as the terminal's is.
"""

from __future__ import annotations

import contextlib
import math
import os
import select
import time
from pathlib import Path

from benchctl.web.live import LivePublisher

REPEAT_S = 2.0  # the question published again while it waits
POLL_S = 0.1  # how often the answer file is looked for


class PanelAsker:
    """Plan prompts on the panel: publish, then wait for the answer file."""

    def __init__(self, publisher: LivePublisher, answers: Path,
                 timeout_s: float | None) -> None:
        self.publisher = publisher
        self.answers = answers
        self.timeout_s = timeout_s
        self.asked = 0

    def __call__(self, text: str) -> bool:
        qid, self.asked = self.asked, self.asked + 1
        path = self.answers / f"prompt-{qid}.answer"
        # the operator's time: the host's, whatever the run's clock (as the terminal's prompt)
        t0 = time.monotonic()  # noqa: TID251
        sent = -math.inf
        while True:
            now = time.monotonic()  # noqa: TID251
            if now - sent >= REPEAT_S:
                self.publisher.send("prompt", id=qid, text=text, timeout_s=self.timeout_s)
                sent = now
            answer = _read(path)
            if answer is not None:
                self.publisher.send("prompt_closed", id=qid, why=answer)
                return answer == "yes"
            if self.timeout_s is not None and now - t0 >= self.timeout_s:
                self.publisher.send("prompt_closed", id=qid, why="timeout")
                raise TimeoutError(f"no answer on the panel within {self.timeout_s:g} s")
            select.select([], [], [], POLL_S)  # a host wait; a signal raises here


def _read(path: Path) -> str | None:
    """``yes``/``no`` from the answer file once it is there (anything else: no)."""
    try:
        text = path.read_text(encoding="utf-8").strip().lower()
    except FileNotFoundError:
        return None
    except OSError:
        return "no"
    with contextlib.suppress(OSError):
        os.unlink(path)
    return "yes" if text == "yes" else "no"
