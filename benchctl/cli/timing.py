"""``benchctl timing calibrate``: the bench's stream-to-stream offset from a run of a reference of
known latency, stored dated in the bench config (``benchctl.run.timing_cal``)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from benchctl.errors import InputError
from benchctl.jsonout import dumps
from benchctl.outcomes import ExitCode


def register(sub: Any) -> None:
    p = sub.add_parser(
        "timing",
        help="calibrate the bench's own timing (the delay between its two streams)",
        description=(
            "The bench's own timing: the delay its acquisition adds between the stand's "
            "samples and the instrument's (serial line, CAN adapter, USB, the host's stamps), "
            "measured on a run of a reference of known latency and applied to every later "
            "run's analysis (the config's timing: section)."
        ),
    )
    ts = p.add_subparsers(dest="timing_command", metavar="ACTION")
    ts.required = True
    cal = ts.add_parser(
        "calibrate",
        help="measure the offset on a recording of a reference of known latency",
        description=(
            "Measure the bench's stream-to-stream offset on RECORDING, a run (benchctl run, any "
            "multisine profile) of a reference instrument whose response is a pure delay "
            "(--reference-latency-s, certified). The offset is the delay measured beyond that "
            "latency (plus the offset the recording was already analysed with). --write stores "
            "it, with today's date, in the bench config's timing: section."
        ),
    )
    cal.add_argument("recording", type=Path, metavar="RECORDING", help="the reference's run")
    cal.add_argument("--reference-latency-s", type=float, required=True, metavar="SEC",
                     help="the reference's certified latency (s)")
    cal.add_argument("--reference", metavar="TEXT",
                     help="what the reference is (model, serial, certificate): into the config")
    cal.add_argument("--axis", choices=("roll", "pitch"),
                     help="the axis to measure on (default: the recording's first)")
    cal.add_argument("--write", type=Path, metavar="CONFIG.yaml",
                     help="store the offset in this bench config (its timing: section replaced)")
    cal.add_argument("--json", action="store_true", help="one JSON object on stdout")
    cal.set_defaults(handler=handle_calibrate)


def handle_calibrate(args: argparse.Namespace) -> int:
    from benchctl.config import load_config
    from benchctl.recording import load_recording
    from benchctl.run.timing_cal import calibrate_recording, timing_section, write_timing

    if not math.isfinite(args.reference_latency_s) or abs(args.reference_latency_s) > 10:
        raise InputError(f"--reference-latency-s {args.reference_latency_s!r}: expected a "
                         "finite latency in seconds (|L| ≤ 10)")
    rec = load_recording(args.recording)
    rec.require_intact()
    cal = calibrate_recording(rec, args.reference_latency_s, axis=args.axis)
    out = cal.to_dict()
    if args.write is not None:
        try:
            text = args.write.read_text(encoding="utf-8")
        except OSError as e:
            raise InputError(f"{args.write}: cannot read the bench config: {e.strerror}") from None
        new = write_timing(text, timing_section(cal, args.reference))
        tmp = args.write.with_name(args.write.name + ".timing-tmp")
        tmp.write_text(new, encoding="utf-8")
        try:
            load_config(tmp)  # refused (ConfigError) before the config is touched
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        tmp.replace(args.write)
        out["written"] = str(args.write)
    if args.json:
        print(dumps(out))
        return ExitCode.OK
    print(f"bench timing offset {cal.offset_s * 1e3:+.4f} ms ± {cal.uncertainty_s * 1e3:.4f} ms "
          f"(the reference's delay {cal.measured_delay_s * 1e3:.4f} ms as analysed, certified "
          f"{cal.reference_latency_s * 1e3:g} ms, offset applied then "
          f"{cal.previous_offset_s * 1e3:+.4f} ms; {cal.fit.n_lines} lines, gain "
          f"{cal.fit.gain:.4f})")
    for w in cal.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if args.write is not None:
        print(f"written to {args.write} (timing:, calibrated {cal.date.isoformat()})")
    return ExitCode.OK
