"""A plan's result: each setup and cleanup action's (``ActionResult``), each step's
(``StepResult``) and the plan's (``PlanResult``, whose ``to_dict()`` is the plan record
``plan.json``, schema ``benchctl-plan/1``: ``benchctl.plan.record``).

What ``benchctl.plan.runner`` fills in as the plan runs, and what the JUnit XML
(``benchctl.plan.junit``) and the command line read.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchctl import __version__
from benchctl.outcomes import ExitCode, Outcome
from benchctl.results.record import sha256_file

PLAN_SCHEMA_ID = "benchctl-plan/1"


@dataclass
class ActionResult:
    phase: str  # setup | cleanup
    index: int
    prompt: str | None
    check: str | None
    status: str  # ok | declined | unanswered | interrupted | failed | skipped
    detail: str = ""
    duration_s: float = 0.0  # the action's time, its prompt's answer included (JUnit)

    def to_dict(self) -> dict[str, Any]:
        return {"phase": self.phase, "index": self.index, "prompt": self.prompt,
                "check": self.check, "status": self.status, "detail": self.detail}


@dataclass
class StepResult:
    name: str
    profile: str
    status: Outcome  # PASS | FAIL | INCONCLUSIVE | ABORTED | ERROR | SKIPPED
    reason: str = ""
    on_fail: str = "stop"
    exit_code: ExitCode | None = None
    timed_out: bool = False
    duration_s: float = 0.0
    start_utc: str | None = None
    recording: Path | None = None
    record_path: Path | None = None
    record: dict[str, Any] | None = None  # record.json's content (validated), when written
    abort: dict[str, Any] | None = None

    @property
    def measurements(self) -> list[dict[str, Any]]:
        return list((self.record or {}).get("measurements") or [])

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "profile": self.profile,
            "status": self.status,
            "reason": self.reason,
            "on_fail": self.on_fail,
            "exit_code": self.exit_code,
            "timed_out": self.timed_out,
            "duration_s": round(self.duration_s, 3),
            "start_utc": self.start_utc,
            "recording": None if self.recording is None else str(self.recording),
            "record_path": None if self.record_path is None else str(self.record_path),
            "abort": self.abort,
            "record": self.record,
        }


@dataclass
class PlanResult:
    """What ``run_plan`` returns; ``to_dict()`` is the plan record (``plan.json``)."""

    name: str
    source: Path | None
    serial: str
    operator: str
    config: Path | None
    outcome: Outcome = Outcome.PASS  # PASS | FAIL | INCONCLUSIVE | ABORTED
    exit_code: ExitCode = ExitCode.OK
    reason: str = ""
    timed_out: bool = False
    interrupted: bool = False
    start_utc: str = ""
    end_utc: str = ""
    duration_s: float = 0.0
    setup: list[ActionResult] = field(default_factory=list)
    steps: list[StepResult] = field(default_factory=list)
    cleanup: list[ActionResult] = field(default_factory=list)
    folder: Path | None = None  # <output_dir>/plan_<stamp>_<serial>: plan.json, sim.log
    record_path: Path | None = None  # plan.json
    junit: Path | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "schema": PLAN_SCHEMA_ID,
            "software": {"name": "benchctl", "version": str(__version__)},
            "plan": {
                "name": self.name,
                "path": None if self.source is None else str(self.source),
                "sha256": sha256_file(self.source),
            },
            "serial": self.serial,
            "operator": self.operator,
            "config": None if self.config is None else str(self.config),
            "outcome": self.outcome,
            "exit_code": self.exit_code,
            "reason": self.reason,
            "timed_out": self.timed_out,
            "interrupted": self.interrupted,
            "start_utc": self.start_utc,
            "end_utc": self.end_utc,
            "duration_s": round(self.duration_s, 3),
            "setup": [a.to_dict() for a in self.setup],
            "steps": [s.to_dict() for s in self.steps],
            "cleanup": [a.to_dict() for a in self.cleanup],
            "junit": None if self.junit is None else str(self.junit),
        }


__all__ = ["PLAN_SCHEMA_ID", "ActionResult", "PlanResult", "StepResult"]
