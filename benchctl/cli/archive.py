"""``benchctl archive status|sync|rebuild DIR``: the results archive's queue (and the records
the database refused, set aside with their reasons), sending it, and the rebuild from
recordings. Which archive: ``--url``, else the config's ``archive:`` section (``--config``),
else the default SQLite file in the output folder (``--out``, else the config's
``run.output_dir``, else ./runs)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from benchctl.errors import InputError
from benchctl.jsonout import dumps
from benchctl.outcomes import ExitCode
from benchctl.text import terminal_lines

CLI_WRITE_TIMEOUT_S = 10.0  # history, show, rebuild: a lock waited for at least this long


def add_archive_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, help="bench config YAML (its archive: section)")
    p.add_argument("--url", metavar="URL",
                   help="the archive: sqlite:///PATH or postgresql+psycopg://USER@HOST/DB")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="output folder whose default archive to use (archive.sqlite there)")


def settings(args: argparse.Namespace) -> Any:
    from benchctl.archive.service import settings_for
    from benchctl.archive.store import parse_url
    from benchctl.config import load_config

    cfg = load_config(args.config) if args.config is not None else None
    if args.url is not None:
        parse_url(args.url, "--url")
    s = settings_for(cfg, args.out, url=args.url)
    parse_url(s.url, "archive.url")
    return s


def open_archive(args: argparse.Namespace, *, create: bool = False) -> Any:
    """The archive the options name; a SQLite file that does not exist is an error unless
    ``create`` (reading commands do not leave an empty database behind)."""
    from benchctl.archive.store import Archive, parse_url, shown

    s = settings(args)
    u = parse_url(s.url)
    if not create and u.drivername == "sqlite" and not Path(str(u.database)).is_file():
        raise InputError(
            f"archive {shown(s.url)}: no such file (no run archived there yet; "
            "expected --config, --url or --out naming an archive)"
        )
    return Archive(s.url, connect_timeout_s=s.connect_timeout_s,
                   busy_timeout_s=max(s.write_timeout_s, CLI_WRITE_TIMEOUT_S))


def register(sub: Any) -> None:
    p = sub.add_parser(
        "archive",
        help="the results archive: send the queue, rebuild",
        description=(
            "The results archive (a SQLite file, or a shared PostgreSQL database) that every "
            "run is stored in. status: the records queued while the database was out of reach "
            "and those it refused, set aside with their reasons. sync: send the queue. "
            "rebuild DIR: store every recording at or below DIR (after restoring a backup, "
            "or to fill a new shared database). Which archive: --url, else the config's "
            "archive: section (--config), else archive.sqlite in --out (or ./runs)."
        ),
    )
    rs = p.add_subparsers(dest="archive_command", metavar="ACTION")
    rs.required = True
    text = "the queue and the records set aside as refused (opens no database)"
    st = rs.add_parser("status", help=text, description=(
        f"{text[0].upper()}{text[1:]}: one line per queued record, and each refused record "
        "with the database's reason. Exit 0."))
    add_archive_options(st)
    st.add_argument("--json", action="store_true", help="one JSON object on stdout")
    st.set_defaults(handler=handle_status)
    sy = rs.add_parser(
        "sync", help="send the records queued while the archive was unreachable",
        description=(
            "Send the records queued while the archive was unreachable: a record leaves the "
            "queue once its run is in the database, or when the database refuses it (set "
            "aside with its reason: archive status); a database that cannot take records now "
            "(locked, read-only, out of reach) stops the sync with the rest kept in the queue. "
            "Exit 0, or 2 when a record was refused or the sync stopped."))
    add_archive_options(sy)
    sy.add_argument("--json", action="store_true", help="one JSON object on stdout")
    sy.set_defaults(handler=handle_sync)
    rb = rs.add_parser(
        "rebuild", help="store every recording under DIR in the archive",
        description=(
            "Store every recording at or below DIR (a recording, an output folder, a tree of "
            "them) in the archive, from its record.json (else its meta.json, end.json and "
            "report.json); a recording left without end.json by a killed run is stored "
            "ABORTED. Storing a run again replaces its rows."))
    rb.add_argument("dir", type=Path, metavar="DIR", help="a recording or a folder of them")
    add_archive_options(rb)
    rb.add_argument("--json", action="store_true", help="one JSON object on stdout")
    rb.set_defaults(handler=handle_rebuild)


def handle_status(args: argparse.Namespace) -> int:
    from benchctl.archive.service import queued, refused
    from benchctl.archive.store import shown

    s = settings(args)
    pending = [p.name for p in queued(s.queue_dir)]
    aside = refused(s.queue_dir)
    if args.json:
        print(dumps({"archive": shown(s.url), "queue_dir": str(s.queue_dir),
                     "queued": pending, "refused": aside}))
        return ExitCode.OK
    lines = [f"archive {shown(s.url)}",
             f"queue {s.queue_dir}: {len(pending)} record(s) waiting"
             + ("" if not pending else " (`benchctl archive sync` sends them)")]
    lines += [f"  queued   {name}" for name in pending]
    # file names and reasons carry run ids (serials) and database text: shown, never as escapes
    lines += [f"  refused  {r['file']} ({r['refused_utc']}): {r['reason']}" for r in aside]
    if aside:
        lines.append(f"refused records are kept in {s.queue_dir / 'refused'}: once the cause is "
                     "fixed, move one back into the queue folder to send it again")
    print(terminal_lines(lines))
    return ExitCode.OK


def handle_sync(args: argparse.Namespace) -> int:
    from benchctl.archive.service import REFUSED, queued, sync
    from benchctl.archive.store import shown

    s = settings(args)
    n = len(queued(s.queue_dir))
    res = sync(s)
    if args.json:
        print(dumps({"archive": shown(s.url), "queue_dir": str(s.queue_dir), **res.to_dict()}))
    elif n == 0:
        print(f"queue {s.queue_dir}: empty, nothing to send")
    else:
        lines = [f"sent {len(res.sent)} run(s) to {shown(s.url)}; {res.left} left in "
                 f"{s.queue_dir}"]
        lines += [f"  refused, set aside in {s.queue_dir / REFUSED}: {why}" for why in res.refused]
        if res.stopped is not None:
            lines.append(f"  stopped: {res.stopped}")
        print(terminal_lines(lines))
    return ExitCode.OK if not res.refused and res.stopped is None else ExitCode.ERROR


def handle_rebuild(args: argparse.Namespace) -> int:
    from benchctl.archive.service import rebuild

    if not args.dir.is_dir():
        raise InputError(f"{args.dir}: not a folder (expected a recording or a folder of them)")
    with open_archive(args, create=True) as a:
        res = rebuild(a, args.dir)
        name = a.name
    if args.json:
        print(dumps({"archive": name, **res.to_dict()}))
    else:
        print(f"stored {len(res.stored)} run(s) from {args.dir} in {name}")
        for why in res.skipped:
            print(f"  skipped {why}")
        for why in res.refused:
            print(f"  refused {why}")
    return ExitCode.OK if not res.refused else ExitCode.ERROR
