"""``benchctl host-check --config BENCH.yaml [--window S] [--json]``: the host fitness check
alone — the host's scheduling latency measured and judged against the config's stand, as a run
does before its motion (``benchctl.run.fitness``). Nothing is opened, nothing moves.
Exit 0 the host leaves the margin asked for, 1 it does not, 2 an error."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path
from typing import Any

from benchctl.outcomes import ExitCode

MAX_WINDOW_S = 60.0


def register(sub: Any) -> None:
    p = sub.add_parser(
        "host-check",
        help="measure this computer's scheduling latency and judge it against a bench config",
        description=(
            "Measure this computer's scheduling latency as a run does before its motion (the "
            "host fitness check; cf. cyclictest, LinuxCNC's latency test): threads ask to wake "
            "every run.host_check.period_s (1 ms) and every stand-loop period for the window "
            "(run.host_check.window_s, 2 s), each wake's lateness is measured, and the worst "
            "times run.host_check.margin is judged against what the config's stand tolerates "
            "(its buffer, a streaming loop's send window, its heartbeat watchdog's slack). "
            "With run.realtime_priority the threads ask for that SCHED_FIFO priority first and "
            "say whether they got it. Prints the figures and the verdict; nothing is opened, "
            "nothing moves. Useful to qualify a line PC. Exit 0 the host leaves the margin, "
            "1 it does not (a run would warn or refuse: run.host_check.on_poor), 2 an error."
        ),
    )
    p.add_argument("--config", required=True, type=Path, help="bench config YAML")
    p.add_argument("--window", type=float, metavar="S",
                   help=f"measure for S seconds (0 < S ≤ {MAX_WINDOW_S:g}; default: "
                        "run.host_check.window_s)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    p.set_defaults(handler=handle)


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.3f} ms"


def lines(check: Any) -> list[str]:
    """The figures under the verdict's line: each period's, the bounds, the priority."""
    out = [check.line]
    for s in check.per_period:
        over = ", ".join(f"{t * 1e3:g} ms: {n}" for t, n in s.over)
        out.append(
            f"  every {s.period_s * 1e3:g} ms: {s.count} wakes, median {_ms(s.median_s)}, "
            f"p99 {_ms(s.p99_s)}, p99.9 {_ms(s.p999_s)}, max {_ms(s.max_s)}; "
            f"later than {over}")
    tightest = check.verdict.bound
    for b in check.bounds:
        out.append(f"  against {b.text}" + (" (the tightest)" if b is tightest else ""))
    if not check.bounds:
        out.append("  against nothing: a table-mode stand without stand.watchdog_s")
    if check.realtime is not None:
        out.append(f"  {check.realtime.detail}")
    return out


def handle(args: argparse.Namespace) -> int:
    import math

    from benchctl.clock import REAL
    from benchctl.config import load_config
    from benchctl.errors import InputError
    from benchctl.jsonout import dumps
    from benchctl.run.fitness import host_check

    if args.window is not None and not (math.isfinite(args.window)
                                        and 0 < args.window <= MAX_WINDOW_S):
        raise InputError(f"--window {args.window:g}: expected seconds, "
                         f"0 < S ≤ {MAX_WINDOW_S:g}")
    cfg = load_config(args.config)
    stop = REAL.event()
    try:
        check = host_check(cfg, REAL, stop, window_s=args.window)
    finally:
        stop.set()  # an interrupted measurement's threads end at once
    with contextlib.suppress(OSError):
        if args.json:
            print(dumps({"line": check.line, **check.values()}))
        else:
            print("\n".join(lines(check)))
        sys.stdout.flush()
    return ExitCode.OK if check.ok else ExitCode.FAIL
