"""What a run hands back (``RunResult``), and what an aborted one says of itself: the verdict
it measured before the abort (``measured_verdict``) and where it left the stand
(``stand_after``)."""

from __future__ import annotations

import shlex
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchctl.outcomes import ExitCode, Outcome
from benchctl.run import prechecks as pc
from benchctl.run.report import Report


@dataclass
class RunResult:
    state: str  # done | aborted
    reason: str
    exit_code: ExitCode
    recording: Path | None
    report: Report | None = None
    stats: dict[str, Any] = field(default_factory=dict)
    shutdown: list[dict[str, Any]] = field(default_factory=list)
    log: Path | None = None  # the run's log file (<recording>/benchctl.log)
    abort: dict[str, Any] | None = None  # aborted: {kind: operator|equipment|software, reason}
    record: Path | None = None  # <recording>/record.json when written
    # aborted after the analysis (its outputs could not be written): the verdict measured
    measured: dict[str, Any] | None = None

    def to_dict(self) -> dict[str, Any]:
        if self.report is not None:
            d = self.report.to_dict(full=True)
            d["record"] = None if self.record is None else str(self.record)
            return d
        return {
            "verdict": Outcome.ABORTED,
            "state": self.state,
            "reason": self.reason,
            "abort": self.abort,
            "record": None if self.record is None else str(self.record),
            "exit_code": self.exit_code,
            "recording": None if self.recording is None else str(self.recording),
            "log": None if self.log is None else str(self.log),
            "stats": self.stats,
            "shutdown": self.shutdown,
            "measured": self.measured,
        }


def stand_after(final: dict[str, Any] | None, *, zero_tolerance_deg: float,
                config: Path | str | None, known: bool = True) -> dict[str, Any]:
    """Where an abort left the stand (``record.json``'s ``abort.stand``), from the cleanup's
    ``ShutdownReport.final_state`` (None: the stand did not answer): each axis's angle and
    rate, the fault code and its text, the E-stop, the servo, at rest (every |rate| ≤
    ``REST_RATE_DEG_S``), at zero; and, when it is
    not at rest at zero, the commands that bring it there (``benchctl stand reset`` when
    faulted, then ``benchctl stand home``, with the run's config). ``known`` False: no stand was
    connected (nothing moved)."""
    cfg = shlex.quote(str(config)) if config else "CFG"
    out: dict[str, Any] = {
        "known": final is not None, "axes": {}, "enabled": None, "fault_code": None,
        "fault_text": None, "estop": None, "at_rest": None, "at_zero": None, "commands": [],
    }
    if final is None:
        if known:
            out["commands"] = [f"benchctl stand status --config {cfg}"]
            out["text"] = ("unknown: the stand did not answer; see "
                           f"`benchctl stand status --config {cfg}`")
        else:
            out["text"] = "the stand was not connected: it has not moved"
        return out
    angles = {a: float(v) for a, v in (final.get("angle_deg") or {}).items()}
    rates = {a: float(v) for a, v in (final.get("rate_deg_s") or {}).items()}
    code = int(final.get("fault_code") or 0)
    estop = bool(final.get("estop"))
    # at rest as the next run's precheck has it by rate (|rate| ≤ REST_RATE_DEG_S); the status
    # bit ``moving`` is not used: read just after the servo went off it may still show a
    # settling stand (a few hundredths of °/s) as moving
    at_rest = bool(all(abs(v) <= pc.REST_RATE_DEG_S for v in rates.values()))
    at_zero = bool(at_rest and all(abs(v) <= zero_tolerance_deg for v in angles.values()))
    commands = []
    if code or estop:
        commands.append(f"benchctl stand reset --config {cfg}")
    if not at_zero:
        commands.append(f"benchctl stand home --config {cfg}")
    out.update(
        axes={a: {"angle_deg": angles[a], "rate_deg_s": rates.get(a, 0.0)} for a in angles},
        enabled=bool(final.get("enabled")), fault_code=code,
        fault_text=str(final.get("fault_text") or "") if code else "", estop=estop,
        at_rest=at_rest, at_zero=at_zero, commands=commands,
    )
    where = ", ".join(f"{a} {v:+.3f}°" for a, v in angles.items())
    flags = ["at rest" if at_rest else "MOVING",
             "servo on" if out["enabled"] else "servo off"]
    if code:
        flags.append(f"fault {code}" + (f" ({out['fault_text']})" if out["fault_text"] else ""))
    if estop:
        flags.append("E-stop pressed")
    out["text"] = f"{where}; {', '.join(flags)}" + ("" if at_zero else "; NOT at zero")
    return out


def measured_verdict(report: Report | None) -> dict[str, Any] | None:
    """An aborted run's verdict measured before the abort (end.json's ``measured``)."""
    if report is None:
        return None
    return {
        "verdict": report.verdict,
        "axes": {a: {"sigma": v.sigma_deg, "sigma_ci95": list(v.sigma_ci95_deg),
                     "limit": v.limit_deg, "verdict": v.outcome}
                 for a, v in report.axes.items()},
        "note": "measured before the run was aborted; its report, record or archive could not "
                "all be written",
    }
