"""Write a recording as the run goes (thread-safe, line-buffered, crash-safe).

A write that fails (disk full, I/O error) raises ``RecordingError`` once, naming the file and the
errno, and reports it to ``on_error``; from then on rows and events are dropped and counted
(``dropped_rows``, ``dropped_events``) instead of raising again, so the run's cleanup goes on.
``close`` still writes ``end.json`` (with the error and the counts) and raises
``RecordingError`` only when it cannot.

Room for ``end.json``: the writer keeps a reserve file (``RESERVE_FILE``, ``RESERVE_BYTES``
allocated on the disk; a quarter or a sixteenth of it when a file size limit or a nearly full
disk refuses that, none when even that is refused) in the recording from its start; ``close``
(or ``release_reserve``, on a full disk) deletes it just before writing ``end.json``, so a disk
that filled up during the run still has room for the closing record (and the run's
``record.json`` after it).

Integrity: every byte written to a data file (the three streams, ``events.jsonl``,
``meta.json``) goes through a SHA-256 and its rows are counted; ``close`` writes them into
``end.json`` (``integrity``), which the reader checks (``benchctl.recording.reader``). A file
whose write failed is hashed and counted as found on the disk at close.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import numbers
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import IO, Any

from benchctl import __version__
from benchctl.clock import REAL, Clock
from benchctl.devices.base import InstrumentSample, StandSample
from benchctl.errors import InputError, RecordingError, is_disk_full
from benchctl.fileout import atomic_write_bytes
from benchctl.jsonout import dumps
from benchctl.recording.format import (
    END_FILE,
    EVENTS_FILE,
    FORMAT_NAME,
    FORMAT_VERSION,
    INTEGRITY_ALGORITHM,
    META_FILE,
    RESERVE_BYTES,
    RESERVE_FILE,
    STREAM_COLUMNS,
    STREAM_FILES,
)


def _num(x: float | int | None) -> str:
    if type(x) is float:  # the usual case, first: what the general path below does with it
        return repr(x) if math.isfinite(x) else "nan"
    if x is None:
        return ""
    if isinstance(x, numbers.Integral):  # numpy's integers too
        return str(int(x))
    f = float(x)  # numpy's floats too (their repr is not a number)
    return repr(f) if math.isfinite(f) else "nan"


def _json_bytes(obj: Mapping[str, Any]) -> bytes:
    return (dumps(obj, indent=2) + "\n").encode("utf-8")


def _atomic_json(path: Path, obj: Mapping[str, Any]) -> bytes:
    """Write ``obj`` as ``path`` atomically (no ``.tmp`` left when it fails); its bytes."""
    data = _json_bytes(obj)
    atomic_write_bytes(path, data)
    return data


def make_reserve(path: Path, size: int = RESERVE_BYTES) -> None:
    """A new file of ``size`` bytes really allocated on the disk (``posix_fallocate``; where
    the file system cannot, random bytes are written, which no compression can shrink)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    try:
        try:
            os.posix_fallocate(fd, 0, size)
        except OSError as e:
            if is_disk_full(e):
                raise
            left = size
            while left > 0:
                left -= os.write(fd, os.urandom(min(left, 1 << 16)))
    except BaseException:
        os.close(fd)
        with contextlib.suppress(OSError):
            path.unlink()
        raise
    os.close(fd)


def file_integrity(path: Path, header_lines: int) -> dict[str, Any]:
    """``{rows, bytes, sha256}`` of a data file as it is on the disk: ``rows`` its complete
    lines after ``header_lines`` (a torn last line is not a row: the reader drops it)."""
    h = hashlib.sha256()
    size = lines = 0
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
            size += len(chunk)
            lines += chunk.count(b"\n")
    return {"rows": max(0, lines - header_lines), "bytes": size, "sha256": h.hexdigest()}


class _Tally:
    """SHA-256, bytes and rows of what was written to one file."""

    def __init__(self) -> None:
        self.sha = hashlib.sha256()
        self.bytes = 0
        self.rows = 0

    def add(self, data: bytes, row: bool = True) -> None:
        self.sha.update(data)
        self.bytes += len(data)
        self.rows += int(row)

    def to_dict(self) -> dict[str, Any]:
        return {"rows": self.rows, "bytes": self.bytes, "sha256": self.sha.hexdigest()}


def utc_now(clock: Clock = REAL) -> str:
    return clock.now_utc().isoformat(timespec="milliseconds")


class RecordingWriter:
    """Opens a new recording folder and appends to its streams.

    Every ``write_*`` call goes straight to the OS: a killed process loses nothing written.
    ``close(state, reason)`` writes ``end.json``; it is idempotent. The first failed write raises
    ``RecordingError`` (and calls ``on_error`` with it, from the writing thread); later writes are
    dropped and counted.
    """

    def __init__(
        self,
        path: str | Path,
        axes: Sequence[str],
        meta: Mapping[str, Any],
        on_error: Callable[[RecordingError], None] | None = None,
        *,
        clock: Clock = REAL,
    ) -> None:
        self.clock = clock
        self.path = Path(path)
        if self.path.exists() and any(self.path.iterdir()):
            raise InputError(f"{self.path}: recording folder exists and is not empty")
        self.path.mkdir(parents=True, exist_ok=True)
        self.axes = tuple(axes)
        self._lock = clock.lock()
        self._closed = False
        self._end_written = False
        self._close_lock = clock.lock()
        self._meta_lock = clock.lock()  # meta.json's rewrites (update_meta)
        self.counts = {name: 0 for name in STREAM_FILES}
        self.dropped_rows = 0  # stream rows not written after a write failure
        self.dropped_events = 0
        self._rows_off = False  # release_reserve: a full disk, rows dropped from now on
        self.error: RecordingError | None = None  # the first write failure
        self._on_error = on_error
        self.t0_monotonic = clock.monotonic()
        full_meta = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "software_version": __version__,
            "axes": list(self.axes),
            "start_utc": utc_now(clock),
            "start_monotonic": self.t0_monotonic,
            **meta,
        }
        self._meta: dict[str, Any] = full_meta
        self._meta_bytes = _atomic_json(self.path / META_FILE, full_meta)
        # what was written to each data file (end.json's integrity), and the files whose
        # write failed (counted from the disk at close)
        self._tally = {fname: _Tally() for fname in (*STREAM_FILES.values(), EVENTS_FILE)}
        self._suspect: set[str] = set()
        self.reserve: Path | None = self.path / RESERVE_FILE
        self.reserve_bytes = 0
        for size in (RESERVE_BYTES, RESERVE_BYTES // 4, RESERVE_BYTES // 16):
            try:  # best effort: a file size limit (EFBIG) or a nearly full disk takes less
                make_reserve(self.reserve, size)
            except OSError:
                continue
            self.reserve_bytes = size
            break
        else:
            self.reserve = None  # no room kept (the prechecks' free-space check says more)
        self._files: dict[str, IO[str]] = {}
        for name, fname in STREAM_FILES.items():
            f = (self.path / fname).open("w", encoding="utf-8", buffering=1, newline="\n")
            head = ",".join(STREAM_COLUMNS[name](self.axes)) + "\n"
            f.write(head)
            self._tally[fname].add(head.encode("utf-8"), row=False)
            self._files[name] = f
        self._events = (self.path / EVENTS_FILE).open(
            "w", encoding="utf-8", buffering=1, newline="\n"
        )

    def _failed(self, path: Path, e: OSError, what: str = "write") -> RecordingError:
        """Record the first failure (call with the lock held)."""
        self._suspect.add(path.name)
        err = RecordingError.from_oserror(path, e, what)
        if self.error is None:
            self.error = err
        return err

    def _report(self, err: RecordingError) -> RecordingError:
        if self._on_error is not None:
            with contextlib.suppress(Exception):  # a broken listener must not hide the error
                self._on_error(err)
        return err

    def _write(self, name: str, fields: list[str]) -> None:
        line = ",".join(fields) + "\n"
        with self._lock:
            if self._closed:
                return
            if self.error is not None or self._rows_off:
                self.dropped_rows += 1
                return
            try:
                self._files[name].write(line)
            except OSError as e:
                self.dropped_rows += 1
                err = self._failed(self.path / STREAM_FILES[name], e)
            else:
                self.counts[name] += 1
                self._tally[STREAM_FILES[name]].add(line.encode("utf-8"))
                return
        raise self._report(err)

    def write_stand(self, s: StandSample) -> None:
        a = self.axes
        fields = [_num(s.t_host), _num(s.rtt_s)]
        fields += [_num(s.angle_deg.get(ax)) for ax in a]
        fields += [_num(s.rate_deg_s.get(ax)) for ax in a]
        fields += [_num(s.setpoint_deg.get(ax)) for ax in a]
        st = s.status
        word = (
            int(st.ready)
            | int(st.enabled) << 1
            | int(st.moving) << 2
            | int(st.fault) << 3
            | int(st.estop) << 4
            | int(st.limit) << 5
            | int(st.table_running) << 6
        )
        fields += [str(word), str(st.fault_code)]
        lo, hi = s.t_window if s.t_window is not None else (None, None)
        fields += [_num(lo), _num(hi), _num(s.t_stand)]
        self._write("stand", fields)

    def write_instrument(self, s: InstrumentSample) -> None:
        fields = [_num(s.t_host), _num(s.device_time_s), _num(s.counter), _num(s.adapter_time_s)]
        fields += [_num(s.angle_deg.get(ax)) for ax in self.axes]
        self._write("instrument", fields)

    def write_setpoint(
        self, t_send: float, angle_deg: Mapping[str, float], t_slot: float | None = None
    ) -> None:
        """A commanded setpoint sent at ``t_send``: the profile's value at slot time ``t_slot``."""
        fields = [_num(t_send), _num(t_slot)] + [_num(angle_deg.get(ax)) for ax in self.axes]
        self._write("setpoints", fields)

    def update_meta(self, **fields: Any) -> None:
        """Add or replace metadata fields (meta.json is rewritten atomically; on a write failure
        the old file stays and ``RecordingError`` is raised, as for any first failure).

        The rewrite ends in an fsync, which a busy disk can make last seconds: it holds only
        its own lock, never the one the streams' rows take, so the stand loop and the
        instrument reader, whose rows are written meanwhile, never wait for the disk."""
        with self._meta_lock:  # one rewrite at a time, in the order asked
            with self._lock:
                self._meta = meta = {**self._meta, **fields}
            try:
                data = _atomic_json(self.path / META_FILE, meta)
            except OSError as e:
                with self._lock:
                    err = self._failed(self.path / META_FILE, e)
            else:
                with self._lock:
                    self._meta_bytes = data
                return
        raise self._report(err)

    def event(self, kind: str, **fields: Any) -> None:
        rec = {"t_host": self.clock.monotonic(), "utc": utc_now(self.clock), "kind": kind, **fields}
        line = dumps(rec) + "\n"
        with self._lock:
            if self._closed:
                return
            if self.error is not None:
                self.dropped_events += 1
                return
            try:
                self._events.write(line)
            except OSError as e:
                self.dropped_events += 1
                err = self._failed(self.path / EVENTS_FILE, e)
            else:
                self._tally[EVENTS_FILE].add(line.encode("utf-8"))
                return
        raise self._report(err)

    def close(self, state: str, reason: str = "", **extra: Any) -> None:
        """Flush and close the streams, write ``end.json``; idempotent once ``end.json`` is
        written. Raises ``RecordingError`` when ``end.json`` cannot be written (the streams are
        closed anyway; a later call tries ``end.json`` again, with its own state and reason)."""
        with self._close_lock:
            self._close(state, reason, extra)

    def _close(self, state: str, reason: str, extra: dict[str, Any]) -> None:
        with self._lock:
            if self._end_written:
                return
            again = self._closed
            self._closed = True
        if not again:
            named = [(self.path / STREAM_FILES[n], f) for n, f in self._files.items()]
            for path, f in (*named, (self.path / EVENTS_FILE, self._events)):
                try:
                    f.flush()
                    os.fsync(f.fileno())
                except OSError as e:
                    with self._lock:
                        self._failed(path, e)
                finally:
                    with contextlib.suppress(OSError):
                        f.close()  # closes the descriptor even when its last flush fails
        self._release_reserve()  # the room kept for end.json (a full disk: it is needed now)
        end: dict[str, Any] = {
            "state": state,
            "reason": reason,
            "end_utc": utc_now(self.clock),
            "end_monotonic": self.clock.monotonic(),
            "counts": dict(self.counts),
            **extra,
            "integrity": self.integrity(),
        }
        if self.error is not None or self.dropped_rows:
            if self.error is not None:
                end["recording_error"] = str(self.error)
            end["dropped_rows"] = self.dropped_rows
            end["dropped_events"] = self.dropped_events
        try:
            _atomic_json(self.path / END_FILE, end)
        except OSError as e:
            raise RecordingError.from_oserror(self.path / END_FILE, e) from None
        self._end_written = True

    def release_reserve(self) -> None:
        """The disk is full: give the room kept for ``end.json`` back now, for the abort's last
        events and ``end.json``; stream rows from now on are dropped and counted
        (``dropped_rows``), so the stand's samples during the cleanup cannot take that room.
        ``close`` gives the room back anyway. Idempotent."""
        with self._lock:
            self._rows_off = True
        self._release_reserve()

    def _release_reserve(self) -> None:
        if self.reserve is None:
            return
        with contextlib.suppress(FileNotFoundError):
            self.reserve.unlink()
        self.reserve = None

    def integrity(self) -> dict[str, Any]:
        """``end.json``'s ``integrity``: per data file its rows (CSV: after the header), bytes
        and SHA-256 — as written, or, for a file whose write failed, as found on the disk."""
        files: dict[str, Any] = {}
        for fname, tally in self._tally.items():
            if fname in self._suspect:
                try:
                    files[fname] = {**file_integrity(self.path / fname,
                                                     0 if fname == EVENTS_FILE else 1),
                                    "after_write_error": True}
                except OSError:
                    continue  # unreadable: not vouched for
            else:
                files[fname] = tally.to_dict()
        # meta.json is replaced whole (a failed rewrite leaves the last one): as last written
        files[META_FILE] = {"bytes": len(self._meta_bytes),
                            "sha256": hashlib.sha256(self._meta_bytes).hexdigest()}
        return {"algorithm": INTEGRITY_ALGORITHM, "files": files}

    @property
    def meta(self) -> dict[str, Any]:
        """The metadata as written to meta.json (a copy)."""
        with self._lock:
            return dict(self._meta)

    @property
    def closed(self) -> bool:
        return self._closed
