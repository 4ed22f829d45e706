"""What a phase of the run sees of it: ``RunContext``, the run's state and its few shared steps
(record a precheck, wait, the run's statistics), as ``benchctl.run.session.Session`` holds them.

The phase modules (``benchctl.run.motion``, ``benchctl.run.equalise``, …) take the run as a
``RunContext`` and so never import the session that calls them."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

from benchctl.clock import Clock
from benchctl.config import BenchConfig
from benchctl.devices.base import AngleSensor, Stand
from benchctl.recording import RecordingWriter
from benchctl.run import fitness
from benchctl.run import prechecks as pc
from benchctl.run.display import Display
from benchctl.run.plan import MotionPlan
from benchctl.run.precision import PrecisionWatch
from benchctl.run.prepare import PreparedMotion, RunOptions
from benchctl.run.realtime import PrioritySetter
from benchctl.run.recorder import Recorder
from benchctl.run.stand_loop import StandLoop
from benchctl.run.state import StateMachine
from benchctl.run.supervisor import Supervisor


class RunContext(Protocol):
    """One run as its phases see it (``Session``)."""

    cfg: BenchConfig
    clock: Clock
    opts: RunOptions
    prep: PreparedMotion  # the prepared motion: never changed
    plan: MotionPlan  # the plan the motion plays: the prepared one, or the equalised one
    axes: tuple[str, ...]
    path: Path  # the recording
    rule: str  # the decision rule
    display: Display
    supervisor: Supervisor
    machine: StateMachine
    writer: RecordingWriter | None
    stand: Stand | None
    sensor: AngleSensor | None
    loop: StandLoop | None
    recorder: Recorder | None
    moved: bool  # the stand may be away from rest: the cleanup ramps it to zero
    meta: dict[str, Any]
    precision: PrecisionWatch | None
    prechecks: list[dict[str, Any]]
    host_warnings: list[str]
    host_probe: fitness.Probe | None
    priority_setter: PrioritySetter | None

    def precheck(self, result: pc.CheckResult, shown: str | None = None) -> None:
        """Record and show a precheck; a failed one raises (``PrecheckFailed``)."""

    def wait(self, seconds: float) -> None:
        """Wait on the main thread, leaving at once on a fault."""

    def stats(self) -> dict[str, Any]:
        """The run's statistics so far (the stand loop's, the instrument's, the rows)."""
