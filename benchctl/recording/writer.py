"""Write a recording as the run goes (thread-safe, line-buffered, crash-safe)."""

from __future__ import annotations

import json
import math
import os
import threading
import time
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

from benchctl import __version__
from benchctl.devices.base import InstrumentSample, StandSample
from benchctl.errors import InputError
from benchctl.recording.format import (
    END_FILE,
    EVENTS_FILE,
    FORMAT_NAME,
    FORMAT_VERSION,
    META_FILE,
    STREAM_COLUMNS,
    STREAM_FILES,
)


def _num(x: float | int | None) -> str:
    if x is None:
        return ""
    if isinstance(x, float) and not math.isfinite(x):
        return "nan"
    return repr(x)


def _atomic_json(path: Path, obj: Mapping[str, Any]) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    with tmp.open("w", encoding="utf-8") as f:
        json.dump(obj, f, indent=2, default=str)
        f.write("\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def utc_now() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


class RecordingWriter:
    """Opens a new recording folder and appends to its streams.

    Every ``write_*`` call goes straight to the OS: a killed process loses nothing written.
    ``close(state, reason)`` writes ``end.json``; it is idempotent.
    """

    def __init__(self, path: str | Path, axes: Sequence[str], meta: Mapping[str, Any]) -> None:
        self.path = Path(path)
        if self.path.exists() and any(self.path.iterdir()):
            raise InputError(f"{self.path}: recording folder exists and is not empty")
        self.path.mkdir(parents=True, exist_ok=True)
        self.axes = tuple(axes)
        self._lock = threading.Lock()
        self._closed = False
        self.counts = {name: 0 for name in STREAM_FILES}
        self.t0_monotonic = time.monotonic()
        full_meta = {
            "format": FORMAT_NAME,
            "version": FORMAT_VERSION,
            "software_version": __version__,
            "axes": list(self.axes),
            "start_utc": utc_now(),
            "start_monotonic": self.t0_monotonic,
            **meta,
        }
        self._meta: dict[str, Any] = full_meta
        _atomic_json(self.path / META_FILE, full_meta)
        self._files: dict[str, IO[str]] = {}
        for name, fname in STREAM_FILES.items():
            f = (self.path / fname).open("w", encoding="utf-8", buffering=1)
            f.write(",".join(STREAM_COLUMNS[name](self.axes)) + "\n")
            self._files[name] = f
        self._events = (self.path / EVENTS_FILE).open("w", encoding="utf-8", buffering=1)

    def _write(self, name: str, fields: list[str]) -> None:
        line = ",".join(fields) + "\n"
        with self._lock:
            if self._closed:
                return
            self._files[name].write(line)
            self.counts[name] += 1

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
        self._write("stand", fields)

    def write_instrument(self, s: InstrumentSample) -> None:
        fields = [_num(s.t_host), _num(s.device_time_s), _num(s.counter)]
        fields += [_num(s.angle_deg.get(ax)) for ax in self.axes]
        self._write("instrument", fields)

    def write_setpoint(
        self, t_send: float, angle_deg: Mapping[str, float], t_slot: float | None = None
    ) -> None:
        """A commanded setpoint sent at ``t_send``: the profile's value at slot time ``t_slot``."""
        fields = [_num(t_send), _num(t_slot)] + [_num(angle_deg.get(ax)) for ax in self.axes]
        self._write("setpoints", fields)

    def update_meta(self, **fields: Any) -> None:
        """Add or replace metadata fields (meta.json is rewritten atomically)."""
        with self._lock:
            self._meta = {**self._meta, **fields}
            _atomic_json(self.path / META_FILE, self._meta)

    def event(self, kind: str, **fields: Any) -> None:
        rec = {"t_host": time.monotonic(), "utc": utc_now(), "kind": kind, **fields}
        line = json.dumps(rec, default=str) + "\n"
        with self._lock:
            if not self._closed:
                self._events.write(line)

    def close(self, state: str, reason: str = "", **extra: Any) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            for f in (*self._files.values(), self._events):
                f.flush()
                os.fsync(f.fileno())
                f.close()
        _atomic_json(
            self.path / END_FILE,
            {
                "state": state,
                "reason": reason,
                "end_utc": utc_now(),
                "end_monotonic": time.monotonic(),
                "counts": dict(self.counts),
                **extra,
            },
        )

    @property
    def meta(self) -> dict[str, Any]:
        """The metadata as written to meta.json (a copy)."""
        with self._lock:
            return dict(self._meta)

    @property
    def closed(self) -> bool:
        return self._closed
