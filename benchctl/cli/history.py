"""``benchctl history [SERIAL] [--since DATE] [--station S] [--json|--csv] [--html FILE]``:
the runs in the results archive, oldest first; with a serial, that unit's σ over its runs;
the stations' yield per day (JSON and the HTML page)."""

from __future__ import annotations

import argparse
from datetime import datetime
from pathlib import Path
from typing import Any

from benchctl.cli.archive import add_archive_options, open_archive
from benchctl.errors import InputError
from benchctl.jsonout import dumps
from benchctl.outcomes import ExitCode


def since_date(text: str) -> datetime:
    """--since: a date (YYYY-MM-DD, UTC midnight) or an ISO time (naive: UTC)."""
    from benchctl.archive.rows import utc_naive

    d = utc_naive(text)
    if d is None:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected a date YYYY-MM-DD or an ISO time YYYY-MM-DDTHH:MM[:SS][+00:00]"
        )
    return d


def register(sub: Any) -> None:
    p = sub.add_parser(
        "history",
        help="runs in the results archive (a unit's, a station's)",
        description=(
            "The runs in the results archive, oldest first: every run, or one unit's (SERIAL), "
            "one station's (--station), from a date on (--since). As a table, CSV (--csv) or "
            "one JSON object (--json: the runs, the yield per day, and with SERIAL the unit's "
            "σ over its runs); --html FILE also writes the history page (σ over the runs with "
            "its limit, the yield per day, the table of runs; self-contained, prints on A4). "
            "Which archive: --url, else the config's archive: section (--config), else "
            "archive.sqlite in --out (or ./runs). Exit 0, or 2 for an archive that cannot be "
            "read."
        ),
    )
    p.add_argument("serial", nargs="?", help="only this unit's runs (and its σ over them)")
    p.add_argument("--since", type=since_date, metavar="DATE", help="runs started from DATE on")
    p.add_argument("--station", metavar="S", help="only runs of station S")
    add_archive_options(p)
    g = p.add_mutually_exclusive_group()
    g.add_argument("--json", action="store_true",
                   help="one JSON object: runs, sigma (with SERIAL), yield per day")
    g.add_argument("--csv", action="store_true", help="the runs as CSV")
    p.add_argument("--html", type=Path, metavar="FILE",
                   help="also write the history page (σ plot, yield per day) to FILE")
    p.set_defaults(handler=handle)


def handle(args: argparse.Namespace) -> int:
    from benchctl.archive import history as h

    with open_archive(args) as a:
        rows = a.history(args.serial, since=args.since, station=args.station)
        listed = {r["run_id"] for r in rows}  # the σ series of the runs selected
        series = [s for s in a.sigma_series(args.serial) if s["run_id"] in listed] \
            if args.serial else []
        # a station's yield where a station is asked for, or no unit: every station's
        stations = (a.station_yield(args.station, since=args.since)
                    if args.station is not None or not args.serial else [])
        name = a.name
    # a unit's yield: its own runs' verdicts (not its stations' days)
    yields = h.unit_yield_per_day(args.serial, rows) if args.serial else stations
    if args.html is not None:
        page = h.html_page(rows, archive=name, serial=args.serial, sigma_series=series,
                           yields=[*yields, *stations] if args.serial else yields,
                           station=args.station,
                           since=None if args.since is None else args.since.isoformat())
        try:
            args.html.write_text(page, encoding="utf-8")
        except OSError as e:
            raise InputError(f"{args.html}: cannot write the history page: {e.strerror}") from None
    if args.json:
        out: dict[str, Any] = {"archive": name, "runs": rows, "yield_per_day": yields}
        if args.serial:
            out["sigma"] = series
            out["yield"] = h.unit_yield(args.serial, rows)
            if args.station is not None:
                out["station_yield_per_day"] = stations
        print(dumps(out))
    elif args.csv:
        print(h.to_csv(rows), end="")
    else:
        print(h.to_text(rows))
        if args.html is not None:
            print(f"history page: {args.html}")
    return ExitCode.OK
