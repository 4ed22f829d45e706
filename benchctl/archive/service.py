"""The archive as a run sees it: where it is (``ArchiveSettings`` from the config), storing a
finished run without ever failing or holding it up, the local queue, sync and rebuild.

- ``archive_run``: after a run's verdict (or abort) the recording's record is stored; when the
  database cannot be reached or written within its short timeouts (connect ~2 s, a lock or a
  busy SQLite file 2 s, a statement 4 s), the record goes into the queue folder instead, one
  ``<run_id>.json`` per run; a record the database refuses (a value it cannot store) is set
  aside in ``<queue>/refused/`` with its reason;
- ``archive_at_start``: at the start of a run, recordings left without ``end.json`` (a killed
  run) are stored ABORTED ("killed (no end.json)") and the queue is sent, when there is
  anything to do;
- ``RunArchive``: both for one run, the start's database work in the background and the
  run's record queued at once when the database was out of reach at the start;
- ``sync``: sends the queue (``benchctl archive sync``); a file leaves the queue only once its
  run is in the database, or set aside with its reason when the database refuses it (the rest
  still go); a database locked, read-only or out of reach stops it, the queue kept;
- ``rebuild``: stores every recording under a folder (``benchctl archive rebuild DIR``) — the
  recordings are the source of truth.

Storing is idempotent by run_id, so a record sent twice (queued and stored) is one run.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchctl.archive.ingest import (
    incomplete_recordings,
    is_live,
    record_of,
    recording_sha256,
    recordings_under,
)
from benchctl.archive.store import DEFAULT_CONNECT_TIMEOUT_S, Archive, shown
from benchctl.errors import ArchiveError, BenchError, DataError
from benchctl.fileout import atomic_write_bytes
from benchctl.jsonout import dumps
from benchctl.redact import redact_text

if TYPE_CHECKING:
    from benchctl.config import BenchConfig

log = logging.getLogger(__name__)

DEFAULT_DB = "archive.sqlite"
DEFAULT_QUEUE = "archive-queue"
DEFAULT_WRITE_TIMEOUT_S = 2.0  # a lock (a busy SQLite file) waited for; a statement: twice it
QUEUE_SUFFIX = ".json"
REFUSED = "refused"  # <queue_dir>/refused/: records the database refused, each with its reason
REASON_SUFFIX = ".reason"


@dataclass(frozen=True)
class ArchiveSettings:
    url: str
    queue_dir: Path
    enabled: bool = True
    connect_timeout_s: float = DEFAULT_CONNECT_TIMEOUT_S
    #: how long a statement waits for a lock another session holds (SQLite: a busy file);
    #: any one statement is given twice this (PostgreSQL's statement_timeout)
    write_timeout_s: float = DEFAULT_WRITE_TIMEOUT_S

    def open(self) -> Archive:
        """The archive with these timeouts (``ArchiveError`` when it cannot be opened)."""
        return Archive(self.url, connect_timeout_s=self.connect_timeout_s,
                       busy_timeout_s=self.write_timeout_s)


def settings_for(cfg: BenchConfig | None, out_dir: Path | None = None, *,
                 url: str | None = None, queue_dir: Path | None = None) -> ArchiveSettings:
    """The archive of a bench: ``url`` / ``queue_dir`` given here, else the config's
    ``archive:`` section, else ``sqlite:///<out_dir>/archive.sqlite`` and
    ``<out_dir>/archive-queue`` (``out_dir``: the run's output folder, by default the
    config's ``run.output_dir``)."""
    section = getattr(cfg, "archive", None) if cfg is not None else None
    if out_dir is None:
        out_dir = cfg.run.output_dir if cfg is not None else Path("runs")
    out_dir = Path(out_dir).resolve()
    u = url or (section.url if section is not None else None)
    if u is None:
        u = f"sqlite:///{out_dir / DEFAULT_DB}"
    elif u.startswith("sqlite:///") and not u.startswith("sqlite:////"):
        # a relative SQLite path: against the config file's folder, as every path in a config
        rel = u[len("sqlite:///"):]
        base = cfg.source.parent if cfg is not None and cfg.source is not None and not url \
            else Path.cwd()
        u = f"sqlite:///{(base / rel).resolve()}"
    q = queue_dir or (section.queue_dir if section is not None else None)
    return ArchiveSettings(
        url=u,
        queue_dir=Path(q) if q is not None else out_dir / DEFAULT_QUEUE,
        enabled=bool(section.enabled) if section is not None else True,
        connect_timeout_s=float(section.connect_timeout_s) if section is not None
        else DEFAULT_CONNECT_TIMEOUT_S,
        write_timeout_s=float(section.write_timeout_s) if section is not None
        else DEFAULT_WRITE_TIMEOUT_S,
    )


# --- the queue -------------------------------------------------------------------------------

def _entry(record: dict[str, Any], sha: str | None, source: str) -> dict[str, Any]:
    return {"record": record, "recording_sha256": sha, "source": source,
            "queued_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}


def enqueue(queue_dir: Path, entry: dict[str, Any]) -> Path:
    """Write one pending record as ``<queue_dir>/<run_id>.json`` (atomically; a newer entry
    for the same run replaces the older)."""
    run_id = str(entry["record"]["run_id"])
    queue_dir.mkdir(parents=True, exist_ok=True)
    dest = queue_dir / f"{run_id}{QUEUE_SUFFIX}"
    # strict JSON (benchctl.jsonout); a hidden temporary name the queue's listing skips, removed
    # when the write fails (a full disk leaves no 0-byte file behind)
    atomic_write_bytes(dest, dumps(entry, sort_keys=True).encode("utf-8"),
                       tmp_name=f".{run_id}.{os.getpid()}.tmp")
    return dest


def queued(queue_dir: Path) -> list[Path]:
    """The pending records, oldest first."""
    if not queue_dir.is_dir():
        return []
    files = [p for p in queue_dir.glob(f"*{QUEUE_SUFFIX}") if not p.name.startswith(".")]
    return sorted(files, key=lambda p: (p.stat().st_mtime, p.name))


def _utc_now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def _write_reason(folder: Path, name: str, reason: str) -> None:
    one_line = " ".join(redact_text(reason).split())
    (folder / f"{name}{REASON_SUFFIX}").write_text(f"{_utc_now()} {one_line}\n",
                                                  encoding="utf-8")


def set_aside(queue_dir: Path, path: Path, reason: str) -> str:
    """Move a queued file the database refused (or that is not a queued record) to
    ``<queue_dir>/refused/`` with ``<name>.reason`` beside it; returns ``"<name>: <reason>"``.
    ``OSError`` when it cannot be moved (it stays in the queue)."""
    folder = queue_dir / REFUSED
    folder.mkdir(parents=True, exist_ok=True)
    _write_reason(folder, path.name, reason)
    os.replace(path, folder / path.name)
    return f"{path.name}: {reason}"


def _refuse_entry(queue_dir: Path, entry: dict[str, Any], reason: str) -> Path:
    """A run's own record the database refused: straight into ``<queue_dir>/refused/``."""
    dest = enqueue(queue_dir / REFUSED, entry)
    _write_reason(dest.parent, dest.name, reason)
    return dest


def refused(queue_dir: Path) -> list[dict[str, str]]:
    """The records set aside: ``{"file", "path", "refused_utc", "reason"}`` each, oldest
    first."""
    folder = queue_dir / REFUSED
    if not folder.is_dir():
        return []
    out = []
    for p in folder.iterdir():
        if p.name.endswith(REASON_SUFFIX) or p.name.startswith(".") or not p.is_file():
            continue
        try:
            when, _, why = (folder / f"{p.name}{REASON_SUFFIX}").read_text(
                encoding="utf-8").strip().partition(" ")
        except OSError:
            when, why = "", "(no reason recorded)"
        out.append({"file": p.name, "path": str(p), "refused_utc": when, "reason": why})
    return sorted(out, key=lambda r: (r["refused_utc"], r["file"]))


@dataclass
class SyncResult:
    sent: list[str] = field(default_factory=list)
    #: set aside in <queue_dir>/refused/: "<file>: <reason>" (refused by the database, or not
    #: a queued record at all)
    refused: list[str] = field(default_factory=list)
    left: int = 0  # still queued
    #: why the sync stopped before the end of the queue (the database locked, read-only, out
    #: of reach…: the rest waits), None when it went through
    stopped: str | None = None
    stopped_kind: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"sent": self.sent, "refused": self.refused, "left": self.left,
                "stopped": self.stopped, "stopped_kind": self.stopped_kind}


def _read_entry(p: Path) -> dict[str, Any]:
    entry = json.loads(p.read_text(encoding="utf-8"))
    if not isinstance(entry, dict) or not isinstance(entry.get("record"), dict):
        raise ValueError("no record in it")
    return entry


def sync(settings: ArchiveSettings, archive: Archive | None = None) -> SyncResult:
    """Send the queue to the database, oldest first. ``ArchiveError`` when it cannot be
    opened (nothing leaves the queue then). A record the database refuses, and a file that
    is not a queued record, is set aside with its reason (``set_aside``) and the rest go on;
    any other failure (locked, read-only, timed out, lost) stops the sync there, the rest
    kept in the queue (``SyncResult.stopped``)."""
    res = SyncResult()
    files = queued(settings.queue_dir)
    if not files:
        return res
    own = archive is None
    a = archive or settings.open()
    try:
        for p in files:
            reason: str | None = None
            try:
                entry = _read_entry(p)
                record = entry["record"]
                a.store(record, recording_sha256=entry.get("recording_sha256"),
                        source=str(entry.get("source") or "record.json"))
            except FileNotFoundError:
                continue  # sent meanwhile by another process
            except (OSError, ValueError, KeyError, TypeError) as e:
                reason = f"not a queued record ({e})"
            except DataError as e:  # no run_id: this record can never be stored
                reason = f"refused: {e}"
            except ArchiveError as e:
                if e.kind != "refused":
                    res.stopped, res.stopped_kind = str(e), e.kind
                    log.warning("%s: sync stopped, %d record(s) kept in %s", e,
                                len(queued(settings.queue_dir)), settings.queue_dir)
                    break
                reason = str(e)
            if reason is None:
                p.unlink(missing_ok=True)
                res.sent.append(str(record.get("run_id")))
                continue
            try:
                res.refused.append(set_aside(settings.queue_dir, p, reason))
                log.warning("%s: %s: set aside in %s", p.name, reason,
                            settings.queue_dir / REFUSED)
            except OSError as e:
                log.warning("%s: %s; cannot be set aside (%s): left in the queue", p.name,
                            reason, e.strerror)
    finally:
        res.left = len(queued(settings.queue_dir))
        if own:
            a.close()
    return res


# --- a run's own archive ---------------------------------------------------------------------

# how the log says why a record was queued, from ArchiveError.kind
_WHY = {"unreachable": "is unreachable", "locked": "is locked", "read-only": "is read-only",
        "timed out": "did not answer in time", "denied": "denied the login",
        "failed": "failed"}


def _open_or_none(settings: ArchiveSettings) -> tuple[Archive | None, ArchiveError | None]:
    """The archive for a run's bookkeeping, or None and why (said in the log) when it cannot
    be had: the run goes on, its record queued."""
    try:
        return settings.open(), None
    except ArchiveError as e:
        log.warning("%s", e)
        return None, e


@dataclass
class _Stored:
    stored: list[str] = field(default_factory=list)
    queued: list[str] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    why: str = "unreachable"  # the kind of the last failure that queued a record


def _store_or_queue(settings: ArchiveSettings, entries: list[dict[str, Any]],
                    archive: Archive | None, why: str = "unreachable") -> _Stored:
    """Each entry stored, else queued (the database out of reach, locked, read-only…), else —
    refused by the database — set aside in ``<queue>/refused/`` with its reason. ``OSError``
    when the queue cannot be written."""
    out = _Stored(why=why)
    for e in entries:
        run_id = str(e["record"]["run_id"])
        if archive is not None:
            try:
                archive.store(e["record"], recording_sha256=e["recording_sha256"],
                              source=e["source"])
                out.stored.append(run_id)
                continue
            except ArchiveError as err:
                if err.kind == "refused":
                    dest = _refuse_entry(settings.queue_dir, e, str(err))
                    log.warning("%s: set aside in %s (it will never be stored as it is)",
                                err, dest.parent)
                    out.refused.append(run_id)
                    continue
                log.warning("%s", err)
                out.why = err.kind
            except Exception as err:  # whatever it is, the record must not be lost: queued
                log.warning("archive: run %s not stored (%s: %s)", run_id,
                            type(err).__name__, redact_text(str(err)), exc_info=err)
                out.why = "failed"
        enqueue(settings.queue_dir, e)
        out.queued.append(run_id)
    return out


def archive_run(settings: ArchiveSettings, recording: Path, *, try_database: bool = True,
                why: str = "unreachable") -> str:
    """Store the run in ``recording`` (its record.json, or one built from its files); never
    raises. Returns what happened: ``stored``, ``queued`` (the database unreachable, locked,
    read-only…: the record waits in the queue for ``benchctl archive sync``), ``refused`` (the
    database will not take this record: set aside in ``<queue>/refused/`` with its reason),
    ``disabled`` or ``failed`` (not even the queue could be written: a warning; ``benchctl
    archive rebuild`` recovers it from the recording). ``try_database=False``: queued at
    once (the database is known to be out of reach: ``why``, an ``ArchiveError.kind``)."""
    if not settings.enabled:
        return "disabled"
    try:
        record, source = record_of(recording)
        entry = _entry(record, recording_sha256(recording), source)
    except (BenchError, OSError) as e:
        log.warning("archive: %s: cannot read the run's record: %s", recording, e)
        return "failed"
    archive, err = _open_or_none(settings) if try_database else (None, None)
    try:
        done = _store_or_queue(settings, [entry], archive, err.kind if err else why)
        if done.stored and queued(settings.queue_dir) and archive is not None:
            try:  # the database is back: send what waited
                sync(settings, archive)
            except ArchiveError as e:
                log.warning("%s", e)
    except OSError as e:
        log.warning("archive: run %s neither stored nor queued (%s: %s); "
                    "`benchctl archive rebuild` recovers it from the recording",
                    recording.name, settings.queue_dir, e.strerror)
        return "failed"
    finally:
        if archive is not None:
            archive.close()
    if done.stored:
        log.info("archive: run %s stored in %s", recording.name, shown(settings.url))
        return "stored"
    if done.refused:
        return "refused"
    log.warning("archive: run %s queued in %s (the archive %s %s; "
                "`benchctl archive sync` sends it)", recording.name, settings.queue_dir,
                shown(settings.url), _WHY.get(done.why, done.why))
    return "queued"


def archive_at_start(settings: ArchiveSettings, out_dir: Path,
                     exclude: Path | None = None) -> dict[str, list[str]]:
    """At the start of a run: recordings in ``out_dir`` left without end.json (a killed run)
    and not yet archived are stored ABORTED, and the queue is sent. Does nothing (opens no
    database) when there is neither; never raises."""
    done = _empty_start()
    if not settings.enabled:
        return done
    work = _start_work(settings, out_dir, exclude)
    return _do_start_work(settings, *work)[0] if work is not None else done


def _empty_start() -> dict[str, list[str]]:
    return {"killed": [], "queued": [], "synced": []}


def _start_work(settings: ArchiveSettings, out_dir: Path,
                exclude: Path | None) -> tuple[list[Path], list[Path]] | None:
    """The killed recordings and the queued records found at the start (a scan of folders);
    None when they cannot be read (said in the log)."""
    try:
        return incomplete_recordings(out_dir, exclude=exclude), queued(settings.queue_dir)
    except (BenchError, OSError) as e:
        log.warning("archive: not updated at the start of the run: %s", e)
        return None


def _do_start_work(settings: ArchiveSettings, killed: list[Path], pending: list[Path],
                   probe: bool = False) -> tuple[dict[str, list[str]], bool | None, str]:
    """Store ``killed`` ABORTED and send the queue; never raises. Returns what was done,
    whether the database could be opened (None: not tried) and, when not, why (an
    ``ArchiveError.kind``). ``probe``: it is opened even with nothing to do."""
    done = _empty_start()
    reachable: bool | None = None
    why = "unreachable"
    if not killed and not pending and not probe:
        return done, reachable, why
    try:
        archive, err = _open_or_none(settings)
        reachable = archive is not None
        why = err.kind if err is not None else why
        try:
            known = archive.run_ids(d.name for d in killed) if archive is not None else set()
            entries = []
            for d in killed:
                name = f"{d.name}{QUEUE_SUFFIX}"
                if d.name in known or (settings.queue_dir / name).exists() \
                        or (settings.queue_dir / REFUSED / name).exists():
                    continue
                try:
                    record, source = record_of(d)
                except (DataError, OSError) as e:
                    log.warning("archive: %s: %s", d, e)
                    continue
                entries.append(_entry(record, recording_sha256(d), source))
            put = _store_or_queue(settings, entries, archive)
            done["killed"], done["queued"] = put.stored, put.queued
            if archive is not None and queued(settings.queue_dir):
                done["synced"] = sync(settings, archive).sent
        finally:
            if archive is not None:
                archive.close()
        for run_id in done["killed"] + done["queued"]:
            log.warning("archive: run %s was killed (no end.json): archived ABORTED", run_id)
    except (BenchError, OSError) as e:
        log.warning("archive: not updated at the start of the run: %s", e)
    except Exception as e:  # a background thread's: said, never raised into the run
        log.warning("archive: not updated at the start of the run (%s: %s)",
                    type(e).__name__, e, exc_info=e)
    return done, reachable, why


class RunArchive:
    """One run's archive bookkeeping, kept out of the run's way: a database out of reach (or
    hung) never holds the run up, before or after its motion.

    ``begin()``, before the run: the folders are scanned at once for killed runs and queued
    records (the scan must not see this run's own recording, made next); the database work —
    those stored, the queue sent — and a probe of the database go to a background thread,
    which the run's prechecks outlast. ``end(recording)``, after the verdict: waits for that
    thread (it is normally long done; at most its connect timeout more), then stores the run;
    when the database was out of reach at the start, the record goes straight into the queue
    (``benchctl archive sync``, or the next run's start, sends it) without a second wait."""

    def __init__(self, settings: ArchiveSettings, out_dir: Path) -> None:
        self.settings = settings
        self.out_dir = out_dir
        self.start_result: dict[str, list[str]] = _empty_start()
        #: whether the database could be opened at the start (None: not known yet)
        self.reachable: bool | None = None
        self.why = "unreachable"  # when it could not: why (an ArchiveError.kind)
        self._thread: threading.Thread | None = None

    def begin(self) -> None:
        if not self.settings.enabled:
            return
        work = _start_work(self.settings, self.out_dir, None)
        if work is None:
            return

        def run() -> None:
            self.start_result, self.reachable, self.why = _do_start_work(
                self.settings, *work, probe=True)

        self._thread = threading.Thread(target=run, name="archive-at-start", daemon=True)
        self._thread.start()

    def end(self, recording: Path) -> str:
        """Store the run (``archive_run``, within ``end_bound_s``); never raises."""
        if self._thread is None:  # nothing begun in the background: try it now
            return archive_run_within(self.settings, recording)
        # the start's work is bounded by the connect timeout and, per statement, the
        # statement timeout (twice the write timeout); it is not waited for longer
        self._thread.join(self.settings.connect_timeout_s + 2.0 * self.settings.write_timeout_s)
        # out of reach at the start, or still not answering: queued at once
        return archive_run_within(self.settings, recording, try_database=self.reachable is True,
                                  why=self.why if self.reachable is False else "unreachable")


def end_bound_s(settings: ArchiveSettings) -> float:
    """How long a run's end waits for the database at most: its connect timeout and two
    statement timeouts (each twice the write timeout). The server enforces its statement and
    lock timeouts itself; this bound holds when it cannot (a server stopped, or a network
    gone, in the middle of a statement)."""
    return settings.connect_timeout_s + 4.0 * settings.write_timeout_s


def archive_run_within(settings: ArchiveSettings, recording: Path, **kw: Any) -> str:
    """``archive_run`` given ``end_bound_s`` at most: when the database has not answered by
    then, the record is queued and ``queued`` returned while the attempt goes on in a daemon
    thread (a run's process ends without it; storing twice is harmless: one run, one row).
    Never raises."""
    box: list[str] = []

    def go() -> None:
        box.append(archive_run(settings, recording, **kw))

    t = threading.Thread(target=go, name="archive-at-end", daemon=True)
    t.start()
    bound = end_bound_s(settings)
    t.join(bound)
    if box:
        return box[0]
    try:
        record, source = record_of(recording)
        enqueue(settings.queue_dir, _entry(record, recording_sha256(recording), source))
    except (BenchError, OSError) as e:
        log.warning("archive: run %s: the archive %s did not answer within %g s, and the "
                    "record could not be queued (%s); `benchctl archive rebuild` recovers it "
                    "from the recording", recording.name, shown(settings.url), bound, e)
        return "failed"
    log.warning("archive: run %s queued in %s (the archive %s did not answer within %g s; "
                "`benchctl archive sync` sends it)", recording.name, settings.queue_dir,
                shown(settings.url), bound)
    return "queued"


# --- rebuild -------------------------------------------------------------------------------

@dataclass
class RebuildResult:
    stored: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # live runs, unreadable recordings
    #: "<recording>: <reason>": the database refused its record (the others still went)
    refused: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"stored": self.stored, "skipped": self.skipped, "refused": self.refused}


def rebuild(archive: Archive, root: Path,
            progress: Callable[[str, str], None] | None = None) -> RebuildResult:
    """Store every recording under ``root`` (record.json where there is one, else built from
    its files; a killed run ABORTED). A run still being written is skipped; a record the
    database refuses is listed (``refused``) and the others still go; any other failure
    (locked, read-only, out of reach) is an ``ArchiveError``: nothing more could be stored."""

    if not root.is_dir():
        raise DataError(f"{root}: not a folder of recordings")
    res = RebuildResult()
    for folder in recordings_under(root):
        if is_live(folder):
            res.skipped.append(f"{folder.name}: in progress (no end.json, written recently)")
            continue
        try:
            record, source = record_of(folder)
        except (DataError, OSError) as e:
            res.skipped.append(f"{folder.name}: {e}")
            continue
        try:
            archive.store(record, recording_sha256=recording_sha256(folder), source=source)
        except ArchiveError as e:
            if e.kind != "refused":
                raise
            log.warning("%s: %s", folder, e)
            res.refused.append(f"{folder.name}: {e}")
            continue
        res.stored.append(folder.name)
        if progress is not None:
            progress(folder.name, str(record.get("outcome")))
    return res


__all__ = [
    "ArchiveSettings",
    "RebuildResult",
    "RunArchive",
    "SyncResult",
    "archive_at_start",
    "archive_run",
    "archive_run_within",
    "enqueue",
    "queued",
    "rebuild",
    "refused",
    "set_aside",
    "settings_for",
    "sync",
]
