"""``benchctl run``: one whole test, prechecks to verdict. Exit 0 PASS, 1 FAIL, 2 error/abort,
3 INCONCLUSIVE (guarded decision rule)."""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from benchctl.errors import ConfigError, InputError

ABORT_WORDS = {"operator": "operator stop", "equipment": "equipment fault",
               "software": "software error"}


def register(sub: Any) -> None:
    p = sub.add_parser(
        "run",
        help="run a dynamic-error test: prechecks, profile, analysis, verdict",
        description=(
            "Run a test: prechecks, fade-in, the profile, fade-out, analysis and a PASS/FAIL "
            "verdict against run.limit_sigma_deg. Every way out (Ctrl-C, SIGTERM, SIGHUP, "
            "SIGQUIT, a device fault, a silent instrument, a breach, a full disk) brings the "
            "stand to rest, closes the recording marked aborted and exits 2. One run per stand: "
            "a stand in use by another run is refused before connecting (run.lock_dir)."
        ),
    )
    p.add_argument("--config", required=True, type=Path, help="bench config YAML")
    p.add_argument("--profile", required=True, type=Path, help="motion profile YAML")
    p.add_argument("--serial", help="serial number of the instrument under test")
    p.add_argument("--operator", help="who runs the test")
    p.add_argument("--duration", type=float, metavar="SEC", help="profile duration (s)")
    p.add_argument("--seed", type=int, help="override the profile's seed")
    p.add_argument(
        "--scale-to-fit",
        action="store_true",
        help="scale a profile over the stand limits down (the report says by how much)",
    )
    p.add_argument(
        "--precision",
        type=float,
        metavar="FRACTION",
        help="stop once σ's 95 %% interval is within ± this fraction of σ (0 < FRACTION < 1, "
        "e.g. 0.05; after at least one whole period of the multisine; overrides run.precision)",
    )
    p.add_argument(
        "--equalise",
        action="store_true",
        default=None,
        help="before the motion, a short low-level pre-test measures the stand's response on the "
        "profile's lines and the drive is corrected by it (turns run.equalise.enabled on)",
    )
    p.add_argument(
        "--decision-rule",
        choices=("simple", "guarded"),
        help="how σ is judged against its limit: simple (σ ≤ limit) or guarded (the 95 %% "
        "interval wholly within: PASS, wholly beyond: FAIL, else INCONCLUSIVE, exit 3); "
        "overrides run.decision_rule",
    )
    p.add_argument("--part-number", help="part number of the unit (overrides unit.part_number)")
    p.add_argument("--out", type=Path, metavar="DIR", help="output folder (default run.output_dir)")
    p.add_argument("--json", action="store_true", help="print one JSON object (report) on stdout")
    p.add_argument("--quiet", action="store_true", help="no live progress on stderr")
    p.add_argument(
        "--live",
        type=Path,
        metavar="SOCKET",
        help="also publish the live progress (state, angles, σ, messages, verdict) as JSON "
        "datagrams to this Unix socket, never waiting on it (benchctl serve starts its runs "
        "with it)",
    )
    p.set_defaults(handler=handle)


def ask_value(value: str | None, what: str, option: str,
              check: Callable[[str, str], str] | None = None) -> str:
    """``value``, else a line asked for on the terminal; no terminal: ``option`` is required.

    ``check(text, option)`` returns the value to use or raises ``InputError``
    (``benchctl.text``: a serial, an operator): a given ``value`` it refuses ends the command
    (exit 2); a line typed on the terminal it refuses is explained and asked for again. The
    input ending at the prompt (Ctrl-D: end of file) ends the command too (exit 2), saying so."""
    if value is not None:  # given, even empty or blank: checked, never asked for again
        return check(value, option) if check is not None else value
    if not (sys.stdin.isatty() and sys.stderr.isatty()):
        raise ConfigError(f"{option} is required (the {what.lower()}); no terminal to ask on")
    while True:
        sys.stderr.write(f"{what}: ")
        sys.stderr.flush()
        line = sys.stdin.readline()
        if not line:  # end of file: Ctrl-D on an empty line
            sys.stderr.write("\n")  # the command's message on a line of its own
            raise InputError(f"{option}: the input ended (EOF, Ctrl-D) at the prompt for the "
                             f"{what.lower()}; nothing was run")
        if not line.strip():
            continue
        if check is None:
            return line.strip()
        try:
            return check(line, option)
        except InputError as e:
            sys.stderr.write(f"{e}\n")


def handle(args: argparse.Namespace) -> int:
    from benchctl.config import load_config
    from benchctl.jsonout import dumps
    from benchctl.options import MAX_RUN_DURATION_S, MAX_SEED, check_option
    from benchctl.run import RunOptions, run_test
    from benchctl.run.display import make_display
    from benchctl.run.prepare import check_motion_length
    from benchctl.text import check_operator, check_part_number, check_serial
    from benchctl.web.live import live_display

    # The stand loop thread must get the interpreter within a fraction of its 10 ms period when
    # the instrument reader or the display holds it: hand the GIL over every 1 ms, not 5 ms.
    sys.setswitchinterval(0.001)
    # option ranges (docs/reference/run.md, the option table), before anything is read or opened
    check_option("--duration", args.duration, 0, MAX_RUN_DURATION_S, lo_open=True, unit="s")
    check_option("--seed", args.seed, 0, MAX_SEED)
    if args.precision is not None and not (
        math.isfinite(args.precision) and 0.0 < args.precision < 1.0
    ):
        raise InputError(
            f"--precision {args.precision!r}: expected a fraction 0 < value < 1 (e.g. 0.05 for "
            "±5 %)"
        )
    cfg = load_config(args.config)
    if args.duration is not None:  # before asking anything (the run checks every motion)
        check_motion_length(cfg.stand, args.duration, f"--duration {args.duration:g}")
    pattern, where = cfg.unit.serial_pattern, f"unit.serial_pattern of {cfg.source}"
    serial = ask_value(args.serial, "Serial number of the instrument", "--serial",
                       lambda v, o: check_serial(v, o, pattern, where))
    operator = ask_value(args.operator, "Operator", "--operator", check_operator)
    part_number = None if args.part_number is None else check_part_number(args.part_number)
    opts = RunOptions(
        serial=serial,
        operator=operator,
        duration_s=args.duration,
        out_dir=args.out,
        seed=args.seed,
        scale_to_fit=args.scale_to_fit,
        precision=args.precision,
        decision_rule=args.decision_rule,
        part_number=part_number,
        equalise=args.equalise,
    )
    # on a terminal the verdict's banner waits for the summary: the last thing on the screen
    display = make_display(sys.stderr, quiet=args.quiet, hold_banner=not args.json)
    result = run_test(cfg, args.profile, opts, display=live_display(display, args.live))
    if args.json:
        with contextlib.suppress(OSError):  # the console may be gone: the exit code still tells
            print(dumps(result.to_dict()))
        return result.exit_code
    print_outcome(result, display)
    return result.exit_code


def summary_lines(result: Any) -> list[str]:
    """The run's summary for stdout: the report's text, or an aborted run's reason, cleanup
    steps and files."""
    from benchctl.run.report import format_report
    from benchctl.text import visible

    if result.report is not None:
        return str(format_report(result.report)).split("\n")
    lines = [f"ABORTED: {visible(result.reason)}"]
    if result.abort is not None:
        lines.append(f"  abort: {ABORT_WORDS.get(result.abort['kind'], result.abort['kind'])}")
    if result.measured is not None:
        lines.append(f"  {_measured_text(result.measured)}")
    if result.shutdown:
        lines.append("  cleanup:")
        for step in result.shutdown:
            ok = "ok" if step["ok"] else f"FAILED {step['detail']}"
            lines.append(f"    {step['step']}: {ok}"
                         + (f" ({step['detail']})" if step["ok"] and step["detail"] else "")
                         + (f" (at the {step['when']})" if step.get("when") else ""))
    if result.recording is not None:
        closed = any(s["step"] == "close recording" and s["ok"] for s in result.shutdown)
        how = "closed, marked aborted" if closed else "NOT closed: no end.json"
        lines.append(f"  recording {result.recording} ({how})")
    if result.log is not None:
        lines.append(f"  log {result.log}")
    if result.record is not None:
        lines.append(f"  record {result.record}")
    stand_after: dict[str, Any] | None = (result.abort or {}).get("stand")
    if stand_after:  # where the stand is, and how to bring it to zero
        from benchctl.run.outputs import stand_lines

        lines += [f"  {visible(line)}" for line in stand_lines(stand_after)]
    return lines


def print_outcome(result: Any, display: Any) -> None:
    """The summary on stdout, then the verdict's banner the display held back (stderr), so the
    banner is the last thing on the screen. With both on a terminal the summary is wrapped at
    words to its width and, with the banner, kept within its height (less detail, and where the
    rest is: ``_where_in_full``)."""
    from benchctl.run.display import TtyDisplay, fit_rows, rows_of, terminal_size

    # the console may be gone (SIGHUP, a closed pipe): the exit code still tells
    with contextlib.suppress(OSError):
        try:
            lines = summary_lines(result)
            held = display.held if isinstance(display, TtyDisplay) else []
            if sys.stdout.isatty():
                size = terminal_size(sys.stdout)
                width = max(20, size.columns - 1)  # the last column left: no early fold
                room = size.lines - 1 - rows_of(held, size.columns)  # a row for the prompt
                more = _where_in_full(result)
                lines = fit_rows(lines, width, max(room, 3), more, size.columns)
            sys.stdout.write("\n".join(lines) + "\n")
            sys.stdout.flush()
        finally:
            if isinstance(display, TtyDisplay):
                display.show_banner()


def _where_in_full(result: Any) -> str:
    """Where the lines a terminal's summary leaves out are: the recording's report.txt (a
    finished run), else its end.json (an aborted run: the reason and the cleanup's steps)."""
    if result.recording is None:
        return ""
    for name in ("report.txt", "end.json"):
        if (Path(result.recording) / name).is_file():
            return str(Path(result.recording) / name)
    return ""


def _measured_text(m: dict[str, Any]) -> str:
    """The verdict an aborted run measured before its outputs failed (a full disk)."""
    axes = "; ".join(f"{a} σ {v['sigma']:.4f}° limit {v['limit']:g}° {v['verdict']}"
                     for a, v in m.get("axes", {}).items())
    return (f"measured before the abort: {m['verdict']} ({axes}); not the run's result: its "
            "report, record or archive could not all be written (the reason above), exit 2")
