"""Live progress for the person at the stand.

On a terminal: a small block of lines redrawn in place with plain ANSI escapes (state, elapsed
and remaining time, stand and instrument angles, tracking error, running σ). Without one:
plain log lines, one every ``period_s`` and one at each state change. ``NullDisplay`` for
``--json`` scripts that want silence.
"""

from __future__ import annotations

import logging
import math
import sys
import time
from dataclasses import dataclass, field
from typing import Protocol, TextIO


@dataclass
class Snapshot:
    state: str
    elapsed_s: float | None = None  # since the motion started
    remaining_s: float | None = None
    stand_deg: dict[str, float] = field(default_factory=dict)
    instrument_deg: dict[str, float] = field(default_factory=dict)
    tracking_error_deg: dict[str, float] = field(default_factory=dict)
    sigma_deg: dict[str, float] = field(default_factory=dict)
    missed_cycles: int = 0
    instrument_samples: int = 0


class Display(Protocol):
    def state(self, state: str, reason: str = "") -> None: ...
    def update(self, snap: Snapshot) -> None: ...
    def message(self, text: str) -> None: ...
    def close(self) -> None: ...


def _mmss(s: float | None) -> str:
    if s is None or not math.isfinite(s):
        return "--:--"
    s = max(0.0, s)
    return f"{int(s // 60):02d}:{int(s % 60):02d}"


def _angles(d: dict[str, float], fmt: str = "+7.2f") -> str:
    if not d:
        return "—"
    return "  ".join(f"{a} {v:{fmt}}°" if math.isfinite(v) else f"{a}    —  " for a, v in d.items())


def format_lines(snap: Snapshot) -> list[str]:
    """The progress block as text lines (shared by both displays)."""
    return [
        f"state {snap.state:<10} elapsed {_mmss(snap.elapsed_s)}"
        f"  remaining {_mmss(snap.remaining_s)}"
        f"  missed cycles {snap.missed_cycles}  instrument samples {snap.instrument_samples}",
        f"  stand       {_angles(snap.stand_deg)}",
        f"  instrument  {_angles(snap.instrument_deg)}",
        f"  tracking    {_angles(snap.tracking_error_deg, '+7.3f')}",
        f"  σ (running) {_angles(snap.sigma_deg, '7.3f')}",
    ]


class NullDisplay:
    def state(self, state: str, reason: str = "") -> None:
        pass

    def update(self, snap: Snapshot) -> None:
        pass

    def message(self, text: str) -> None:
        pass

    def close(self) -> None:
        pass


class LogDisplay:
    """Plain lines: one per state change and one every ``period_s``."""

    def __init__(self, stream: TextIO, period_s: float = 5.0) -> None:
        self.stream = stream
        self.period_s = period_s
        self._last = -math.inf

    def _print(self, text: str) -> None:
        self.stream.write(f"[{time.strftime('%H:%M:%S')}] {text}\n")
        self.stream.flush()

    def state(self, state: str, reason: str = "") -> None:
        self._print(f"state → {state}" + (f" ({reason})" if reason else ""))

    def update(self, snap: Snapshot) -> None:
        now = time.monotonic()
        if now - self._last < self.period_s:
            return
        self._last = now
        self._print(" | ".join(line.strip() for line in format_lines(snap)))

    def message(self, text: str) -> None:
        self._print(text)

    def close(self) -> None:
        pass


class TtyDisplay:
    """The progress block redrawn in place (cursor up + clear line), at most ``fps`` a second."""

    def __init__(self, stream: TextIO, fps: float = 5.0) -> None:
        self.stream = stream
        self.min_dt = 1.0 / fps
        self._drawn = 0
        self._last = -math.inf
        self._snap: Snapshot | None = None

    def _erase(self) -> None:
        if self._drawn:
            self.stream.write(f"\x1b[{self._drawn}F\x1b[J")
            self._drawn = 0

    def _draw(self, snap: Snapshot) -> None:
        self._erase()
        lines = format_lines(snap)
        self.stream.write("\n".join(lines) + "\n")
        self.stream.flush()
        self._drawn = len(lines)

    def state(self, state: str, reason: str = "") -> None:
        self.message(f"state → {state}" + (f" ({reason})" if reason else ""))

    def update(self, snap: Snapshot) -> None:
        self._snap = snap
        now = time.monotonic()
        if now - self._last >= self.min_dt:
            self._last = now
            self._draw(snap)

    def message(self, text: str) -> None:
        self._erase()
        self.stream.write(f"[{time.strftime('%H:%M:%S')}] {text}\n")
        if self._snap is not None:
            self._draw(self._snap)
        else:
            self.stream.flush()

    def close(self) -> None:
        if self._snap is not None:
            self._draw(self._snap)
        self.stream.flush()


def make_display(stream: TextIO | None = None, quiet: bool = False) -> Display:
    """A TTY display when ``stream`` is a terminal, plain log lines otherwise."""
    s = stream if stream is not None else sys.stderr
    if quiet:
        return NullDisplay()
    if s.isatty():
        return TtyDisplay(s)
    return LogDisplay(s)


class SafeDisplay:
    """A display whose failures never reach the run: a console gone away (the terminal closed,
    SIGHUP; a closed pipe) or a bug in drawing is logged once, and the display goes quiet."""

    def __init__(self, inner: Display) -> None:
        self.inner = inner
        self.failed = False

    def _call(self, name: str, *args: object) -> None:
        if self.failed:
            return
        try:
            getattr(self.inner, name)(*args)
        except Exception as e:
            self.failed = True
            logging.getLogger(__name__).warning(
                "live display stopped: %s: %s",
                type(e).__name__,
                e,
                exc_info=None if isinstance(e, OSError) else e,
            )

    def state(self, state: str, reason: str = "") -> None:
        self._call("state", state, reason)

    def update(self, snap: Snapshot) -> None:
        self._call("update", snap)

    def message(self, text: str) -> None:
        self._call("message", text)

    def close(self) -> None:
        self._call("close")
