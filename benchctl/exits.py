"""Every way out of a benchctl command: the exit signals, the log files, no traceback on screen.

- ``EXIT_SIGNALS`` (SIGINT, SIGTERM, SIGHUP, SIGQUIT) each end a command cleanly with exit code
  2. ``exit_signals()`` (entered first thing in ``benchctl.cli.main``) makes each of them raise
  ``Interrupted`` once; while a run lasts its ``Supervisor`` takes them over (the stand is brought
  to rest first) and gives them back after. A signal the process was started with ignored
  (``nohup`` ignores SIGHUP) stays ignored.
- ``console_handler(level)``: log records on stderr as one line each; a record's traceback never
  goes to the console, only to the log file, whose path the line names.
- ``run_log(folder)``: the run's log file ``<recording>/benchctl.log`` (INFO and up, with the
  tracebacks of unexpected exceptions), attached to the root logger while the run lasts.
- ``crash_log(exc)``: where ``main`` writes the traceback of an unexpected exception: the run's
  log when there is one, else ``benchctl.log`` in the folder given to ``set_log_dir`` (the run's
  output folder), else a new ``benchctl-*.log`` in the system temp dir.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import tempfile
import threading
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from benchctl.clock import REAL, Clock
from benchctl.errors import Interrupted
from benchctl.text import visible

log = logging.getLogger(__name__)

LOG_NAME = "benchctl.log"
EXIT_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP", "SIGQUIT") if hasattr(signal, n)
)
LOG_FORMAT = "%(asctime)s %(levelname)s %(threadName)s %(name)s: %(message)s"


@dataclass
class _State:
    active_log: Path | None = None  # the run's log file while it is attached
    last_log: Path | None = None  # the last run's log file (an error after the run goes there)
    log_dir: Path | None = None  # else a benchctl.log here (the output folder)
    interrupting: bool = False  # a signal has been raised as Interrupted: later ones are ignored


_state = _State()


def reset() -> None:
    """Forget the log files of an earlier command (``main`` called twice in one process)."""
    global _state
    _state = _State()


def set_log_dir(folder: Path | None) -> None:
    """Where an unexpected exception's traceback goes when no run log exists (the output dir)."""
    _state.log_dir = folder


def current_log() -> Path | None:
    return _state.active_log


def ignored(sig: signal.Signals) -> bool:
    """True when ``sig`` is to stay ignored: SIGHUP the process was started with ignored (under
    ``nohup``, a closed terminal must not stop a run: the operator asked for that).

    SIGINT, SIGTERM and SIGQUIT are always handled, even when inherited ignored: a shell without
    job control starts its background commands with SIGINT and SIGQUIT ignored, nobody asked for
    it, and a ``kill -INT`` from a supervising script must still stop the stand safely."""
    if sig != signal.SIGHUP:
        return False
    try:
        return signal.getsignal(sig) is signal.SIG_IGN
    except (OSError, ValueError):
        return True


@contextmanager
def exit_signals() -> Iterator[None]:
    """While the block lasts (main thread only), the first exit signal raises ``Interrupted``
    where the program is; later ones are ignored so the way out is not itself interrupted."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: FrameType | None) -> None:
        if _state.interrupting:
            return
        _state.interrupting = True
        raise Interrupted(signum)

    old: dict[signal.Signals, Any] = {}
    for s in EXIT_SIGNALS:
        if not ignored(s):
            old[s] = signal.signal(s, handler)
    try:
        yield
    finally:
        _state.interrupting = True  # from here on the handler ignores them, until restored
        for s, h in old.items():
            signal.signal(s, h)
        _state.interrupting = False


# ------------------------------------------------------------------------------ logging
class _ConsoleFormatter(logging.Formatter):
    """One line per record: the traceback is left out (the log file has it) and named; a
    control character in the message (a serial's ESC, a device's CR/LF) shown as an escape
    (``benchctl.text.visible``), never sent to the terminal."""

    def format(self, record: logging.LogRecord) -> str:
        saved = record.exc_info, record.exc_text, record.stack_info
        record.exc_info, record.exc_text, record.stack_info = None, None, None
        try:
            text = super().format(record)
        finally:
            record.exc_info, record.exc_text, record.stack_info = saved
        if saved[0] and _state.active_log is not None:
            text += f" (traceback in {_state.active_log})"
        return visible(text)


class _QuietStreamHandler(logging.StreamHandler):
    def handleError(self, record: logging.LogRecord) -> None:
        pass  # a console gone away (SIGHUP, closed pipe) must not print a logging traceback


class _QuietFileHandler(logging.FileHandler):
    def handleError(self, record: logging.LogRecord) -> None:
        pass  # a full disk: the run's own recording reports it; logging stays silent

    def close(self) -> None:
        with contextlib.suppress(OSError):  # a full disk: the last flush fails, the file closes
            super().close()


def console_handler(level: int) -> logging.Handler:
    h = _QuietStreamHandler(sys.stderr)
    h.setLevel(level)
    h.setFormatter(_ConsoleFormatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    return h


@contextmanager
def run_log(folder: Path) -> Iterator[Path | None]:
    """Log INFO and up (and tracebacks) to ``folder/benchctl.log`` while the block lasts."""
    path = folder / LOG_NAME
    try:
        h = _QuietFileHandler(path, encoding="utf-8")
    except OSError as e:
        log.warning("no log file %s: %s", path, e.strerror)
        yield None
        return
    h.setFormatter(logging.Formatter(LOG_FORMAT))
    root = logging.getLogger()
    old_level = root.level
    if root.getEffectiveLevel() > logging.INFO:
        root.setLevel(logging.INFO)
    root.addHandler(h)
    prev = _state.active_log
    _state.active_log = _state.last_log = path
    try:
        yield path
    finally:
        _state.active_log = prev
        root.removeHandler(h)
        h.close()
        root.setLevel(old_level)


def crash_log(exc: BaseException, command: str = "", *, clock: Clock = REAL) -> Path | None:
    """Write ``exc``'s traceback to a log file (see the module doc); its path, or None. The
    stamp is ``clock``'s (the process's own crash: the real one unless a caller says)."""
    stamp = clock.now_utc().isoformat(timespec="milliseconds")
    head = f"{stamp} ERROR benchctl {command}: unexpected {type(exc).__name__}: {exc}\n"
    text = head + "".join(traceback.format_exception(exc))
    places = [_state.active_log, _state.last_log]
    if _state.log_dir is not None and _state.log_dir.is_dir():
        places.append(_state.log_dir / LOG_NAME)
    for p in places:
        if p is None:
            continue
        try:
            with p.open("a", encoding="utf-8") as f:
                f.write(text)
            return p
        except OSError:
            continue
    try:
        fd, name = tempfile.mkstemp(prefix="benchctl-", suffix=".log")
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        return Path(name)
    except OSError:
        return None


def unexpected(exc: BaseException, command: str = "") -> str:
    """The one line for an unexpected exception; its traceback goes to ``crash_log``."""
    where = crash_log(exc, command)
    line = f"unexpected {type(exc).__name__}: {exc}"
    return line + (f" (traceback in {where})" if where else "")


@contextmanager
def quiet_tracebacks() -> Iterator[None]:
    """An exception escaping a thread (or an unraisable one) is one log line, its traceback in
    the log file, instead of Python's traceback on stderr."""

    def thread_hook(args: threading.ExceptHookArgs) -> None:
        if args.exc_type is SystemExit or args.exc_value is None:
            return
        name = args.thread.name if args.thread is not None else "?"
        if _state.active_log is not None:
            log.error(
                "exception in thread %s: %s: %s",
                name,
                args.exc_type.__name__,
                args.exc_value,
                exc_info=(args.exc_type, args.exc_value, args.exc_traceback),
            )
        else:
            log.error("exception in thread %s: %s", name, unexpected(args.exc_value))

    def unraisable_hook(u: Any) -> None:
        if u.exc_value is None:
            return
        log.warning("%s: %s", u.err_msg or "exception ignored", unexpected(u.exc_value))

    old_thread, old_unraisable = threading.excepthook, sys.unraisablehook
    threading.excepthook = thread_hook
    sys.unraisablehook = unraisable_hook
    try:
        yield
    finally:
        threading.excepthook = old_thread
        sys.unraisablehook = old_unraisable
