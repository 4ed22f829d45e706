"""``benchctl show RUN [--json]``: one run from the results archive (RUN: its recording
folder's name, or the folder itself)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from benchctl.cli.archive import add_archive_options, open_archive
from benchctl.errors import InputError
from benchctl.jsonout import dumps
from benchctl.outcomes import ExitCode


def register(sub: Any) -> None:
    p = sub.add_parser(
        "show",
        help="one run from the results archive",
        description=(
            "One run from the results archive: its unit, station, operator, times, outcome "
            "(an aborted run's kind and reason), profile, software, the recording and report "
            "with their SHA-256, every measurement with its value, interval, limits and "
            "outcome, and the recording's integrity checked now (when its folder is on this "
            "computer). --json: the same as one JSON object with the run's whole record. "
            "RUN is the recording folder's name, or the folder. Exit 0, or 2 for a run not in "
            "the archive."
        ),
    )
    p.add_argument("run", metavar="RUN", help="run id (the recording folder's name) or folder")
    add_archive_options(p)
    p.add_argument("--json", action="store_true",
                   help="one JSON object: the run, its measurements and its whole record")
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from benchctl.archive.history import show_text

    run_id = Path(args.run.rstrip("/")).name or args.run
    with open_archive(args) as a:
        run = a.show(run_id)
        name = a.name
    if run is None:
        raise InputError(f"run {run_id!r}: not in the archive {name}")
    integrity = _integrity(run)
    if args.json:
        print(dumps({**run, "integrity": integrity.to_dict()}))
    else:
        print(show_text(run))
        print(f"integrity  {integrity.text()}")
    return ExitCode.OK


def _integrity(run: dict[str, Any]) -> Any:
    """The integrity of the run's recording folder, checked now (``recording.reader``):
    unknown when the folder is not on this computer."""
    from benchctl.recording import verify_recording
    from benchctl.recording.reader import UNKNOWN, Integrity

    path = (run.get("recording") or {}).get("path")
    if not path or not Path(path).is_dir():
        return Integrity(UNKNOWN, note=f"recording folder {path} not found here")
    return verify_recording(path)
