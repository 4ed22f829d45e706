"""One run as the panel knows it (:class:`Run`: who started it, its process, what it
published, how it ended), what a browser is sent of it (``Run.view``) and its verdict screen
(``outcome``), each text in the station's language (``benchctl.web.wording``).
"""

from __future__ import annotations

import subprocess
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from benchctl.web import runstate
from benchctl.web.wording import DETAILS, Words, _

TRACE_POINTS = 3000  # the plot's history (5 min of the run's 10 snapshots a second)
STATUS_TRACE_POINTS = 600  # sent to a browser that connects mid-run (the last minute)
MESSAGES = 200  # the run's last messages kept


@dataclass
class Run:
    """One run started from the panel."""

    id: int
    serial: str
    operator: str
    profile: str  # the profile's (or the plan's) name
    folder: Path  # the panel's own files for this run: the socket, result.json, stderr.txt
    kind: str = "test"  # test (benchctl run) | plan (benchctl plan)
    proc: subprocess.Popen[bytes] | None = None
    pid: int | None = None  # the run's process (this server's child, or one taken up again)
    identity: str = ""  # its boot id and start time (benchctl.web.runstate.identity)
    adopted: bool = False  # taken up again after the panel's restart: not this server's child
    recording: str | None = None  # the run's recording folder, once it says it
    finished: bool = False  # ended (an adopted run's exit code is not known)
    state: str = "starting"
    reason: str = ""
    snapshot: dict[str, Any] | None = None
    trace: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=TRACE_POINTS))
    messages: deque[dict[str, str]] = field(default_factory=lambda: deque(maxlen=MESSAGES))
    verdict: dict[str, Any] | None = None
    result: dict[str, Any] | None = None
    exit_code: int | None = None
    error: str = ""
    refused: bool = False
    stop_requested: bool = False
    datagrams: int = 0
    started_utc: str = ""  # when the panel started it (ISO 8601, UTC)
    ended_utc: str = ""  # when it ended
    prompt: dict[str, Any] | None = None  # a plan's question waiting for the operator
    answered: set[int] = field(default_factory=set)  # its questions answered here

    @property
    def ended(self) -> bool:
        return self.finished or self.exit_code is not None

    def view(self, trace_points: int = STATUS_TRACE_POINTS,
             words: Words | None = None) -> dict[str, Any]:
        """What a browser is sent: everything it shows of this run (its texts in the language
        of ``words``)."""
        w = words or Words()
        reason = w.state_reason(self.reason)
        return {
            "id": self.id, "kind": self.kind, "serial": self.serial,
            "operator": self.operator, "profile": self.profile, "state": self.state,
            "reason": self.reason, "reason_text": reason["text"],
            "reason_detail": reason["detail"], "prompt": self.prompt,
            "snapshot": self.snapshot,
            "trace": list(self.trace)[-trace_points:] if trace_points > 0 else [],
            "messages": list(self.messages)[-20:], "ended": self.ended,
            "stop_requested": self.stop_requested, "adopted": self.adopted,
            "outcome": outcome(self, w) if self.ended else None,
        }

    def saved(self, path: Path | None) -> dict[str, Any]:
        """What the state file keeps of this run (``benchctl.web.runstate``)."""
        return {
            "run_id": self.id, "serial": self.serial, "operator": self.operator,
            "profile": self.profile, "kind": self.kind, "folder": str(self.folder),
            "socket": str(self.folder / "live.sock"), "pid": self.pid,
            "identity": self.identity, "recording": self.recording,
            "out_dir": None if path is None else str(path),
            "started_utc": self.started_utc, "stop_requested": self.stop_requested,
            "ended": self.ended, "ended_utc": self.ended_utc, "state": self.state,
            "exit_code": self.exit_code, "error": self.error, "refused": self.refused,
            "result": runstate.slim(self.result) if self.ended else None,
        }


def outcome(run: Run, words: Words | None = None) -> dict[str, Any]:
    """The verdict screen's content: the verdict, σ per axis with its interval and limit, an
    abort's headline, where the stand is and what to do next, the report; or why the run did
    not start. Each text in the language of ``words`` (English by default); the run's own
    English (its reason, its stand description) as ``detail`` and ``stand_detail``."""
    w = words or Words()
    res = run.result
    if res is None:
        verdict = "ABORTED" if run.stop_requested else "ERROR"
        if run.refused:
            headline = w(_("The stand is in use: this run was refused before anything moved"))
        elif verdict == "ABORTED":
            headline = w(_("The run was stopped before it wrote its result."))
        elif run.error:
            headline = w(_("The run did not start"))
        elif run.exit_code is not None:
            headline = w(_("The run ended (exit code %(code)s) without a result."),
                         code=run.exit_code)
        else:
            headline = w(_("The run ended without a result."))
        return {"verdict": verdict, "word": w.outcome_word(verdict) if verdict == "ABORTED"
                else w(_("NOT STARTED")), "axes": [], "steps": [], "reason": run.error,
                "headline": headline, "detail": run.error, "details_label": w(DETAILS),
                "refused": run.refused, "kind": "", "next": [], "advice": "",
                "report": False, "exit_code": run.exit_code}
    if run.kind == "plan":
        return _plan_outcome(run, res, w)
    axes = []
    for name, a in (res.get("axes") or {}).items():
        ci = a.get("sigma_ci95") or [None, None]
        axes.append({"axis": name, "axis_name": w.axis(name), "sigma": a.get("sigma"),
                     "ci": ci, "limit": a.get("limit"), "verdict": a.get("verdict"),
                     "word": w.outcome_word(a.get("verdict"))})
    verdict = res.get("verdict", "ERROR")
    reason = str(res.get("reason") or "")
    abort = res.get("abort") or {}
    stand = abort.get("stand") or {}
    nxt: list[str] = list(stand.get("commands") or [])
    recording = res.get("recording")
    report = isinstance(recording, str) and (Path(recording) / "report.html").is_file()
    measured = res.get("measured")
    aborted = verdict == "ABORTED"
    return {
        "verdict": verdict, "word": w.outcome_word(verdict), "axes": axes,
        "reason": reason, "kind": abort.get("kind", ""),
        "headline": w.abort_headline(abort, reason) if aborted else "",
        "detail": reason, "details_label": w(DETAILS),
        "stand": stand.get("text", ""), "stand_text": w.stand_sentence(stand),
        "stand_detail": stand.get("text", ""), "at_rest": stand.get("at_rest"),
        "at_zero": stand.get("at_zero"), "next": nxt,
        "advice": w.abort_advice(abort, reason) if aborted else "", "report": report,
        "measured": measured,
        "measured_word": w.outcome_word(measured.get("verdict"))
        if isinstance(measured, dict) else "",
        "deviations": res.get("deviations") or [],
        "refused": False, "exit_code": run.exit_code, "recording": recording, "steps": [],
    }


def _plan_outcome(run: Run, res: dict[str, Any], w: Words) -> dict[str, Any]:
    """A plan's verdict screen: its outcome, each step's status and report."""
    steps = []
    for s in res.get("steps") or []:
        rec = s.get("recording")
        steps.append({"name": s.get("name"), "verdict": s.get("status"),
                      "word": w.outcome_word(s.get("status")), "reason": s.get("reason", ""),
                      "detail": s.get("reason", ""),
                      "report": isinstance(rec, str) and (Path(rec) / "report.html").is_file()})
    verdict = res.get("outcome", "ERROR")
    headline = (w(_("The plan was stopped before its end.")) if verdict == "ABORTED" else
                w(_("The plan could not be carried out.")) if verdict == "ERROR" else "")
    return {"verdict": verdict, "word": w.outcome_word(verdict), "axes": [], "steps": steps,
            "reason": res.get("reason", ""), "headline": headline,
            "detail": res.get("reason", ""), "details_label": w(DETAILS), "kind": "",
            "stand": "", "stand_text": "", "stand_detail": "", "next": [], "advice": "",
            "report": False, "refused": False, "exit_code": run.exit_code, "recording": None}
