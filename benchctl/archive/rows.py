"""A run record (``benchctl-record/1``) as the archive's rows, and stored rows back as the
summaries the archive hands out: ``run_row``, ``measurement_rows`` (each record field read
defensively: any may be missing or of the wrong type), the times as naive UTC
(``utc_naive``, ``iso``). Pure mapping, no database.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import UTC, date, datetime
from typing import Any

from benchctl.errors import DataError
from benchctl.jsonout import dumps
from benchctl.outcomes import Outcome

SOURCES = ("record.json", "recording", "killed")
"""Where an archived run came from: its record, a recording without one, a killed run."""


def utc_naive(value: Any) -> datetime | None:
    """An ISO time (or datetime) as naive UTC (how the archive stores times); None when absent
    or unreadable."""
    if value is None or value == "":
        return None
    if isinstance(value, datetime):
        d = value
    elif isinstance(value, date):
        d = datetime(value.year, value.month, value.day)
    else:
        try:
            d = datetime.fromisoformat(str(value).replace("Z", "+00:00"))
        except ValueError:
            return None
    if d.tzinfo is not None:
        d = d.astimezone(UTC).replace(tzinfo=None)
    return d


def iso(d: datetime | None) -> str | None:
    """A stored (naive UTC) time as ISO 8601 with its zone."""
    return None if d is None else d.replace(tzinfo=UTC).isoformat(timespec="milliseconds")


def _num(v: Any) -> float | None:
    if isinstance(v, bool):
        return 1.0 if v else 0.0
    if isinstance(v, int | float):
        f = float(v)
        return f if math.isfinite(f) else None
    return None


def _text(v: Any, limit: int) -> str | None:
    if v is None:
        return None
    s = str(v)
    return s[:limit]


def _map(v: Any) -> Mapping[str, Any]:
    return v if isinstance(v, Mapping) else {}


def _ci(m: Mapping[str, Any]) -> tuple[float | None, float | None]:
    ci = m.get("ci95")
    if isinstance(ci, list | tuple) and len(ci) == 2:
        return _num(ci[0]), _num(ci[1])
    return None, None


def run_row(record: Mapping[str, Any], *, recording_sha256: str | None = None,
            source: str = "record.json") -> dict[str, Any]:
    """The ``runs`` row of a record (``benchctl-record/1``; read defensively: any field may be
    missing). ``DataError`` when it has no run_id."""
    run_id = record.get("run_id")
    if not isinstance(run_id, str) or not run_id:
        raise DataError(f"record: run_id = {run_id!r}: expected the recording folder's name")
    unit = _map(record.get("unit"))
    profile = _map(record.get("profile"))
    abort_v = record.get("abort")
    abort = abort_v if isinstance(abort_v, Mapping) else None
    rule = record.get("decision_rule")
    files = _map(record.get("files"))
    report = _map(files.get("report_json"))
    software = _map(record.get("software"))
    outcome = str(record.get("outcome") or Outcome.ABORTED).upper()
    seed = profile.get("seed")
    return {
        "run_id": run_id[:255],
        "serial": (_text(unit.get("serial"), 200) or ""),
        "part_number": _text(unit.get("part_number"), 200),
        "station": _text(record.get("station"), 200) or "",
        "operator": _text(record.get("operator"), 200) or "",
        "start_utc": utc_naive(record.get("start_utc")),
        "end_utc": utc_naive(record.get("end_utc")),
        "outcome": outcome[:20],
        "exit_code": record.get("exit_code") if isinstance(record.get("exit_code"), int) else None,
        "abort_kind": None if abort is None else _text(abort.get("kind"), 20),
        "abort_reason": None if abort is None else _text(abort.get("reason"), 10000),
        "decision_rule": _text(rule.get("name") if isinstance(rule, Mapping) else rule, 20),
        "profile_name": _text(profile.get("name"), 200),
        "profile_kind": _text(profile.get("kind"), 100),
        "profile_seed": seed if isinstance(seed, int) and not isinstance(seed, bool)
        and -(2**63) <= seed < 2**63 else None,
        "profile_sha256": _text(profile.get("sha256"), 64),
        "config_sha256": _text(record.get("config_sha256"), 64),
        "software_version": _text(software.get("version"), 100),
        "recording_path": _text(files.get("recording"), 10000),
        "recording_sha256": recording_sha256,
        "report_path": _text(report.get("path"), 10000),
        "report_sha256": _text(report.get("sha256"), 64),
        "source": source if source in SOURCES else "record.json",
        "record_json": dumps(record, sort_keys=True),  # strict JSON: NaN → null
        "archived_utc": datetime.now(UTC).replace(tzinfo=None),
    }


def measurement_rows(record: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The ``measurements`` rows of a record, in its order."""
    out = []
    ms = record.get("measurements")
    for i, m in enumerate(ms if isinstance(ms, list) else []):
        if not isinstance(m, Mapping):
            continue
        lo, hi = _ci(m)
        out.append({
            "run_id": str(record["run_id"])[:255],
            "seq": i,
            "name": _text(m.get("name"), 200) or "?",
            "axis": _text(m.get("axis"), 50),
            "value": _num(m.get("value")),
            "unit": _text(m.get("unit"), 50),
            "low": _num(m.get("low")),
            "high": _num(m.get("high")),
            "ci95_low": lo,
            "ci95_high": hi,
            "outcome": _text(m.get("outcome"), 20),
            "rule": _text(m.get("rule"), 20),
        })
    return out


def measurement_dict(m: dict[str, Any]) -> dict[str, Any]:
    return {
        "name": m["name"], "axis": m["axis"], "value": m["value"], "unit": m["unit"],
        "low": m["low"], "high": m["high"],
        "ci95": None if m["ci95_low"] is None or m["ci95_high"] is None
        else [m["ci95_low"], m["ci95_high"]],
        "outcome": m["outcome"], "rule": m["rule"],
    }


def run_summary(r: dict[str, Any], sigmas: list[dict[str, Any]]) -> dict[str, Any]:
    return {
        "run_id": r["run_id"], "serial": r["serial"], "part_number": r["part_number"],
        "station": r["station"], "operator": r["operator"],
        "start_utc": iso(r["start_utc"]), "end_utc": iso(r["end_utc"]),
        "outcome": r["outcome"], "exit_code": r["exit_code"],
        "abort": None if r["abort_kind"] is None and r["abort_reason"] is None
        else {"kind": r["abort_kind"], "reason": r["abort_reason"]},
        "decision_rule": r["decision_rule"],
        "profile": {"name": r["profile_name"], "kind": r["profile_kind"],
                    "seed": r["profile_seed"], "sha256": r["profile_sha256"]},
        "config_sha256": r["config_sha256"], "software_version": r["software_version"],
        "recording": {"path": r["recording_path"], "sha256": r["recording_sha256"]},
        "report_json": {"path": r["report_path"], "sha256": r["report_sha256"]},
        "source": r["source"], "archived_utc": iso(r["archived_utc"]),
        "sigma": {str(m["axis"]): m["value"] for m in sigmas},
        "sigma_limit": {str(m["axis"]): m["high"] for m in sigmas},
    }
