"""The station panel's heartbeat for the line view (``benchctl.web.lineheartbeat``): what the
run going on (or the last one) makes the station publish — idle, or running with its phase,
unit and operator; the last run's outcome once it ended."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from benchctl.web.linestations import StationState
from benchctl.web.panelrun import Run, outcome


def beat_of(run: Run, part_number: str | None) -> tuple[StationState, dict[str, Any]]:
    """The state and fields (``StationBoard.publish``'s) that ``run`` makes the station
    publish."""
    if not run.ended:
        return StationState.RUNNING, {
            "phase": run.state, "serial": run.serial, "operator": run.operator,
            "part_number": part_number, "started_utc": run.started_utc,
        }
    fields: dict[str, Any] = {"last_serial": run.serial, "last_end_utc": run.ended_utc}
    o = outcome(run)
    if o["verdict"] in ("PASS", "FAIL", "INCONCLUSIVE", "ABORTED"):
        fields["last_outcome"] = o["verdict"]
    recording = (run.result or {}).get("recording")
    if isinstance(recording, str):
        fields["last_run_id"] = Path(recording).name
    return StationState.IDLE, fields
