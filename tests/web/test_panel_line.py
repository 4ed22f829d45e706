"""The station panel beside the line view: it serves ``/line`` and ``/history`` behind its own
access rules, and keeps this station's heartbeat going into the runs' archive — idle, running
with the run's phase, then the run's outcome."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient
from panel import wait_for
from repo_paths import ROOT

from benchctl.archive.store import Archive
from benchctl.web.app import create_app
from benchctl.web.linestations import StationBoard, StationState
from benchctl.web.panelrun import Run
from benchctl.web.security import hash_token
from benchctl.web.settings import PanelSettings
from benchctl.web.station_beat import beat_of

LOOPBACK = "http://127.0.0.1:8350"


def settings(tmp: Path, **kw: object) -> PanelSettings:
    return PanelSettings(config=ROOT / "config/sim_virtual.yaml",
                         profiles=(ROOT / "profiles/paper_vessel_roll_short120.yaml",),
                         out_dir=tmp / "runs", **kw)  # type: ignore[arg-type]


def states(tmp: Path) -> dict[str, str]:
    db = tmp / "runs" / "archive.sqlite"
    if not db.is_file():
        return {}
    with Archive(f"sqlite:///{db}") as a:
        try:
            return {h.station: h.state for h in StationBoard(a).read()[1]}
        except Exception:  # the table not made yet
            return {}


def test_the_line_view_and_the_heartbeat_beside_the_panel(tmp_path: Path) -> None:
    with TestClient(create_app(settings(tmp_path)), base_url=LOOPBACK) as c:
        wait_for("the station's first heartbeat", lambda: states(tmp_path), 60)
        assert states(tmp_path) == {"sim-bench": "idle"}
        line = c.get("/line")
        assert line.status_code == 200 and "sim-bench" in line.text
        assert "unsafe-inline" in line.headers["content-security-policy"]  # its own policy
        assert c.get("/history").status_code == 200


def test_the_line_view_is_behind_the_login(tmp_path: Path) -> None:
    s = settings(tmp_path, require_token=True, token_scrypt=hash_token("x" * 12, n=2**10))
    with TestClient(create_app(s), base_url=LOOPBACK) as c:
        assert c.get("/line", follow_redirects=False).status_code == 303
        assert c.get("/line/data.json", follow_redirects=False).status_code == 303


def test_what_a_run_makes_the_station_publish(tmp_path: Path) -> None:
    run = Run(1, "SN-1", "anna", "short", tmp_path, state="running",
              started_utc="2026-11-27T08:00:00+00:00")
    state, fields = beat_of(run, "IN-100")
    assert state == StationState.RUNNING
    assert fields == {"phase": "running", "serial": "SN-1", "operator": "anna",
                      "part_number": "IN-100", "started_utc": "2026-11-27T08:00:00+00:00"}
    run.exit_code, run.ended_utc = 1, "2026-11-27T08:20:00+00:00"
    run.result = {"verdict": "FAIL", "state": "done", "recording": str(tmp_path / "20261127_SN-1")}
    state, fields = beat_of(run, "IN-100")
    assert state == StationState.IDLE
    assert fields == {"last_serial": "SN-1", "last_end_utc": "2026-11-27T08:20:00+00:00",
                      "last_outcome": "FAIL", "last_run_id": "20261127_SN-1"}
    refused = Run(2, "SN-2", "anna", "short", tmp_path)
    refused.exit_code, refused.error = 2, "stand in use"
    assert "last_outcome" not in beat_of(refused, None)[1]  # it did not run: no outcome


def test_the_line_view_in_the_stations_language(tmp_path: Path) -> None:
    """A Russian station's panel serves the line view in Russian: its headings from the same
    catalogs as the station page."""
    with TestClient(create_app(settings(tmp_path, lang="ru")), base_url=LOOPBACK) as c:
        wait_for("the station's first heartbeat", lambda: states(tmp_path), 60)
        text = c.get("/line").text
        assert "Линия" in text and "Стенды" in text and "Выход годных" in text
        assert "Line view" not in text and "Yield" not in text
