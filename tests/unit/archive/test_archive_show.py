"""``benchctl show`` of a run with fields it has no value for — an aborted run (no report), a
killed run (no end, no software, no report) — says so, and never prints ``None``."""

from __future__ import annotations

from pathlib import Path

import pytest
from archive_helpers import age, make_record, make_recording

from benchctl.archive.service import rebuild
from benchctl.archive.store import Archive
from benchctl.cli import main

ABORT = {"kind": "equipment", "reason": "stand loop: StandFault: stand fault 10",
         "source": "stand loop", "error": "StandFault"}


def _aborted_record(run_id: str) -> dict[str, object]:
    """As a run aborted by a stand fault writes it: no report.json, the prechecks judged,
    σ never measured (no value, no outcome), no decision rule."""
    rec = make_record(run_id, outcome="ABORTED", abort=ABORT)
    rec["files"] = {"recording": "/nowhere", "report_json": None, "report_txt": None}
    rec["decision_rule"] = None
    rec["measurements"] = [
        {"name": "precheck: stand answers", "axis": None, "value": True, "unit": None,
         "low": None, "high": None, "ci95": None, "outcome": "PASS", "rule": "check"},
        {"name": "sigma", "axis": "roll", "value": None, "unit": "deg", "low": None,
         "high": 0.4, "ci95": None, "outcome": None, "rule": "simple"},
    ]
    return rec


def _show(url: str, run_id: str, capsys: pytest.CaptureFixture[str]) -> list[str]:
    assert main(["show", run_id, "--url", url]) == 0
    return capsys.readouterr().out.splitlines()


def test_show_of_an_aborted_run_says_what_is_missing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    url = f"sqlite:///{tmp_path / 'archive.sqlite'}"
    with Archive(url) as a:
        a.store(_aborted_record("20261120T080000Z_SN-1"))
    lines = _show(url, "20261120T080000Z_SN-1", capsys)
    text = "\n".join(lines)
    assert "None" not in text
    assert lines[1] == "outcome    ABORTED (equipment: stand loop: StandFault: stand fault 10)"
    assert "report     — (no report: the run was aborted)" in lines
    assert [ln.split()[0] for ln in lines[7:10]] == ["recording", "sha256", "report"]
    sigma = next(ln for ln in lines if ln.lstrip().startswith("sigma roll"))
    assert sigma.split() == ["sigma", "roll", "—", "deg", "limit", "≤", "0.4", "—"]
    assert next(ln for ln in lines if "precheck: stand answers" in ln).split()[-2:] == [
        "1", "PASS"]


def test_show_of_a_killed_run_says_what_is_missing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    runs = tmp_path / "runs"
    killed = make_recording(runs, "20261120T110000Z_SN-4", serial="SN-4", close=None)
    age(killed, 3600)
    url = f"sqlite:///{tmp_path / 'archive.sqlite'}"
    with Archive(url) as a:
        assert rebuild(a, runs).stored == [killed.name]
        run = a.show(killed.name)
    assert run is not None and run["report_json"]["path"] is None  # not to be shown raw
    lines = _show(url, killed.name, capsys)
    text = "\n".join(lines)
    assert "None" not in text
    assert lines[1].startswith("outcome    ABORTED (software: killed (no end.json))")
    assert "report     — (no report: the run was aborted)" in lines
    assert next(ln for ln in lines if ln.startswith("recording")).endswith(killed.name)
