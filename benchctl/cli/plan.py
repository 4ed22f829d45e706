"""``benchctl plan PLAN.yaml --serial SN``: an acceptance plan, unattended. Exit 0 every step
PASS, 1 a measured FAIL, 2 an abort or error, 3 INCONCLUSIVE (guarded decision rule)."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path
from typing import Any

from benchctl.cli.run import ask_value
from benchctl.errors import InputError
from benchctl.outcomes import Outcome
from benchctl.text import terminal_lines, visible


def register(sub: Any) -> None:
    p = sub.add_parser(
        "plan",
        help="run an acceptance plan: setup, steps with their limits, cleanup; JUnit XML",
        description=(
            "Run an acceptance plan (YAML): setup actions (operator prompts, stand checks), "
            "its steps in order — each a whole run with the step's limits and failure policy "
            "(on_fail: stop|continue) and timeout — and cleanup actions, which always run "
            "(after a fail, an abort, a timeout, Ctrl-C). Prompts are asked on the terminal "
            "(y/N) or answered by --yes; with prompts, no terminal and no --yes the plan is "
            "refused before anything moves. A prompt answered no, not answered within the "
            "plan's prompt_timeout_s (default 600 s), ended by Ctrl-D or interrupted by a "
            "signal ends the plan and no cleanup action moves a stand the plan has not moved "
            "itself. Prints a summary (or --json: the plan record), "
            "writes plan.json in <output_dir>/plan_<time>_<serial>/ and, with --junit, JUnit "
            "XML. Exit 0 all PASS, 1 a measured FAIL, 2 an abort or error, 3 INCONCLUSIVE."
        ),
    )
    p.add_argument("plan", type=Path, help="plan YAML")
    p.add_argument("--serial", help="serial number of the unit under test")
    p.add_argument("--config", type=Path, help="bench config YAML (default: the plan's config)")
    p.add_argument("--operator", help="who runs the plan (default: the plan's operator)")
    p.add_argument("--yes", action="store_true",
                   help="answer every operator prompt yes (unattended use)")
    p.add_argument("--junit", type=Path, metavar="FILE.xml", help="write JUnit XML here")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="output folder of the recordings and the plan folder "
                   "(default run.output_dir)")
    p.add_argument("--json", action="store_true",
                   help="print the plan record (one JSON object, benchctl-plan/1) on stdout")
    p.add_argument("--quiet", action="store_true", help="no live progress of the steps' runs")
    p.add_argument("--live", type=Path, metavar="SOCKET",
                   help="also publish the plan's progress (its lines, each step's live state "
                   "and verdict, its prompts) as JSON datagrams to this Unix socket, never "
                   "waiting on it (benchctl serve starts its plans with it)")
    p.add_argument("--answers", type=Path, metavar="DIR",
                   help="with --live: the operator's prompts are answered on the panel, which "
                   "writes each answer into this folder (instead of the terminal)")
    p.set_defaults(handler=handle)


def _say(text: str) -> None:
    with contextlib.suppress(OSError, ValueError):
        print(f"plan: {visible(text)}", file=sys.stderr, flush=True)


def summary(result: Any) -> str:
    """One line per step and its judged measurements, then the plan's outcome; every line
    made safe for a terminal (``benchctl.text.visible``)."""
    lines = [f"plan {result.name}   serial {result.serial}   operator {result.operator}"]
    for a in result.setup:
        lines.append(f"  setup {a.index + 1}: {a.status}" + (f" — {a.detail}" if a.detail
                                                             else ""))
    for s in result.steps:
        head = f"  {s.status:<12} {s.name}"
        if s.duration_s:
            head += f"  ({s.duration_s:.0f} s)"
        if s.reason and s.status != Outcome.PASS:
            head += f"  {s.reason}"
        lines.append(head)
        for m in s.measurements:
            if not m.get("decisive") or m.get("outcome") == Outcome.NOT_JUDGED:
                continue
            if str(m.get("name", "")).startswith("precheck"):
                continue
            value = m.get("value")
            shown = f"{value:.4g}" if isinstance(value, float) else str(value)
            unit = f" {m['unit']}" if m.get("unit") not in (None, "1") else ""
            lim = " … ".join("" if x is None else f"{x:g}" for x in (m.get("low"), m.get("high")))
            axis = f"{m['axis']} " if m.get("axis") else ""
            lines.append(f"      {m['outcome']:<12} {axis}{m['name']} = {shown}{unit}  "
                         f"[{lim}]")
        if s.recording is not None:
            lines.append(f"      recording {s.recording}")
    for a in result.cleanup:
        lines.append(f"  cleanup {a.index + 1}: {a.status}" + (f" — {a.detail}" if a.detail
                                                               else ""))
    lines.append(f"{result.outcome}   exit {result.exit_code}"
                 + (f"   {result.reason}" if result.reason else "")
                 + f"   ({result.duration_s:.0f} s)")
    if result.record_path is not None:
        lines.append(f"plan record {result.record_path}")
    if result.junit is not None:
        lines.append(f"JUnit XML {result.junit}")
    return terminal_lines(lines)  # a serial's or an operator's ESC or CR/LF shown, not sent


def handle(args: argparse.Namespace) -> int:
    from benchctl.jsonout import dumps
    from benchctl.plan import load_plan, run_plan
    from benchctl.run.display import make_display
    from benchctl.text import check_operator, check_serial
    from benchctl.web.plan_live import PlanLive

    # as benchctl run: the stand loop thread gets the interpreter within its period
    sys.setswitchinterval(0.001)
    plan = load_plan(args.plan)
    # the config's serial_pattern, if any, is checked by run_plan once the config is read
    serial = ask_value(args.serial, "Serial number of the instrument", "--serial", check_serial)
    operator = ask_value(args.operator or plan.operator, "Operator", "--operator",
                         check_operator)
    if args.answers is not None and args.live is None:
        raise InputError("--answers DIR needs --live SOCKET (the panel that answers)")
    live = PlanLive(args.live, args.answers, plan.prompt_timeout_s)
    try:
        result = run_plan(
            plan,
            serial=serial,
            config=args.config,
            operator=operator,
            yes=args.yes,
            ask=live.asker(),
            out_dir=args.out,
            junit=args.junit,
            display=lambda: live.display(make_display(sys.stderr, quiet=args.quiet)),
            say=live.say(_say),
        )
    finally:
        live.close()
    with contextlib.suppress(OSError):
        if args.json:
            print(dumps(result.to_dict()))
        else:
            print(summary(result))
    return result.exit_code
