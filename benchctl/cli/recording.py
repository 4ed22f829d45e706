"""``benchctl recording show|export``: look into a recording, export it to CSV or MATLAB .mat."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from benchctl.errors import InputError
from benchctl.jsonout import dumps
from benchctl.outcomes import ExitCode
from benchctl.text import terminal_lines


def register(sub: Any) -> None:
    p = sub.add_parser(
        "recording",
        help="show or export a recording",
        description=(
            "A recording folder (what a run writes: meta.json, events.jsonl, end.json and "
            "the stand, instrument and setpoint streams as CSV): show what it holds, or "
            "export its streams to CSV files or one MATLAB .mat file."
        ),
    )
    rs = p.add_subparsers(dest="recording_command", metavar="ACTION")
    rs.required = True
    show = rs.add_parser(
        "show", help="metadata, end state and stream sizes of a recording",
        description=(
            "A recording's metadata (serial, operator, station, profile, devices), its end "
            "state (done or aborted, and why) and each stream's rows, time span and columns."))
    show.add_argument("path", type=Path, help="recording folder")
    show.add_argument("--json", action="store_true", help="one JSON object on stdout")
    show.set_defaults(handler=handle_show)
    exp = rs.add_parser(
        "export", help="export the streams to CSV files or one .mat file",
        description=(
            "Export a recording's streams: one CSV file per stream into a folder (--csv DIR), "
            "or all of them into one MATLAB .mat file (--mat FILE)."))
    exp.add_argument("path", type=Path, help="recording folder")
    g = exp.add_mutually_exclusive_group(required=True)
    g.add_argument("--csv", type=Path, metavar="DIR", help="one CSV per stream into DIR")
    g.add_argument("--mat", type=Path, metavar="FILE", help="all streams into one MATLAB .mat")
    exp.set_defaults(handler=handle_export)


def summary(path: Path) -> dict[str, Any]:
    from benchctl.recording import load_recording

    rec = load_recording(path)
    m = rec.meta
    streams = {}
    for name, cols in rec.streams.items():
        t = cols.get("t_host", cols.get("t_send"))
        n = 0 if t is None else int(t.size)
        span = float(t[-1] - t[0]) if n > 1 and t is not None else 0.0
        streams[name] = {"rows": n, "span_s": span, "columns": list(cols)}
    return {
        "path": str(rec.path),
        "state": rec.state,
        "integrity": rec.integrity.to_dict(),
        "reason": (rec.end or {}).get("reason", ""),
        "serial": m.get("serial"),
        "operator": m.get("operator"),
        "station": m.get("station"),
        "profile": m.get("profile_name"),
        "seed": m.get("seed"),
        "axes": list(rec.axes),
        "start_utc": m.get("start_utc"),
        "end_utc": (rec.end or {}).get("end_utc"),
        "software_version": m.get("software_version"),
        "devices": m.get("devices", {}),
        "streams": streams,
        "events": len(rec.events),
        "states": [e.get("to") for e in rec.events if e.get("kind") == "state"],
    }


def handle_show(args: argparse.Namespace) -> int:
    s = summary(args.path)
    if args.json:
        print(dumps(s))
        return ExitCode.OK
    integrity = s["integrity"]
    failed = integrity["status"] == "FAILED"
    lines = [
        f"recording {s['path']}",
        f"  state      {s['state']}" + (f" ({s['reason']})" if s["reason"] else "")
        + (" — INTEGRITY FAILED" if failed else ""),
        *f"  integrity  {_integrity_text(integrity)}".split("\n"),
        f"  serial     {s['serial']}   operator {s['operator']}   station {s['station']}",
        f"  profile    {s['profile']} (seed {s['seed']}), axes {', '.join(s['axes'])}",
        f"  start/end  {s['start_utc']} → {s['end_utc'] or '(not closed)'}",
    ]
    for role, d in (s["devices"] or {}).items():
        lines.append(f"  {role:<10} {d.get('vendor', '')} {d.get('model', '')} "
                     f"{d.get('serial', '')}")
    for name, st in s["streams"].items():
        lines.append(f"  {name:<10} {st['rows']} rows over {st['span_s']:.1f} s")
    lines.append(f"  states     {' → '.join(str(x) for x in s['states'])}")
    # the serial, the operator, the devices' identities: shown, never sent as escapes
    print(terminal_lines(lines))
    return ExitCode.OK


def _integrity_text(d: dict[str, Any]) -> str:
    """The integrity line of ``recording show`` (``Integrity.to_dict``)."""
    if d["status"] == "verified":
        return f"verified: rows and SHA-256 as end.json states ({', '.join(d['files'])})"
    if d["status"] == "FAILED":
        return "INTEGRITY FAILED, altered after the run closed it:\n" + "\n".join(
            f"               {p}" for p in d["problems"])
    return f"unknown, not verifiable: {d['note']}"


def handle_export(args: argparse.Namespace) -> int:
    from benchctl.recording import load_recording

    if not args.path.is_dir():
        raise InputError(f"{args.path}: not a recording folder")
    rec = load_recording(args.path)
    if args.csv is not None:
        for f in rec.export_csv(args.csv):
            print(f)
    else:
        print(rec.export_mat(args.mat))
    return ExitCode.OK
