"""Live progress for the person at the stand.

On a terminal: a small block of lines redrawn in place with plain ANSI escapes, never wider
than 80 columns (nor than the terminal), so nothing wraps or scrolls: the unit's serial and the
operator, state, elapsed and remaining time, stand and instrument angles, tracking error, the
running σ beside its limit, and the stand's health (missed control cycles, rejoins,
instrument samples) with a warning only when the motion is touched (``health_warning``: stream
mode's missed cycles, underruns, rejoins; buffered mode's missed polls are a count); at the
end a banner with the verdict. Without a terminal: plain log lines, one every ``period_s``
and one at each state change, and the verdict as one more line. ``NullDisplay`` for
``--json`` scripts that want silence.

Every text a display writes — the serial and the operator, messages (a device's identity, a log
record), reasons, the verdict's detail — goes through ``benchctl.text.visible``: a control
character in it is shown as an escape (``\x1b``), never sent to the terminal, and no value
starts a line of its own.
"""

from __future__ import annotations

import logging
import math
import os
import re
import sys
import textwrap
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import datetime
from typing import Protocol, TextIO

from benchctl.clock import REAL, Clock
from benchctl.outcomes import Outcome
from benchctl.text import visible


def _hms(clock: Clock) -> str:
    """The clock's wall time as local hours:minutes:seconds (a line's stamp for people)."""
    return datetime.fromtimestamp(clock.time()).strftime("%H:%M:%S")


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
    serial: str = ""
    operator: str = ""
    limit_deg: float | None = None  # the σ limit (run.limit_sigma_deg)
    cycles: int = 0  # control cycles so far (the missed ones' share)
    rejoins: int = 0  # the stand re-joined the profile after a lost link or a breach
    #: the stand's mode (stand.mode): in "stream" a missed cycle is a setpoint not sent (the
    #: motion held); in "buffered" and "table" a missed poll leaves the motion alone (the stand
    #: plays on its own clock). "" (not said): judged as "stream"
    mode: str = ""
    underruns: int = 0  # the stand's trajectory queue ran dry while moving (it stopped itself)
    #: motion time (``elapsed_s``) from which the running σ is judged against the limit: the
    #: fade-in and one whole period of the multisine. None: never judged live (no period)
    sigma_judged_after_s: float | None = None


WIDTH = 80  # the live block's widest line (columns)
ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
#: SGR colours of a verdict's banner head and of a warning (a terminal that supports colour)
COLOURS: dict[str, str] = {
    Outcome.PASS: "1;32", Outcome.FAIL: "1;31", Outcome.ABORTED: "1;31",
    Outcome.INCONCLUSIVE: "1;33", Outcome.WARNING: "33", "within": "32", "over": "33"}
SIGMA_LABEL = "σ (running est.)"  # the live σ: an estimate on the way, not the verdict


def colour_wanted(stream: TextIO, environ: Mapping[str, str] | None = None) -> bool:
    """Colour on ``stream``: a terminal, ``NO_COLOR`` unset or empty (no-color.org) and
    ``TERM`` not ``dumb``."""
    env = os.environ if environ is None else environ
    try:
        tty = stream.isatty()
    except (OSError, ValueError):  # closed
        return False
    return tty and not env.get("NO_COLOR") and env.get("TERM", "") != "dumb"


def paint(text: str, key: str, colour: bool) -> str:
    """``text`` in the colour ``COLOURS[key]`` when ``colour`` (else as it is)."""
    code = COLOURS.get(key)
    return f"\x1b[{code}m{text}\x1b[0m" if colour and code and text else text
MISSED_WARN_SHARE = 0.01  # missed cycles above this share of the cycles: a warning
MISSED_WARN_STEP = 10  # … or this many more since the last drawing


class Display(Protocol):
    def state(self, state: str, reason: str = "") -> None: ...
    def update(self, snap: Snapshot) -> None: ...
    def message(self, text: str) -> None: ...
    def verdict(self, verdict: str, detail: str = "") -> None: ...
    def close(self) -> None: ...


def motion_paced_by_host(snap: Snapshot) -> bool:
    """Whether the host's missed cycles touch the motion: in stream mode (or a mode not said)
    each missed cycle is a setpoint the stand did not get; buffered and table modes play on the
    stand's own clock, and a missed poll only delays a reading."""
    return snap.mode not in ("buffered", "table")


def health_warning(snap: Snapshot, previous_missed: int = 0) -> str:
    """A warning when the stand's health touches the motion, or "": any rejoin or underrun;
    in stream mode missed cycles above ``MISSED_WARN_SHARE`` of the cycles, or climbing by
    ``MISSED_WARN_STEP`` or more since the last look (``previous_missed``). Missed polls in
    buffered or table mode are only counted on the health line (``format_lines``)."""
    parts = []
    if motion_paced_by_host(snap):
        if snap.cycles and snap.missed_cycles / snap.cycles > MISSED_WARN_SHARE:
            parts.append(f"missed {100 * snap.missed_cycles / snap.cycles:.1f} % of cycles")
        elif snap.missed_cycles - previous_missed >= MISSED_WARN_STEP:
            parts.append(f"+{snap.missed_cycles - previous_missed} missed cycles")
    if snap.underruns:
        parts.append(f"{snap.underruns} underrun(s)")
    if snap.rejoins:
        parts.append(f"{snap.rejoins} rejoin(s)")
    return ("WARNING stand health: " + ", ".join(parts)) if parts else ""


def health_text(snap: Snapshot) -> str:
    """The health line's counts: missed cycles (stream mode) or missed polls (buffered, table:
    a count only), underruns when there were any, rejoins, instrument samples."""
    missed = ("missed cycles" if motion_paced_by_host(snap) else "missed polls")
    under = f"  underruns {snap.underruns}" if snap.underruns else ""
    return (f"{missed} {snap.missed_cycles}{under}  rejoins {snap.rejoins}"
            f"  instrument samples {snap.instrument_samples}")


def wrap_words(text: str, width: int = WIDTH) -> list[str]:
    """``text`` (lines split at ``\\n``) wrapped at spaces to ``width`` columns: a line that fits
    is kept as it is; a longer one is broken between words, its continuation indented two more
    than the line (at most half the width). No word is ever cut: a word longer than the width (a
    long path) stands whole on a line of its own, for the terminal to fold."""
    out: list[str] = []
    for para in text.split("\n"):
        para = para.rstrip()
        if len(para) <= width:
            out.append(para)
            continue
        indent = len(para) - len(para.lstrip(" "))
        pad = " " * min(indent, width // 2)
        cont = " " * min(indent + 2, width // 2)
        tokens = re.split(r"( +)", para.strip())  # words, and the gaps between them kept
        line = pad + tokens[0] if len(pad) + len(tokens[0]) <= width else tokens[0]
        for gap, word in zip(tokens[1::2], tokens[2::2], strict=True):
            if len(line) + len(gap) + len(word) <= width:
                line += gap + word
            else:
                out.append(line)
                line = cont + word if len(cont) + len(word) <= width else word
        out.append(line)
    return out


def rows_of(lines: list[str], columns: int) -> int:
    """The terminal rows ``lines`` take on ``columns`` columns (a longer line folds)."""
    return sum(max(1, -(-len(ANSI.sub("", ln)) // columns)) for ln in lines)


def fit_rows(lines: list[str], width: int, rows: int, more: str = "",
             columns: int | None = None) -> list[str]:
    """``lines`` wrapped at words to ``width`` (``wrap_words``) and, when they take more than
    ``rows`` rows, fewer of them: the most indented (the most detailed) go first, from the
    bottom; the first line, warnings and deviations stay. A last line then says how many were
    left out and ``more`` (where they are). Rows are counted on ``columns`` (default one more
    than ``width``): a word longer than a line folds over several."""
    cols = width + 1 if columns is None else columns
    blocks = [wrap_words(ln, width) for ln in lines]
    if rows_of([r for b in blocks for r in b], cols) <= rows:
        return [r for b in blocks for r in b]

    def rank(i: int) -> int:  # higher goes first
        head = lines[i].strip()
        if i == 0 or head.lower().startswith(("warning", "deviation")):
            return -1
        return len(lines[i]) - len(lines[i].lstrip(" "))

    def note(n: int) -> list[str]:
        return wrap_words(f"  … {n} line(s) of detail left out{': ' + more if more else ''}",
                          width)

    kept = set(range(len(blocks)))
    dropped = 0
    for i in sorted((i for i in kept if rank(i) >= 0), key=lambda i: (-rank(i), -i)):
        if sum(rows_of(blocks[j], cols) for j in kept) + rows_of(note(max(dropped, 1)),
                                                                cols) <= rows:
            break
        kept.discard(i)
        dropped += 1
    return [r for j in sorted(kept) for r in blocks[j]] + note(dropped)


def fit(text: str, width: int = WIDTH) -> str:
    """``text`` cut to ``width`` columns (an ellipsis marks the cut)."""
    return text if len(text) <= width else text[: width - 1] + "…"


def _mmss(s: float | None) -> str:
    if s is None or not math.isfinite(s):
        return "--:--"
    s = max(0.0, s)
    return f"{int(s // 60):02d}:{int(s % 60):02d}"


def _angles(d: dict[str, float], fmt: str = "+7.2f") -> str:
    if not d:
        return "—"
    return "  ".join(f"{a} {v:{fmt}}°" if math.isfinite(v) else f"{a}    —  " for a, v in d.items())


def sigma_judgement(snap: Snapshot) -> str:
    """How the running σ stands: "settling" (not meaningful yet: before the fade-in and one
    whole period of the multisine), "within" or "over" the limit (judged), or "" (not judged
    live: no limit, no period, or no estimate yet)."""
    if snap.limit_deg is None or snap.sigma_judged_after_s is None:
        return ""
    if snap.elapsed_s is None or snap.elapsed_s < snap.sigma_judged_after_s:
        return "settling"
    values = [v for v in snap.sigma_deg.values() if math.isfinite(v)]
    if not values:
        return "settling"
    return "over" if max(values) > snap.limit_deg else "within"


def sigma_text(snap: Snapshot) -> str:
    """The running σ's line: settling (with the time to go) until it is meaningful, then the
    values beside the limit and, over it, which axes."""
    limit = "" if snap.limit_deg is None else f"   limit {snap.limit_deg:g}°"
    judged = sigma_judgement(snap)
    if judged == "settling":
        assert snap.sigma_judged_after_s is not None
        to_go = snap.sigma_judged_after_s - (snap.elapsed_s or 0.0)
        return (f"  {SIGMA_LABEL} settling: judged after one period,"
                f" {_mmss(to_go)} to go{limit}")
    text = f"  {SIGMA_LABEL} {_angles(snap.sigma_deg, '7.3f')}{limit}"
    if judged == "over":
        assert snap.limit_deg is not None
        over = [a for a, v in snap.sigma_deg.items() if math.isfinite(v) and v > snap.limit_deg]
        text += f" ({', '.join(over)} over)"
    elif not judged and snap.limit_deg is not None:
        text += " (not judged live)"
    return text


def format_lines(snap: Snapshot) -> list[str]:
    """The progress block as text lines (the log line joins them)."""
    who = " ".join(p for p in (f"serial {visible(snap.serial)}" if snap.serial else "",
                               f"operator {visible(snap.operator)}" if snap.operator else "")
                   if p)
    return [
        *([who] if who else []),
        f"state {snap.state:<10} elapsed {_mmss(snap.elapsed_s)}"
        f"  remaining {_mmss(snap.remaining_s)}",
        f"  stand       {_angles(snap.stand_deg)}",
        f"  instrument  {_angles(snap.instrument_deg)}",
        f"  tracking    {_angles(snap.tracking_error_deg, '+7.3f')}",
        sigma_text(snap),
        f"  health      {health_text(snap)}",
    ]


def format_block(snap: Snapshot, width: int = WIDTH, previous_missed: int = 0) -> list[str]:
    """The live block for a terminal: every line within ``width`` columns, a warning line
    when the stand's health climbs (always the same number of lines: nothing scrolls)."""
    warn = health_warning(snap, previous_missed)
    lines = [fit(ln, width) for ln in format_lines(snap)]
    return [*lines, fit(("  " + warn) if warn else "", width)]


def banner(verdict: str, detail: str = "", width: int = WIDTH, colour: bool = False) -> list[str]:
    """The final banner: the verdict framed, its detail lines below, all within ``width``;
    the verdict's line in its colour when ``colour``."""
    bar = "=" * width
    head = paint(f" {verdict} ".center(width, "="), verdict, colour)
    body = wrap_words("\n".join(visible(ln) for ln in detail.split("\n") if ln.strip()), width)
    return [bar, head, *body, bar]


class NullDisplay:
    def state(self, state: str, reason: str = "") -> None:
        pass

    def update(self, snap: Snapshot) -> None:
        pass

    def message(self, text: str) -> None:
        pass

    def verdict(self, verdict: str, detail: str = "") -> None:
        pass

    def close(self) -> None:
        pass


class LogDisplay:
    """Plain lines: one per state change and one every ``period_s``."""

    def __init__(self, stream: TextIO, period_s: float = 5.0, *, clock: Clock = REAL) -> None:
        self.stream = stream
        self.period_s = period_s
        self.clock = clock
        self._last = -math.inf

    def _print(self, text: str) -> None:
        self.stream.write(f"[{_hms(self.clock)}] {visible(text)}\n")
        self.stream.flush()

    def state(self, state: str, reason: str = "") -> None:
        self._print(f"state → {state}" + (f" ({reason})" if reason else ""))

    def update(self, snap: Snapshot) -> None:
        now = self.clock.monotonic()
        if now - self._last < self.period_s:
            return
        self._last = now
        self._print(" | ".join(line.strip() for line in format_lines(snap)))

    def message(self, text: str) -> None:
        self._print(text)

    def verdict(self, verdict: str, detail: str = "") -> None:
        self._print(f"verdict {verdict}" + "".join(f" | {ln.strip()}" for ln in
                                                   detail.split("\n") if ln.strip()))

    def close(self) -> None:
        pass


class _ToDisplay(logging.Handler):
    """Log records shown as the display's messages (above its block, wrapped to its width)."""

    def __init__(self, display: TtyDisplay, level: int) -> None:
        super().__init__(level)
        self.display = display

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.display.message(f"{record.levelname}: {record.getMessage()}")
        except Exception:  # the terminal is gone: the console handlers take over again
            self.display._release_logging()
            self.handleError(record)


class _Held(logging.Filter):
    """Keeps a console handler quiet while the display shows its records instead."""

    def filter(self, record: logging.LogRecord) -> bool:
        return False


class TtyDisplay:
    """The progress block redrawn in place (cursor up + clear line), at most ``fps`` a second.

    While the block is up, log records that a console handler of the root logger would write to
    the same terminal go through the display instead (a line written under the block would
    break its redrawing); the handler gets them again at ``close``."""

    def __init__(
        self, stream: TextIO, fps: float = 5.0, width: int | None = None, *, clock: Clock = REAL,
        colour: bool = False, hold_banner: bool = False,
    ) -> None:
        self.stream = stream
        self.colour = colour
        #: the verdict's banner kept until ``show_banner`` (the command prints its summary
        #: first, so that the banner is the last thing on the screen)
        self.hold_banner = hold_banner
        self.held: list[str] = []
        self.clock = clock
        self.min_dt = 1.0 / fps
        self._drawn = 0
        self._last = -math.inf
        self._snap: Snapshot | None = None
        self._missed_seen = 0  # missed cycles at the last drawing (the warning as it climbs)
        self._warn_until = -math.inf
        self._warning = ""
        self._done = False
        self._lock = clock.rlock()  # log records may come from the run's other threads
        self._logging: tuple[logging.Handler, list[logging.Handler], _Held] | None = None
        if width is None:
            width = terminal_size(stream).columns - 1
        self.width = max(20, min(WIDTH, width))

    def _erase(self) -> None:
        if self._drawn:
            self.stream.write(f"\x1b[{self._drawn}F\x1b[J")
            self._drawn = 0

    def _capture_logging(self) -> None:
        """Route the root logger's console records on this display's stream through it."""
        if self._logging is not None:
            return
        root = logging.getLogger()
        mine: list[logging.Handler] = [
            h for h in root.handlers
            if isinstance(h, logging.StreamHandler) and not isinstance(h, logging.FileHandler)
            and getattr(h, "stream", None) is self.stream
        ]
        if not mine:
            return
        held = _Held()
        for h in mine:
            h.addFilter(held)
        to_me = _ToDisplay(self, min(h.level for h in mine))
        root.addHandler(to_me)
        self._logging = (to_me, mine, held)

    def _release_logging(self) -> None:
        if self._logging is None:
            return
        to_me, mine, held = self._logging
        self._logging = None
        logging.getLogger().removeHandler(to_me)
        for h in mine:
            h.removeFilter(held)

    def _draw(self, snap: Snapshot) -> None:
        self._capture_logging()
        self._erase()
        now = self.clock.monotonic()
        lines = format_block(snap, self.width, self._missed_seen)
        if lines[-1]:  # a warning stays up a few seconds after the climb
            self._warn_until, self._warning = now + 5.0, lines[-1]
        elif now < self._warn_until:
            lines[-1] = self._warning
        self._missed_seen = snap.missed_cycles
        lines[-1] = paint(lines[-1], Outcome.WARNING, self.colour)
        lines[-3] = paint(lines[-3], sigma_judgement(snap), self.colour)  # the σ line
        self.stream.write("\n".join(lines) + "\n")
        self.stream.flush()
        self._drawn = len(lines)

    def state(self, state: str, reason: str = "") -> None:
        self.message(f"state → {state}" + (f" ({reason})" if reason else ""))

    def update(self, snap: Snapshot) -> None:
        with self._lock:
            self._snap = snap
            now = self.clock.monotonic()
            if now - self._last >= self.min_dt:
                self._last = now
                self._draw(snap)

    def message(self, text: str) -> None:
        """A line above the block, wrapped (not cut) to the display's width."""
        with self._lock:
            self._erase()
            lines = textwrap.wrap(f"[{_hms(self.clock)}] {visible(text)}", self.width,
                                  subsequent_indent=" " * 11, break_on_hyphens=False,
                                  break_long_words=False) or [""]
            self.stream.write("\n".join(lines) + "\n")
            if self._snap is not None and not self._done:
                self._draw(self._snap)
            else:
                self.stream.flush()

    def verdict(self, verdict: str, detail: str = "") -> None:
        """The final banner below everything; the live block is not drawn again."""
        with self._lock:
            self._erase()
            self._done = True
            self._release_logging()
            lines = banner(verdict, detail, self.width, self.colour)
            if self.hold_banner:
                self.held = lines
            else:
                self.stream.write("\n".join(lines) + "\n")
            self.stream.flush()

    def show_banner(self) -> None:
        """The banner held back (``hold_banner``), now: below whatever came since."""
        with self._lock:
            lines, self.held = self.held, []
            if lines:
                self.stream.write("\n".join(lines) + "\n")
                self.stream.flush()

    def close(self) -> None:
        with self._lock:
            if self._snap is not None and not self._done:
                self._draw(self._snap)
            self._release_logging()
            self.stream.flush()


def terminal_size(stream: TextIO) -> os.terminal_size:
    """The terminal's columns and rows: ``COLUMNS``/``LINES`` when set, else ``stream``'s
    terminal, else 80×24."""
    try:
        size = os.get_terminal_size(stream.fileno())
    except (OSError, ValueError, AttributeError):
        size = os.terminal_size((WIDTH, 24))
    env = os.environ
    cols = int(env["COLUMNS"]) if env.get("COLUMNS", "").isdigit() else size.columns
    rows = int(env["LINES"]) if env.get("LINES", "").isdigit() else size.lines
    return os.terminal_size((cols or WIDTH, rows or 24))


def make_display(
    stream: TextIO | None = None, quiet: bool = False, *, clock: Clock = REAL,
    hold_banner: bool = False,
) -> Display:
    """A TTY display when ``stream`` is a terminal (in colour unless ``NO_COLOR`` is set or
    ``TERM`` is ``dumb``: ``colour_wanted``), plain log lines without colour otherwise."""
    s = stream if stream is not None else sys.stderr
    if quiet:
        return NullDisplay()
    if s.isatty():
        return TtyDisplay(s, clock=clock, colour=colour_wanted(s), hold_banner=hold_banner)
    return LogDisplay(s, clock=clock)


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

    def verdict(self, verdict: str, detail: str = "") -> None:
        """The final banner; a display without one (an older or a host's own) gets the
        verdict as a message."""
        if hasattr(self.inner, "verdict"):
            self._call("verdict", verdict, detail)
        else:
            self._call("message", f"{verdict}: {detail}" if detail else verdict)

    def close(self) -> None:
        self._call("close")
