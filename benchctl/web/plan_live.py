"""A plan's live channel to the station panel (``benchctl plan --live SOCKET [--answers DIR]``):
one publisher for the whole plan — its progress lines as ``message``, each step's run display
teed (``benchctl.web.live.LiveDisplay``), its prompts (``benchctl.web.prompts``) — and, without
``--live``, nothing at all: the plan as on a terminal."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from benchctl.run.display import Display
from benchctl.web.live import LiveDisplay, LivePublisher
from benchctl.web.prompts import PanelAsker


class PlanLive:
    def __init__(self, socket: Path | None, answers: Path | None,
                 prompt_timeout_s: float | None) -> None:
        self.publisher = None if socket is None else LivePublisher(socket)
        self.answers = answers
        self.prompt_timeout_s = prompt_timeout_s

    def asker(self) -> PanelAsker | None:
        """The prompts' asker on the panel (None: the plan's own, the terminal or --yes)."""
        if self.publisher is None or self.answers is None:
            return None
        return PanelAsker(self.publisher, self.answers, self.prompt_timeout_s)

    def display(self, inner: Display) -> Display:
        if self.publisher is None:
            return inner
        return LiveDisplay(inner, self.publisher, owns=False)

    def say(self, inner: Callable[[str], None]) -> Callable[[str], None]:
        pub = self.publisher
        if pub is None:
            return inner

        def both(text: str) -> None:
            try:
                inner(text)
            finally:
                pub.send("message", text=text)

        return both

    def close(self) -> None:
        if self.publisher is not None:
            self.publisher.send("close", dropped=self.publisher.dropped)
            self.publisher.close()
