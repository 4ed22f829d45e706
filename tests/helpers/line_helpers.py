"""Two stations' runs for the line view's tests (a known day, known verdicts and σ), and
a station's heartbeat aged on the database's side (a station gone silent)."""

from __future__ import annotations

from typing import Any

from archive_helpers import make_record
from sqlalchemy import text

from benchctl.archive.store import Archive
from benchctl.web.linestations import TABLE

DAY = "2026-11-20"
HOSTILE_OPERATOR = '<script>alert("op")</script>'
HOSTILE_SERIAL = 'B03"><img src=x onerror=alert(1)>'
HOSTILE_STATION = "<svg onload=alert(2)>"
HOSTILE_REASON = "</td></tr></table><script>alert(3)</script>"

# start, station, serial, part number, outcome, σ (None: aborted), σ limit
RUNS: list[tuple[str, str, str, str, str, float | None, float]] = [
    ("2026-11-12T08:00", "bench-1", "A01", "IN-100", "PASS", 0.28, 0.4),  # before the window
    ("2026-11-14T08:00", "bench-1", "A02", "IN-100", "PASS", 0.30, 0.4),
    ("2026-11-15T08:00", "bench-2", "A03", "IN-100", "PASS", 0.29, 0.4),
    ("2026-11-16T08:00", "bench-1", "A04", "IN-100", "PASS", 0.31, 0.4),
    ("2026-11-17T08:00", "bench-2", "B01", "IN-200", "FAIL", 0.52, 0.5),
    ("2026-11-18T08:00", "bench-1", "A05", "IN-100", "PASS", 0.30, 0.4),
    ("2026-11-20T08:00", "bench-1", "A06", "IN-100", "PASS", 0.29, 0.4),  # the day
    ("2026-11-20T09:00", "bench-1", "A07", "IN-100", "FAIL", 0.45, 0.4),
    ("2026-11-20T10:00", "bench-2", "B02", "IN-200", "PASS", 0.35, 0.5),
    ("2026-11-20T11:00", "bench-2", HOSTILE_SERIAL, "IN-200", "INCONCLUSIVE", 0.49, 0.5),
    ("2026-11-20T12:00", "bench-2", "B04", "IN-200", "ABORTED", None, 0.5),
    ("2026-11-21T08:00", "bench-1", "A08", "IN-100", "PASS", 0.30, 0.4),  # the next day
]
IN_100 = [0.28, 0.30, 0.29, 0.31, 0.30, 0.29, 0.45, 0.30]  # its σ in order
IN_200 = [0.52, 0.35, 0.49]


def record(i: int, start: str, station: str, serial: str, part: str, outcome: str,
           sigma: float | None, limit: float) -> dict[str, Any]:
    abort = {"kind": "equipment", "reason": HOSTILE_REASON} if outcome == "ABORTED" else None
    rec = make_record(f"{start.replace('-', '').replace(':', '')}00Z_{i:02d}", serial=serial,
                      outcome=outcome, sigma=sigma if sigma is not None else 0.0, limit=limit,
                      station=station, start=f"{start}:00.000+00:00", part_number=part,
                      operator=HOSTILE_OPERATOR if serial == "A07" else "anna", abort=abort)
    if sigma is None:  # aborted before σ was measured
        rec["measurements"][0]["value"] = None
    return rec


def fill_two_stations(archive: Archive) -> None:
    for i, run in enumerate(RUNS):
        archive.store(record(i, *run))


def age_heartbeat(archive: Archive, station: str, seconds: float) -> None:
    """Date ``station``'s heartbeat back by ``seconds`` (as if it had gone silent then)."""
    with archive.engine.begin() as conn:
        row = conn.execute(text(f"SELECT updated_utc FROM {TABLE} WHERE station = :s"),
                           {"s": station}).one()
        conn.execute(text(f"UPDATE {TABLE} SET updated_utc = :t WHERE station = :s"),
                     {"t": _minus(row[0], seconds), "s": station})


def _minus(value: Any, seconds: float) -> Any:
    from datetime import datetime, timedelta

    if isinstance(value, str):  # SQLite's text
        value = datetime.fromisoformat(value)
    return value - timedelta(seconds=seconds)
