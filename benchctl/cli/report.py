"""``benchctl report RECORDING``: (re)render a recording's ``report.html``."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

from benchctl.errors import DataError
from benchctl.outcomes import ExitCode

log = logging.getLogger(__name__)


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "report",
        help="(re)render a recording's report.html (self-contained, prints on A4)",
        description=(
            "Render the run's report as one self-contained HTML file, report.html in the "
            "recording folder, from its report.json, record.json and the recording itself (an "
            "aborted run: what is known). The record's files.report_html is updated to the new "
            "file's SHA-256."
        ),
    )
    p.add_argument("recording", help="recording folder")
    p.add_argument("--out", metavar="FILE.html",
                   help="write here instead (the record is then left as it is)")
    p.add_argument("--no-trace", action="store_true",
                   help="without the time-trace excerpt (does not read the streams)")
    p.set_defaults(handler=run)


def run(args: argparse.Namespace) -> int:
    from benchctl.recording import is_recording
    from benchctl.report.html import REPORT_HTML, build_context, render_html, write_html
    from benchctl.results.record import RECORD_JSON, load_record, with_file, write_record

    folder = Path(args.recording)
    if not folder.is_dir():
        raise DataError(f"{folder}: no such recording folder")
    if not is_recording(folder):
        raise DataError(f"{folder}: not a benchctl recording (no meta.json)")
    if args.out:
        dest = Path(args.out)
        html = render_html(build_context(folder, trace=not args.no_trace))
        try:
            dest.write_text(html, encoding="utf-8")
        except OSError as e:
            raise DataError(f"{dest}: cannot write the report: {e.strerror}") from None
        print(dest)
        return ExitCode.OK
    record = load_record(folder) if (folder / RECORD_JSON).exists() else None
    try:
        dest = write_html(folder, record=record, trace=not args.no_trace)
    except OSError as e:
        raise DataError(f"{folder / REPORT_HTML}: cannot write the report: {e.strerror}") from None
    if record is not None:
        write_record(folder, with_file(record, "report_html", dest))
    print(dest)
    return ExitCode.OK
