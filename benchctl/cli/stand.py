"""``benchctl stand status | reset | home --config CFG``: the stand outside a run.

``status`` reads the stand (angle, rate, setpoint per axis; ready, enabled, moving, fault,
E-stop, limit) and who holds its lock; it takes no lock and writes nothing. ``reset`` clears a
latched fault or E-stop (the watchdog's fault after a ``kill -9``); ``home`` brings the stand to
zero within its limits (servo on, ramp, servo off). Both take the stand's lock (refused while a
run holds it, naming the holder), ask on the terminal — or take ``--yes``; without either they
are refused before anything opens — and are logged in ``<run.output_dir>/stand.log``.
Exit 0 done (or nothing to do), 2 refused, declined, failed or interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchctl.outcomes import ExitCode


def register(sub: Any) -> None:
    p = sub.add_parser(
        "stand",
        help="the stand outside a run: status, reset a latched fault, bring it home to zero",
        description=(
            "The stand outside a run. status: its angles, rates, fault, E-stop, servo state "
            "and who holds its lock (no lock taken, nothing written). reset: clear a latched "
            "fault or E-stop (e.g. the heartbeat watchdog's after a run was killed); the servo "
            "stays off. home: servo on, a ramp to zero within the configured rate and "
            "acceleration limits, servo off. reset and home take the stand's lock (refused "
            "while a run holds it), ask on the terminal or take --yes (neither: refused, exit "
            "2), and append a line to <run.output_dir>/stand.log. With a config that "
            "simulates its bench (a sim: section) the stand is the one `benchctl sim --config "
            "CFG` serves. Exit 0 done or nothing to do, 2 refused, declined or failed."
        ),
    )
    acts = p.add_subparsers(dest="action", metavar="ACTION")
    acts.required = True
    st = acts.add_parser(
        "status", help="the stand's state and its lock's holder",
        description=(
            "The stand's angles, rates, fault, E-stop and servo state, and who holds its "
            "lock; no lock taken, nothing written, nothing moved."))
    st.add_argument("--config", required=True, type=Path, help="bench config YAML")
    st.add_argument("--json", action="store_true", help="one JSON object on stdout")
    st.set_defaults(handler=handle)
    for name, text in (("reset", "clear a latched fault or E-stop (the servo stays off)"),
                       ("home", "ramp the stand to zero within its limits, then servo off")):
        a = acts.add_parser(name, help=text, description=text)
        a.add_argument("--config", required=True, type=Path, help="bench config YAML")
        a.add_argument("--yes", action="store_true",
                       help="do it without asking (no terminal: required)")
        a.add_argument("--operator", help="who does it (in the stand's lock and its log)")
        a.set_defaults(handler=handle)


def _say(text: str) -> None:
    with contextlib.suppress(OSError, ValueError):
        print(text, file=sys.stderr, flush=True)


def _yes(question: str) -> bool:
    _say(f"{question} yes (--yes)")
    return True


def handle(args: argparse.Namespace) -> int:
    from benchctl.config import load_config
    from benchctl.errors import InputError
    from benchctl.jsonout import dumps
    from benchctl.plan.prompts import terminal_asker
    from benchctl.run import standctl

    cfg = load_config(args.config)
    if args.action == "status":
        state = standctl.read_state(cfg)
        with contextlib.suppress(OSError):
            if args.json:
                print(dumps(state.to_dict()))
            else:
                print("\n".join(standctl.describe(state, cfg.source)))
        return ExitCode.OK
    confirm: Callable[[str], bool]
    if args.yes:
        confirm = _yes
    else:
        asker = terminal_asker()
        if asker is None:
            raise InputError(f"benchctl stand {args.action} asks on the terminal before it acts "
                             "and there is none: confirm with --yes")
        confirm = asker
    who = {"operator": args.operator} if args.operator else {}
    act = standctl.reset_fault if args.action == "reset" else standctl.home
    out = act(cfg, confirm, who)
    _say(f"benchctl stand {args.action}: {out.detail}"
         + (f" (logged in {out.log_file})" if out.log_file is not None else ""))
    return ExitCode.ERROR if out.declined else ExitCode.OK
