"""The run's live channel to the station panel: a display that tees to the run's usual one and
publishes JSON datagrams (state, snapshots, messages, the verdict) on a Unix socket.

The run never waits on it and never sees its failures: every datagram is sent without blocking
(``MSG_DONTWAIT``); one the reader has no room for, or sent while no reader is bound (the server
gone, slow or not started), is dropped and counted. The run's own display (the terminal, the log
lines) is called first, as without a panel.

Each datagram is one JSON object (UTF-8, at most ``MAX_DATAGRAM`` bytes) with a ``kind``:

- ``state``: ``state``, ``reason``
- ``snapshot``: the fields of ``benchctl.run.display.Snapshot`` (non-finite numbers as null)
- ``message``: ``text``
- ``verdict``: ``verdict``, ``detail``
- ``close``: ``dropped`` (datagrams dropped so far)
- a plan's: ``prompt`` (``id``, ``text``, ``timeout_s``: a question waiting for the operator,
  sent again every few seconds while it waits) and ``prompt_closed`` (``id``, ``why``)
  (``benchctl.web.prompts``)

and ``seq``, its number from 0 (a gap: dropped datagrams), and ``pid``, the run's process.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import socket
from pathlib import Path
from typing import Any

from benchctl.jsonout import dumps
from benchctl.run.display import Display, Snapshot

MAX_DATAGRAM = 60_000  # bytes: within the smallest default Unix datagram limit of a Linux host
MAX_TEXT = 8_000  # characters of one message or verdict detail (the rest cut, marked "…")


def _finite(value: Any) -> Any:
    """``value`` with every non-finite float as None (JSON has no NaN)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _cut(text: str) -> str:
    return text if len(text) <= MAX_TEXT else text[: MAX_TEXT - 1] + "…"


class LivePublisher:
    """Datagrams to ``path`` (a Unix datagram socket the panel binds), never blocking."""

    def __init__(self, path: str | Path) -> None:
        self.path = str(path)
        self.seq = 0
        self.dropped = 0
        self.pid = os.getpid()
        self._sock: socket.socket | None = None
        try:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
            self._sock.setblocking(False)
        except OSError:
            self._sock = None

    def send(self, kind: str, **fields: Any) -> bool:
        """Publish one object; False when it was dropped (never raises)."""
        seq, self.seq = self.seq, self.seq + 1
        try:
            data = dumps({"kind": kind, "seq": seq, "pid": self.pid, **_finite(fields)}).encode()
            if len(data) > MAX_DATAGRAM or self._sock is None:
                raise ValueError("datagram too large or no socket")
            self._sock.sendto(data, socket.MSG_DONTWAIT, self.path)
            return True
        except (OSError, ValueError, TypeError):  # no reader, its queue full, a value not JSON
            self.dropped += 1
            return False

    def close(self) -> None:
        if self._sock is not None:
            with contextlib.suppress(OSError):
                self._sock.close()
            self._sock = None


class LiveDisplay:
    """A ``Display`` that calls ``inner`` and then publishes the same call to the panel;
    ``owns``: its ``close`` closes the publisher too (a plan's steps share one: not theirs)."""

    def __init__(self, inner: Display, publisher: LivePublisher, *, owns: bool = True) -> None:
        self.inner = inner
        self.publisher = publisher
        self.owns = owns

    def state(self, state: str, reason: str = "") -> None:
        try:
            self.inner.state(state, reason)
        finally:
            self.publisher.send("state", state=state, reason=_cut(reason))

    def update(self, snap: Snapshot) -> None:
        try:
            self.inner.update(snap)
        finally:
            self.publisher.send("snapshot", **dataclasses.asdict(snap))

    def message(self, text: str) -> None:
        try:
            self.inner.message(text)
        finally:
            self.publisher.send("message", text=_cut(text))

    def verdict(self, verdict: str, detail: str = "") -> None:
        try:
            self.inner.verdict(verdict, detail)
        finally:
            self.publisher.send("verdict", verdict=verdict, detail=_cut(detail))

    def close(self) -> None:
        try:
            self.inner.close()
        finally:
            if self.owns:
                self.publisher.send("close", dropped=self.publisher.dropped)
                self.publisher.close()


def live_display(inner: Display, path: str | Path | None) -> Display:
    """``inner`` teed to the panel's socket at ``path``; ``inner`` itself when no path."""
    if path is None:
        return inner
    return LiveDisplay(inner, LivePublisher(path))
