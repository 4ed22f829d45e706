"""``benchctl serve-line [--config C | --url URL | --out DIR] [--host H] [--port P]``: the line
view and the history pages (``benchctl.web.line``) served on their own, for a desk with no
station: every station's state, today's runs, the yields, the control charts of σ per part
number, from the archive the options name (the stations' shared PostgreSQL database).

Needs the ``web`` extra (FastAPI, uvicorn): without it, one line saying so (exit 2).
"""

from __future__ import annotations

import argparse
from typing import Any

from benchctl.cli.archive import add_archive_options, settings
from benchctl.errors import InputError

DEFAULT_HOST = "127.0.0.1"  # this computer only, unless asked for more
DEFAULT_PORT = 8081


def register(sub: Any) -> None:
    p = sub.add_parser(
        "serve-line",
        help="serve the line view and the history pages (a web page)",
        description=(
            "Serve the line view (every station's state, today's runs, the yield per station "
            "and per part number, the control charts of σ per part number) and the history "
            "pages of `benchctl history --html`, live from the archive, at "
            "http://HOST:PORT/line. Which archive: --url, else the config's archive: section "
            "(--config), else archive.sqlite in --out (or ./runs). Runs until interrupted "
            "(Ctrl-C). Needs the web extra: pip install 'benchctl[web]'."
        ),
    )
    add_archive_options(p)
    p.add_argument("--host", default=DEFAULT_HOST,
                   help=f"address to listen on (default {DEFAULT_HOST}: this computer only)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT,
                   help=f"port to listen on (default {DEFAULT_PORT})")
    p.add_argument("--stale-after", type=float, default=None, metavar="S",
                   help="a station silent for S seconds is shown offline (default 15)")
    p.set_defaults(handler=handle)


def build_app(args: argparse.Namespace) -> Any:
    """The app the options describe (``InputError`` when the web extra is missing)."""
    try:
        from benchctl.web.line import create_line_app
        from benchctl.web.linestations import STALE_AFTER_S
    except ModuleNotFoundError as e:
        raise InputError(f"benchctl serve-line needs {e.name}: pip install 'benchctl[web]'") \
            from None
    if not 1 <= args.port <= 65535:
        raise InputError(f"--port {args.port}: expected 1 … 65535")
    stale = STALE_AFTER_S if args.stale_after is None else args.stale_after
    if not stale > 0:
        raise InputError(f"--stale-after {args.stale_after}: expected a positive number")
    return create_line_app(settings(args).url, stale_after_s=stale)


def handle(args: argparse.Namespace) -> int:
    app = build_app(args)
    import uvicorn

    print(f"line view: http://{args.host}:{args.port}/line (Ctrl-C stops it)", flush=True)
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning")
    return 0
