"""``benchctl history SERIAL``: the unit's yield — its own runs' verdicts per day and over all
— not the daily yield of the stations it was tested on (which it gave before); a station's
yield where a station is asked for."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from archive_helpers import make_record

from benchctl.archive.store import Archive
from benchctl.cli import main

DAY1, DAY2 = "2026-11-20", "2026-11-21"
RUNS = [  # run id, serial, station, day, outcome
    ("a1", "A", "bench-1", DAY1, "PASS"),
    ("a2", "A", "bench-1", DAY1, "FAIL"),
    ("a3", "A", "bench-1", DAY1, "ABORTED"),
    ("b1", "B", "bench-1", DAY1, "PASS"),
    ("b2", "B", "bench-1", DAY1, "PASS"),
    ("a4", "A", "bench-2", DAY2, "INCONCLUSIVE"),
]


@pytest.fixture
def url(tmp_path: Path) -> str:
    u = f"sqlite:///{tmp_path / 'archive.sqlite'}"
    with Archive(u) as a:
        for i, (run_id, serial, station, day, outcome) in enumerate(RUNS):
            abort = {"kind": "equipment", "reason": "stand fault"} if outcome == "ABORTED" \
                else None
            a.store(make_record(run_id, serial=serial, station=station, outcome=outcome,
                                start=f"{day}T08:{i:02d}:00.000+00:00", abort=abort))
    return u


def _json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, Any]:
    assert main(["history", *argv, "--json"]) == 0
    return dict(json.loads(capsys.readouterr().out))


def _counts(d: dict[str, Any]) -> tuple[Any, ...]:
    return (d["runs"], d["pass"], d["fail"], d["inconclusive"], d["aborted"], d["yield"])


def test_a_units_yield_is_its_own_runs(url: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = _json(capsys, "A", "--url", url)
    assert [r["run_id"] for r in out["runs"]] == ["a1", "a2", "a3", "a4"]
    days = out["yield_per_day"]
    assert [(d["serial"], d["day"]) for d in days] == [("A", DAY1), ("A", DAY2)]
    assert "station" not in days[0]
    assert _counts(days[0]) == (3, 1, 1, 0, 1, 0.5)  # B's two passes on bench-1 not counted
    assert _counts(days[1]) == (1, 0, 0, 1, 0, 0.0)
    assert out["yield"]["serial"] == "A"
    assert _counts(out["yield"]) == (4, 1, 1, 1, 1, pytest.approx(1 / 3))
    assert "station_yield_per_day" not in out


def test_a_station_asked_for_keeps_the_stations_yield(
    url: str, capsys: pytest.CaptureFixture[str],
) -> None:
    out = _json(capsys, "A", "--station", "bench-1", "--url", url)
    assert [r["run_id"] for r in out["runs"]] == ["a1", "a2", "a3"]
    assert [_counts(d) for d in out["yield_per_day"]] == [(3, 1, 1, 0, 1, 0.5)]
    assert [(d["station"], d["day"], _counts(d)) for d in out["station_yield_per_day"]] == [
        ("bench-1", DAY1, (5, 3, 1, 0, 1, 0.75))]
    out = _json(capsys, "--station", "bench-1", "--url", url)  # no unit: the station's
    assert [(d["station"], _counts(d)) for d in out["yield_per_day"]] == [
        ("bench-1", (5, 3, 1, 0, 1, 0.75))]
    assert "yield" not in out


def test_the_units_page_shows_its_own_yield(url: str, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    page = tmp_path / "a.html"
    assert main(["history", "A", "--url", url, "--html", str(page)]) == 0
    capsys.readouterr()
    html = page.read_text()
    assert "Yield per day: unit A" in html and "Yield per day: station" not in html
    assert f"{DAY1}: 3 run(s): 1 pass, 1 fail, 0 inconclusive, 1 aborted" in html
