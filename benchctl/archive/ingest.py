"""What the archive stores of a recording: its record (``record.json``, ``benchctl-record/1``)
or, where there is none (an older recording, a run killed before it could write one), an
equivalent record built from ``meta.json``, ``end.json`` and ``report.json``; and the SHA-256 of
the recording itself.

A recording without ``end.json`` was not closed: its process died (killed, a power cut). It is
archived ABORTED with the reason ``killed (no end.json)`` once it has been quiet for
``LIVE_QUIET_S`` (a recording still being written belongs to a run in progress).
"""

from __future__ import annotations

import hashlib
import json
import time
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from benchctl.errors import DataError
from benchctl.outcomes import Outcome
from benchctl.recording.format import (
    END_FILE,
    EVENTS_FILE,
    FORMAT_NAME,
    META_FILE,
    STREAM_FILES,
    is_recording,
)

RECORD_JSON = "record.json"
REPORT_JSON = "report.json"
SCHEMA_ID = "benchctl-record/1"
KILLED_REASON = "killed (no end.json)"
LIVE_QUIET_S = 120.0  # a recording without end.json written to within this is a live run
# the recording's own files, hashed into its SHA-256 (report, record and logs are not part of
# it: they are written after it is closed, or not at all)
RECORDING_FILES = (META_FILE, EVENTS_FILE, END_FILE, *STREAM_FILES.values())


def _json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise DataError(f"{path}: cannot read: {e.strerror}") from None
    except ValueError as e:
        raise DataError(f"{path}: not valid JSON: {e}") from None


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def recording_sha256(folder: Path) -> str | None:
    """The recording's SHA-256: of the manifest ``<sha256 of file>  <name>\\n`` over its own
    files (meta.json, events.jsonl, end.json, stand.csv, instrument.csv, setpoints.csv, those
    present, in that order) — what ``sha256sum`` would print for them, hashed once more."""
    lines = []
    for name in RECORDING_FILES:
        p = folder / name
        if p.is_file():
            try:
                lines.append(f"{_file_sha256(p)}  {name}\n")
            except OSError:
                return None
    if not lines:
        return None
    return hashlib.sha256("".join(lines).encode()).hexdigest()


def _newest_mtime(folder: Path) -> float:
    newest = folder.stat().st_mtime
    for p in folder.iterdir():
        try:
            newest = max(newest, p.stat().st_mtime)
        except OSError:
            continue
    return newest


def is_live(folder: Path, quiet_s: float = LIVE_QUIET_S) -> bool:
    """A recording without end.json written to within ``quiet_s``: a run in progress."""
    if (folder / END_FILE).is_file():
        return False
    try:
        return time.time() - _newest_mtime(folder) < quiet_s
    except OSError:
        return False


def recordings_under(root: Path) -> Iterator[Path]:
    """Every benchctl recording at or below ``root`` (sorted by path)."""
    if is_recording(root):
        yield root
        return
    for meta in sorted(root.rglob(META_FILE)):
        folder = meta.parent
        if folder != root and is_recording(folder):
            yield folder


def incomplete_recordings(out_dir: Path, *, exclude: Path | None = None,
                          quiet_s: float = LIVE_QUIET_S) -> list[Path]:
    """Recordings directly in ``out_dir`` that were never closed (no end.json) and are quiet:
    runs killed before their end."""
    found = []
    try:
        children = sorted(out_dir.iterdir())
    except OSError:
        return []
    for d in children:
        if exclude is not None and d.resolve() == exclude.resolve():
            continue
        if is_recording(d) and not (d / END_FILE).is_file() and not is_live(d, quiet_s):
            found.append(d)
    return found


def _map(v: Any) -> dict[str, Any]:
    return v if isinstance(v, dict) else {}


def _abort_kind(reason: str) -> str:
    r = reason.lower()
    if any(w in r for w in ("sigint", "sigterm", "sighup", "sigquit", "signal", "operator",
                            "interrupted", "stopped by")):
        return "operator"
    if any(w in r for w in ("stand", "instrument", "device", "timeout", "modbus", "can ",
                            "e-stop", "fault", "silent", "tracking")):
        return "equipment"
    return "software"


def _measurements_from_report(report: dict[str, Any]) -> list[dict[str, Any]]:
    ms = report.get("measurements")
    if isinstance(ms, list):
        return [m for m in ms if isinstance(m, dict)]
    out = []
    axes = report.get("axes")
    if isinstance(axes, dict):
        for axis, ax in axes.items():
            if not isinstance(ax, dict):
                continue
            value = ax.get("sigma", ax.get("sigma_deg"))
            if isinstance(value, dict):
                value = value.get("value")
            ci = ax.get("sigma_ci95", ax.get("sigma_ci95_deg"))
            limit = ax.get("limit", ax.get("limit_deg", report.get("limit_sigma_deg")))
            out.append({
                "name": "sigma", "axis": str(axis),
                "value": value if isinstance(value, int | float) else None,
                "unit": "deg", "low": None,
                "high": limit if isinstance(limit, int | float) else None,
                "ci95": list(ci) if isinstance(ci, list | tuple) and len(ci) == 2 else None,
                "outcome": ax.get("verdict"), "rule": "simple",
            })
    return out


def record_from_files(folder: Path) -> tuple[dict[str, Any], str]:
    """A ``benchctl-record/1``-shaped record from a recording's meta.json, end.json and
    report.json; and its source: ``recording`` (closed) or ``killed`` (no end.json)."""
    meta = _json(folder / META_FILE)
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise DataError(f"{folder / META_FILE}: not a benchctl recording's metadata")
    end = _json(folder / END_FILE) if (folder / END_FILE).is_file() else None
    report = _json(folder / REPORT_JSON) if (folder / REPORT_JSON).is_file() else None
    report = report if isinstance(report, dict) else None
    abort: dict[str, Any] | None = None
    if not isinstance(end, dict):
        source = "killed"
        outcome = Outcome.ABORTED
        abort = {"kind": "software", "reason": KILLED_REASON}
        end_utc: str | None = datetime.fromtimestamp(_newest_mtime(folder), UTC).isoformat(
            timespec="milliseconds")
    else:
        source = "recording"
        end_utc = None if end.get("end_utc") is None else str(end.get("end_utc"))
        reason = str(end.get("reason") or "")
        if end.get("state") == "done":
            verdict = str((report or {}).get("verdict") or reason).upper()
            outcome = (Outcome(verdict) if verdict in (Outcome.PASS, Outcome.FAIL,
                                                       Outcome.INCONCLUSIVE)
                       else Outcome.INCONCLUSIVE)
        else:
            outcome = Outcome.ABORTED
            abort = {"kind": _abort_kind(reason), "reason": reason or "aborted"}
    config = _map(meta.get("config"))
    unit_cfg = _map(config.get("unit"))
    stand_cfg = _map(config.get("stand"))
    run_cfg = _map(config.get("run"))
    devices = _map(meta.get("devices"))
    profile = _map(meta.get("profile"))
    spec = _map(profile.get("spec"))
    part = meta.get("part_number") or unit_cfg.get("part_number")
    rule = run_cfg.get("decision_rule") or "simple"
    rj = folder / REPORT_JSON
    record = {
        "schema": SCHEMA_ID,
        "run_id": folder.name,
        "software": {"name": "benchctl", "version": str(meta.get("software_version") or "")},
        "outcome": outcome,
        "abort": abort,
        "decision_rule": {"name": rule, "text": ""},
        "deviations": [],
        "warnings": [],
        "start_utc": meta.get("start_utc"),
        "end_utc": end_utc,
        "unit": {"serial": str(meta.get("serial") or ""),
                 "part_number": None if part is None else str(part),
                 "reported_serial": None, "serial_match": None},
        "operator": str(meta.get("operator") or ""),
        "station": str(meta.get("station") or ""),
        "stand": {"identity": devices.get("stand"),
                  "calibration_due": stand_cfg.get("calibration_due")},
        "instruments": [{"role": "dut", "identity": devices.get("instrument")}],
        "profile": {"name": meta.get("profile_name"), "kind": spec.get("kind")
                    or profile.get("kind"), "seed": meta.get("seed"),
                    "sha256": meta.get("profile_sha256")},
        "config_sha256": meta.get("config_sha256"),
        "measurements": _measurements_from_report(report) if report else [],
        "files": {"recording": str(folder.resolve()),
                  "report_json": {"path": str(rj.resolve()), "sha256": _file_sha256(rj)}
                  if rj.is_file() else None},
    }
    if report is not None and isinstance(report.get("exit_code"), int):
        record["exit_code"] = report["exit_code"]
    return record, source


def record_of(folder: Path) -> tuple[dict[str, Any], str]:
    """The record of a recording and its source: ``record.json`` when the folder holds a
    readable one of schema ``benchctl-record/1``, else one built from its files
    (``record_from_files``). A recording without end.json is ABORTED (killed) whatever its
    record.json says."""
    rp = folder / RECORD_JSON
    if rp.is_file() and (folder / END_FILE).is_file():
        try:
            data = _json(rp)
        except DataError:
            data = None
        if isinstance(data, dict) and data.get("schema") == SCHEMA_ID and data.get("run_id"):
            return data, "record.json"
    return record_from_files(folder)


__all__ = [
    "KILLED_REASON",
    "LIVE_QUIET_S",
    "incomplete_recordings",
    "is_live",
    "record_from_files",
    "record_of",
    "recording_sha256",
    "recordings_under",
]
