"""``benchctl serve --config BENCH.yaml``: the station's web panel (``benchctl.web``)."""

from __future__ import annotations

import argparse
import getpass
import sys
from pathlib import Path
from typing import Any

from benchctl.errors import BenchError, InputError

WEB_EXTRA = 'the web panel needs the "web" extra: pip install "benchctl[web]" (from a ' \
    'checkout: pip install -e ".[web]")'


def register(sub: Any) -> None:
    p = sub.add_parser(
        "serve",
        help="the station's web panel: start, watch and stop runs from a browser",
        description=(
            "Serve the station's web panel: the operator scans or types the serial, chooses a "
            "profile and starts a run; the page shows its state, time, angles, tracking, the "
            "running σ and the stand's health live, Stop (the same path as Ctrl-C: the stand "
            "brought to rest, the recording closed) and the verdict with its report. Each run "
            "is a child process (benchctl run --live) with its own real-time loop: the panel, "
            "a browser or the server going away never touches the motion, and a panel started "
            "again takes up the run it left going (a state file in the runs' output folder). "
            "Listens on "
            "127.0.0.1 unless told otherwise; on any other address an access token is required "
            "(--hash-token makes its hash for the panel settings file). Needs the web extra."
        ),
    )
    p.add_argument("--config", type=Path, help="bench config YAML (required to serve)")
    p.add_argument("--panel", type=Path, metavar="FILE",
                   help="panel settings YAML, instead of the bench config's panel: section (the "
                   "same fields: lang, profiles, plans, duration_s, host, port, token_scrypt, "
                   "require_token, origins, out_dir; the options below override it)")
    p.add_argument("--profile", type=Path, action="append", metavar="FILE|DIR",
                   help="a profile the operator may choose, or a folder of them (*.yaml); "
                   "repeatable (default: the panel settings' profiles)")
    p.add_argument("--plan", type=Path, action="append", metavar="FILE",
                   help="an acceptance plan the operator may start (its prompts become dialogs "
                   "on the panel); repeatable (default: the panel settings' plans)")
    p.add_argument("--lang", choices=("en", "ru"), help="the operator's language (default en)")
    p.add_argument("--host", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, help="port to listen on (default 8350)")
    p.add_argument("--duration", type=float, metavar="SEC",
                   help="each run's profile duration (default: the profile's)")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="the runs' output folder (default run.output_dir)")
    p.add_argument("--require-token", action="store_true", default=None,
                   help="ask for the access token on loopback too (behind a reverse proxy)")
    p.add_argument("--origin", action="append", metavar="URL",
                   help="an address browsers reach the panel by (https://bench3.example.org, "
                   "behind a reverse proxy); repeatable")
    p.add_argument("--hash-token", action="store_true",
                   help="read an access token (the terminal, hidden; or one line on stdin) and "
                   "print its hash for the panel settings file (token_scrypt:), then exit")
    p.set_defaults(handler=handle)


def _read_token() -> str:
    if sys.stdin.isatty():
        token = getpass.getpass("Access token: ")
        if getpass.getpass("Again: ") != token:
            raise InputError("the two tokens differ; nothing printed")
    else:
        token = sys.stdin.readline().rstrip("\r\n")
    if len(token) < 12:
        raise InputError("an access token needs at least 12 characters")
    return token


def settings_from(args: argparse.Namespace) -> Any:
    """The panel's settings: the bench config's ``panel:`` section, or the file ``--panel``
    names instead, the options over it."""
    from benchctl.config import load_config
    from benchctl.web.settings import PanelSettings, plan_files, profile_files, read_panel_file

    if args.config is None:
        raise InputError("--config is required (the bench config of this station)")
    # a bad config refused before anything listens
    f = read_panel_file(args.panel) if args.panel is not None else load_config(args.config).panel
    pick = (lambda opt, name, default: opt if opt is not None  # noqa: E731
            else getattr(f, name) if f is not None else default)
    origins = tuple(args.origin) if args.origin else tuple(f.origins if f else ())
    duration = pick(args.duration, "duration_s", None)
    if duration is not None and not duration > 0:
        raise InputError(f"--duration {duration!r}: expected a duration > 0 s")
    return PanelSettings(
        config=args.config.resolve(),  # the runs' children may start elsewhere
        profiles=tuple(p.resolve() for p in profile_files(args.profile or
                                                          (f.profiles if f else []))),
        plans=tuple(p.resolve() for p in plan_files(args.plan or (f.plans if f else []))),
        lang=pick(args.lang, "lang", "en"),
        duration_s=duration,
        host=pick(args.host, "host", "127.0.0.1"),
        port=pick(args.port, "port", 8350),
        token_scrypt=f.token_scrypt if f is not None else None,
        require_token=bool(pick(args.require_token, "require_token", False)),
        origins=origins,
        out_dir=None if (out := pick(args.out, "out_dir", None)) is None else out.resolve(),
    )


def handle(args: argparse.Namespace) -> int:
    if args.hash_token:
        from benchctl.web.security import hash_token

        print(f"token_scrypt: \"{hash_token(_read_token())}\"")
        return 0
    try:
        import fastapi  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as e:
        raise BenchError(f"{WEB_EXTRA} ({e.name} is missing)") from None
    from benchctl.config import load_config
    from benchctl.web.server import serve

    settings = settings_from(args)
    load_config(settings.config)  # a bad config refused before anything listens (--panel)
    serve(settings)
    return 0
