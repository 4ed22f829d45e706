"""The ``benchctl`` command line: thin; it parses, calls the layers below, and prints.

Each subcommand lives in its own module here with a ``register(subparsers)`` function that
adds its parser and sets ``handler`` (a function taking the parsed args and returning the exit
code). Heavy imports happen inside handlers so ``benchctl --help`` stays fast: the parser
alone takes about 0.15 s; the run, archive, report and plan layers with SciPy, Matplotlib,
Alembic and jsonschema imported up front take about 3.5 s on an idle 2-core machine (measured
with ``/usr/bin/time``), paid by every subcommand, ``--help`` and shell completion included.

Exit codes (``benchctl.outcomes.ExitCode``): 0 pass/success, 1 a measured FAIL (only that),
2 everything else: bad input, a device fault, an abort, a signal (SIGINT, SIGTERM, SIGHUP,
SIGQUIT), an unexpected exception; 3 a run judged INCONCLUSIVE by the guarded decision rule
(σ's 95 % interval straddles the limit).
No traceback reaches the console: ``main`` prints one line, ``benchctl <cmd>: error: …``, and an
unexpected exception's traceback goes to a log file named on that line (``benchctl.exits``).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from typing import Any

from benchctl import exits
from benchctl.errors import BenchError, Interrupted
from benchctl.outcomes import ExitCode
from benchctl.text import terminal_lines

# subcommands, in the order --help lists them (each a module here, its "-" a "_")
SUBCOMMANDS = (
    "run", "plan", "analyze", "report", "predict", "timing", "profile", "sim", "stand",
    "recording",
    "schema", "archive", "history", "show", "host-check", "serve", "serve-line",
)

class _Parser(argparse.ArgumentParser):
    """argparse exits with 2 on a usage error, which is our error code too."""


class _Version(argparse._VersionAction):
    """``--version``: the installed version, looked up when asked (``importlib.metadata``
    costs every command about 50 ms otherwise)."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        import benchctl

        self.version = f"benchctl {benchctl.__version__}"
        super().__call__(parser, namespace, values, option_string)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="benchctl",
        description="Dynamic-error tests of navigation instruments on a roll/pitch motion stand.",
    )
    parser.add_argument("--version", action=_Version)
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="more logging (-vv: wire trace)"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in SUBCOMMANDS:
        try:
            module_name = f"benchctl.cli.{name.replace('-', '_')}"  # host-check: host_check
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as e:
            if e.name == module_name:
                continue  # subcommand not built yet
            raise
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run one command; returns its exit code. Never raises (but argparse's own exits for
    ``--help`` and usage errors) and never prints a traceback."""
    exits.reset()
    # first thing: a signal from now on is a clean exit 2 with one line (the run takes them over)
    with exits.exit_signals():
        name = _command_name(argv)
        try:
            return _main(argv)
        except KeyboardInterrupt as e:  # a signal while reporting something else
            _say(f"{_prefix(name)}: {_interrupted(e)}")
            return ExitCode.ERROR
        finally:
            _flush_std()


def _main(argv: Sequence[str] | None) -> int:
    name = _command_name(argv)
    root = logging.getLogger()
    old_level = root.level
    console: logging.Handler | None = None
    try:
        with exits.quiet_tracebacks():
            parser = build_parser()
            args = parser.parse_args(argv)
            name = args.command
            level = logging.WARNING - 10 * min(args.verbose, 2)
            if not root.handlers:  # as logging.basicConfig: not when the host already logs
                console = exits.console_handler(level)
                root.addHandler(console)
            root.setLevel(min(level, logging.INFO))  # INFO also feeds a run's log file
            return int(args.handler(args))
    except BenchError as e:
        _say(f"{_prefix(name)}: error: {e}")
    except KeyboardInterrupt as e:
        _say(f"{_prefix(name)}: {_interrupted(e)}")
    except BrokenPipeError:  # the reader went away (`benchctl history | head`): nothing to say
        _flush_std()  # the closed stream pointed at /dev/null, so the exit cannot fail either
    except SystemExit:
        raise  # argparse: --help, --version, a usage error (exit 2)
    except BaseException as e:  # a bug: one line here, the traceback in a log file
        _say(f"{_prefix(name)}: error: {exits.unexpected(e, name)}")
    finally:
        if console is not None:
            root.removeHandler(console)
        root.setLevel(old_level)
    return ExitCode.ERROR


def _command_name(argv: Sequence[str] | None) -> str:
    words = list(sys.argv[1:] if argv is None else argv)
    return next((w for w in words if w in SUBCOMMANDS), "")


def _prefix(name: str) -> str:
    return f"benchctl {name}" if name else "benchctl"


def _interrupted(e: KeyboardInterrupt) -> str:
    return str(e) if isinstance(e, Interrupted) else "interrupted by SIGINT"


def _say(text: str) -> None:
    """A message on stderr, made safe (``benchctl.text.terminal_lines``: its own line breaks
    kept, any other control character shown as an escape); a console gone away (SIGHUP, a
    closed pipe) is not an error."""
    with contextlib.suppress(OSError, ValueError):
        print(terminal_lines(text.split("\n")), file=sys.stderr, flush=True)


def _flush_std() -> None:
    """Flush stdout/stderr now; one that cannot be written any more (the terminal closed) is
    pointed at /dev/null so the interpreter's own flush at exit cannot fail either."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            try:
                fd = stream.fileno()
                null = os.open(os.devnull, os.O_WRONLY)
                os.dup2(null, fd)
                os.close(null)
            except (OSError, ValueError, AttributeError):
                pass


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
