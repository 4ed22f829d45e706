"""The ``benchctl`` command line: thin; it parses, calls the layers below, and prints.

Each subcommand lives in its own module here with a ``register(subparsers)`` function that
adds its parser and sets ``handler`` (a function taking the parsed args and returning the exit
code). Heavy imports happen inside handlers so ``benchctl --help`` stays fast.

Exit codes: 0 pass/success, 1 a measured FAIL, 2 an error (bad input, device fault, abort).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from benchctl import __version__
from benchctl.errors import BenchError

# subcommand modules, in the order --help lists them
SUBCOMMANDS = ("run", "analyze", "profile", "sim", "recording")

EXIT_OK, EXIT_FAIL, EXIT_ERROR = 0, 1, 2


class _Parser(argparse.ArgumentParser):
    """argparse exits with 2 on a usage error, which is our error code too."""


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="benchctl",
        description="Dynamic-error tests of navigation instruments on a roll/pitch motion stand.",
    )
    parser.add_argument("--version", action="version", version=f"benchctl {__version__}")
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="more logging (-vv: wire trace)"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"benchctl.cli.{name}")
        except ModuleNotFoundError as e:
            if e.name == f"benchctl.cli.{name}":
                continue  # subcommand not built yet
            raise
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        code = int(args.handler(args))
    except BenchError as e:
        print(f"benchctl {args.command}: error: {e}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"benchctl {args.command}: interrupted", file=sys.stderr)
        return EXIT_ERROR
    return code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
