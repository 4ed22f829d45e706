"""One station's runs as the panel sees them: the child process of the run going on (at most
one), what it published (``benchctl.web.live``) and how it ended; and the browsers watching.

The run is ``benchctl run … --json --quiet --live SOCKET``, a child in a session of its own: its
output goes to files (``result.json``: the run's JSON; ``stderr.txt``: a refusal or an error),
not pipes, so a server that stops or dies never blocks or breaks it. Stop is SIGINT to it — the
same path as Ctrl-C. Everything here runs on the server's event loop; the run's datagrams come
in through an asyncio datagram endpoint and go out to each browser's queue without waiting: a
browser that does not keep up loses its queued events and is sent the whole state again.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import os
import signal
import socket
import subprocess
import sys
import tempfile
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from benchctl.errors import InputError
from benchctl.jsonout import dumps
from benchctl.web.settings import PanelSettings

log = logging.getLogger(__name__)

TRACE_POINTS = 3000  # the plot's history (5 min of the run's 10 snapshots a second)
STATUS_TRACE_POINTS = 600  # sent to a browser that connects mid-run (the last minute)
MESSAGES = 200  # the run's last messages kept
QUEUE_EVENTS = 256  # a browser's backlog before it is sent the whole state instead
POLL_S = 0.1  # how often the child's end is looked for


def sse(event: str, data: dict[str, Any]) -> str:
    """One server-sent event: its name and its data as JSON."""
    return f"event: {event}\ndata: {dumps(data)}\n\n"


class Watcher:
    """One browser's queue of events (each already as its text: encoded once for every
    browser); ``stale`` when events were dropped for it."""

    def __init__(self) -> None:
        self.queue: asyncio.Queue[str] = asyncio.Queue(QUEUE_EVENTS)
        self.stale = False

    def push(self, text: str) -> None:
        try:
            self.queue.put_nowait(text)
        except asyncio.QueueFull:
            self.stale = True
            while not self.queue.empty():
                self.queue.get_nowait()


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
    state: str = "starting"
    reason: str = ""
    snapshot: dict[str, Any] | None = None
    trace: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=TRACE_POINTS))
    messages: deque[str] = field(default_factory=lambda: deque(maxlen=MESSAGES))
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
        return self.exit_code is not None

    def view(self, trace_points: int = STATUS_TRACE_POINTS) -> dict[str, Any]:
        """What a browser is sent: everything it shows of this run."""
        return {
            "id": self.id, "kind": self.kind, "serial": self.serial,
            "operator": self.operator, "profile": self.profile, "state": self.state,
            "reason": self.reason, "prompt": self.prompt,
            "snapshot": self.snapshot,
            "trace": list(self.trace)[-trace_points:] if trace_points > 0 else [],
            "messages": list(self.messages)[-20:], "ended": self.ended,
            "stop_requested": self.stop_requested,
            "outcome": outcome(self) if self.ended else None,
        }


def outcome(run: Run) -> dict[str, Any]:
    """The verdict screen's content: the verdict, σ per axis with its interval and limit, an
    abort's reason and what to do next, the report; or why the run did not start."""
    res = run.result
    if res is None:
        return {"verdict": "ABORTED" if run.stop_requested else "ERROR", "axes": [],
                "steps": [], "reason": run.error or f"ended with exit code {run.exit_code}",
                "refused": run.refused, "kind": "", "next": [], "report": False,
                "exit_code": run.exit_code}
    if run.kind == "plan":
        return _plan_outcome(run, res)
    axes = []
    for name, a in (res.get("axes") or {}).items():
        ci = a.get("sigma_ci95") or [None, None]
        axes.append({"axis": name, "sigma": a.get("sigma"), "ci": ci, "limit": a.get("limit"),
                     "verdict": a.get("verdict")})
    abort = res.get("abort") or {}
    stand = abort.get("stand") or {}
    nxt: list[str] = list(stand.get("commands") or [])
    recording = res.get("recording")
    report = isinstance(recording, str) and (Path(recording) / "report.html").is_file()
    return {
        "verdict": res.get("verdict", "ERROR"), "axes": axes,
        "reason": res.get("reason", ""), "kind": abort.get("kind", ""),
        "stand": stand.get("text", ""), "at_rest": stand.get("at_rest"),
        "at_zero": stand.get("at_zero"), "next": nxt, "report": report,
        "measured": res.get("measured"), "deviations": res.get("deviations") or [],
        "refused": False, "exit_code": run.exit_code, "recording": recording, "steps": [],
    }


def _plan_outcome(run: Run, res: dict[str, Any]) -> dict[str, Any]:
    """A plan's verdict screen: its outcome, each step's status and report."""
    steps = []
    for s in res.get("steps") or []:
        rec = s.get("recording")
        steps.append({"name": s.get("name"), "verdict": s.get("status"),
                      "reason": s.get("reason", ""),
                      "report": isinstance(rec, str) and (Path(rec) / "report.html").is_file()})
    return {"verdict": res.get("outcome", "ERROR"), "axes": [], "steps": steps,
            "reason": res.get("reason", ""), "kind": "", "stand": "", "next": [],
            "report": False, "refused": False, "exit_code": run.exit_code, "recording": None}


def _now_utc() -> str:
    """The host's time now, for the station's heartbeat (the server's, not a run's clock)."""
    return datetime.now(UTC).isoformat(timespec="seconds")  # noqa: TID251


def _point(snap: dict[str, Any]) -> dict[str, Any] | None:
    t = snap.get("elapsed_s")
    if t is None or not math.isfinite(t):
        return None
    return {"t": t, "stand": snap.get("stand_deg") or {},
            "instrument": snap.get("instrument_deg") or {}}


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, station: Station, run: Run) -> None:
        self.station = station
        self.run = run

    def datagram_received(self, data: bytes, addr: Any) -> None:
        try:
            msg = json.loads(data)
        except ValueError:
            return
        if isinstance(msg, dict):
            self.station.on_live(self.run, msg)


class Station:
    """The panel's state: the current or last run, and the browsers watching."""

    def __init__(self, settings: PanelSettings,
                 on_change: Callable[[Run], None] | None = None) -> None:
        """``on_change(run)``: told when a run starts, changes state and ends (the station's
        heartbeat); never lets its failure reach the panel."""
        self.settings = settings
        self.on_change = on_change
        self.run: Run | None = None
        self.watchers: set[Watcher] = set()
        self.last_operator = ""
        self._next_id = 1
        self._tmp = Path(tempfile.mkdtemp(prefix="benchctl-panel-"))
        self._transport: asyncio.BaseTransport | None = None
        self._waiter: asyncio.Task[None] | None = None

    # ---- browsers
    def watch(self) -> Watcher:
        w = Watcher()
        self.watchers.add(w)
        return w

    def unwatch(self, w: Watcher) -> None:
        self.watchers.discard(w)

    def publish(self, event: str, data: dict[str, Any]) -> None:
        if not self.watchers:
            return
        text = sse(event, data)
        for w in list(self.watchers):
            w.push(text)

    def status(self, trace_points: int = STATUS_TRACE_POINTS) -> dict[str, Any]:
        """Everything a browser shows; ``trace_points``: the plot's last points sent."""
        return {"run": self.run.view(trace_points) if self.run is not None else None,
                "last_operator": self.last_operator}

    # ---- runs
    @property
    def busy(self) -> bool:
        return self.run is not None and not self.run.ended

    def command(self, run: Run, path: Path) -> list[str]:
        """The child's command line: ``benchctl run`` of a profile or ``benchctl plan``."""
        s = self.settings
        live = ["--json", "--quiet", "--live", str(run.folder / "live.sock")]
        cmd = [sys.executable, "-m", "benchctl"]
        if run.kind == "plan":
            cmd += ["plan", str(path), "--config", str(s.config), "--serial", run.serial,
                    "--operator", run.operator, *live, "--answers", str(run.folder / "answers")]
        else:
            cmd += ["run", "--config", str(s.config), "--profile", str(path), "--serial",
                    run.serial, "--operator", run.operator, *live]
            if s.duration_s is not None:
                cmd += ["--duration", repr(s.duration_s)]
        if s.out_dir is not None:
            cmd += ["--out", str(s.out_dir)]
        return cmd

    async def start(self, serial: str, operator: str, path: Path, kind: str = "test") -> Run:
        """Start a run of a profile, or a plan (``kind``); ``InputError`` while one is going
        on (or starting: two Starts at once start one run). Its datagram socket is bound
        before the child starts: nothing it publishes is lost. ``OSError`` when the child
        cannot be started (the station is free again)."""
        if self.busy:
            raise InputError("a run is going on at this station: one run per stand")
        run = Run(self._next_id, serial, operator, path.stem,
                  self._tmp / f"run-{self._next_id}", kind=kind)
        self._next_id += 1
        previous, self.run = self.run, run  # taken before the first wait
        try:
            run.folder.mkdir(mode=0o700)
            (run.folder / "answers").mkdir(mode=0o700)
            await self._listen(run)
            with (run.folder / "result.json").open("wb") as out, \
                    (run.folder / "stderr.txt").open("wb") as err:
                run.proc = subprocess.Popen(
                    self.command(run, path), stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                    start_new_session=True,  # the server's terminal's Ctrl-C is not the run's
                )
        except BaseException:
            self.run = previous
            self._close_transport()
            raise
        run.started_utc = _now_utc()
        self._changed(run)
        self.last_operator = operator
        self._waiter = asyncio.get_running_loop().create_task(self._wait(run))
        self.publish("status", self.status())
        return run

    async def _listen(self, run: Run) -> None:
        self._close_transport()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock.bind(str(run.folder / "live.sock"))
        sock.setblocking(False)
        loop = asyncio.get_running_loop()
        self._transport, _ = await loop.create_datagram_endpoint(
            lambda: _Datagrams(self, run), sock=sock)

    def _close_transport(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    def on_live(self, run: Run, msg: dict[str, Any]) -> None:
        """A datagram of ``run``'s: kept and passed on to the browsers."""
        run.datagrams += 1
        kind = msg.get("kind")
        if kind == "snapshot":
            run.snapshot = msg
            run.state = str(msg.get("state", run.state))
            point = _point(msg)
            if point is not None:
                run.trace.append(point)
            self.publish("snapshot", {"snapshot": msg, "point": point})
        elif kind == "state":
            run.state, run.reason = str(msg.get("state", "")), str(msg.get("reason", ""))
            self.publish("state", {"state": run.state, "reason": run.reason})
            self._changed(run)
        elif kind == "message":
            run.messages.append(str(msg.get("text", "")))
            self.publish("message", {"text": str(msg.get("text", ""))})
        elif kind == "verdict":
            run.verdict = {"verdict": msg.get("verdict"), "detail": msg.get("detail", "")}
        elif (kind == "prompt" and isinstance(msg.get("id"), int)
              and msg["id"] not in run.answered):  # sent again until the plan reads it
            if run.prompt is None or run.prompt["id"] != msg["id"]:
                run.prompt = {"id": msg["id"], "text": str(msg.get("text", "")),
                              "timeout_s": msg.get("timeout_s")}
                self.publish("prompt", run.prompt)
        elif (kind == "prompt_closed" and run.prompt is not None
              and run.prompt["id"] == msg.get("id")):
            run.prompt = None
            self.publish("prompt_closed", {"id": msg.get("id"), "why": str(msg.get("why", ""))})

    def answer(self, qid: int, yes: bool) -> bool:
        """The operator's answer to the plan's question ``qid`` (False: no such question is
        waiting): written whole (a rename) where the plan looks for it."""
        run = self.run
        if run is None or run.ended or run.prompt is None or run.prompt["id"] != qid:
            return False
        final = run.folder / "answers" / f"prompt-{qid}.answer"
        part = final.with_suffix(".part")
        part.write_text("yes" if yes else "no", encoding="utf-8")
        os.replace(part, final)
        run.answered.add(qid)
        run.prompt = None
        self.publish("prompt_closed", {"id": qid, "why": "yes" if yes else "no"})
        return True

    async def _wait(self, run: Run) -> None:
        assert run.proc is not None
        while run.proc.poll() is None:
            await asyncio.sleep(POLL_S)
        await asyncio.sleep(POLL_S)  # the last datagrams in
        self._finish(run, run.proc.returncode)

    def _finish(self, run: Run, code: int) -> None:
        text = (run.folder / "result.json").read_text(encoding="utf-8", errors="replace")
        try:
            result = json.loads(text) if text.strip() else None
        except ValueError:
            result = None
        run.result = result if isinstance(result, dict) else None
        err = (run.folder / "stderr.txt").read_text(encoding="utf-8", errors="replace")
        lines = [ln for ln in err.splitlines() if ln.strip()]
        errors = [ln for ln in lines if ": error: " in ln]
        run.error = (errors[-1].split(": error: ", 1)[1] if errors
                     else (lines[-1] if lines else ""))
        run.refused = run.result is None and " is in use by " in run.error
        if run.kind == "plan" and run.result is not None:
            run.state = "aborted" if run.result.get("outcome") == "ABORTED" else "done"
        else:
            run.state = "done" if run.result and run.result.get("state") == "done" else (
                "aborted" if run.result else "refused" if run.refused else "error")
        run.prompt = None
        run.exit_code = code
        run.ended_utc = _now_utc()
        self._changed(run)
        self._close_transport()
        self.publish("ended", {"run": run.view()})

    def _changed(self, run: Run) -> None:
        if self.on_change is None:
            return
        try:
            self.on_change(run)
        except Exception as e:  # the heartbeat is the line view's, never the panel's trouble
            log.warning("station state not published: %s: %s", type(e).__name__, e)

    def stop(self) -> bool:
        """SIGINT to the run going on (Ctrl-C's path); False when none is."""
        run = self.run
        if run is None or run.ended or run.proc is None:
            return False
        if run.stop_requested:  # once: the run is already on its way out
            return True
        run.stop_requested = True
        with contextlib.suppress(ProcessLookupError):
            run.proc.send_signal(signal.SIGINT)
        self.publish("stopping", {"id": run.id})
        return True

    def dismiss(self) -> bool:
        """Put away an ended run's verdict (the form again); False while one is going on."""
        if self.busy:
            return False
        self.run = None
        self.publish("status", self.status())
        return True

    def report_file(self, run_id: int, step: int | None = None) -> Path | None:
        """The report of the run ``run_id`` shown (of its plan's step ``step``), if any."""
        run = self.run
        if run is None or run.id != run_id or run.result is None:
            return None
        recording = run.result.get("recording")
        if run.kind == "plan":
            steps = run.result.get("steps") or []
            if step is None or not 0 <= step < len(steps):
                return None
            recording = steps[step].get("recording")
        path = Path(recording) / "report.html" if recording else None
        return path if path is not None and path.is_file() else None

    async def close(self) -> None:
        """The server stops: a run going on is left to end by itself (never stopped by the
        panel going away); the panel's own files go."""
        if self._waiter is not None:
            self._waiter.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._waiter
        self._close_transport()
        run = self.run
        if run is not None and not run.ended and run.proc is not None:
            log.warning("the run of %s (pid %d) goes on without the panel and ends by itself; "
                        "to stop it as Stop would: kill -INT %d", run.serial, run.proc.pid,
                        run.proc.pid)
            return
        import shutil

        shutil.rmtree(self._tmp, ignore_errors=True)
