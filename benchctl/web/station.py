"""One station's runs as the panel sees them: the child process of the run going on (at most
one), what it published (``benchctl.web.live``) and how it ended; and the browsers watching.

The run is ``benchctl run … --json --quiet --live SOCKET``, a child in a session of its own: its
output goes to files (``result.json``: the run's JSON; ``stderr.txt``: a refusal or an error),
not pipes, so a server that stops or dies never blocks or breaks it. Stop is SIGINT to it — the
same path as Ctrl-C. What the panel needs to take the run up again after its own restart is kept
in a state file (``benchctl.web.runstate``): a panel started again re-attaches to a run still
going on (its live socket bound again at the same path, its end found by polling its process)
or shows the verdict of one that ended meanwhile. Every text the operator reads of the run is
composed in the station's language (``benchctl.web.wording``), the run's English kept as
details; the run itself and its verdict screen are ``benchctl.web.panelrun``. Everything
here runs on the server's event loop; the run's datagrams come in through an asyncio datagram
endpoint and go out to each browser's queue without waiting: a browser that does not keep up
loses its queued events and is sent the whole state again.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import os
import shutil
import signal
import socket
import stat
import subprocess
import sys
import tempfile
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from benchctl.errors import InputError
from benchctl.jsonout import dumps
from benchctl.web import runstate
from benchctl.web.panelrun import STATUS_TRACE_POINTS, Run
from benchctl.web.settings import PanelSettings
from benchctl.web.wording import REATTACHED, Words

log = logging.getLogger(__name__)

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
                 on_change: Callable[[Run], None] | None = None,
                 state_file: Path | None = None) -> None:
        """``on_change(run)``: told when a run starts, changes state and ends (the station's
        heartbeat); never lets its failure reach the panel. ``state_file``: where the current
        run is kept for a panel started again (``benchctl.web.runstate``; None: nowhere)."""
        self.settings = settings
        self.on_change = on_change
        self.state_file = state_file
        self.words = Words(settings.lang)
        self.run: Run | None = None
        self.watchers: set[Watcher] = set()
        self.last_operator = ""
        self._next_id = 1
        self._tmp = Path(tempfile.mkdtemp(prefix="benchctl-panel-"))
        self._transport: asyncio.BaseTransport | None = None
        self._waiter: asyncio.Task[None] | None = None
        self._old_dirs: list[Path] = []  # an earlier panel's folders of a run taken up

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
        return {"run": self.run.view(trace_points, self.words) if self.run is not None
                else None, "last_operator": self.last_operator}

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
        run.pid = run.proc.pid
        run.identity = runstate.identity(run.pid) or ""
        self._save(run)
        self._changed(run)
        self.last_operator = operator
        self._waiter = asyncio.get_running_loop().create_task(self._wait(run))
        self.publish("status", self.status())
        return run

    async def _listen(self, run: Run) -> None:
        self._close_transport()
        path = run.folder / "live.sock"
        if run.adopted:  # the dead server's socket file: the run sends to this path again
            with contextlib.suppress(FileNotFoundError):
                if not stat.S_ISSOCK(path.lstat().st_mode):
                    raise OSError(f"{path}: not a socket; the run's live data not taken up")
                path.unlink()
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        sock.bind(str(path))
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
            reason = self.words.state_reason(run.reason)
            self.publish("state", {"state": run.state, "reason": run.reason,
                                   "reason_text": reason["text"],
                                   "reason_detail": reason["detail"]})
            self._changed(run)
        elif kind == "message":
            text = str(msg.get("text", ""))
            shown = self.words.message(text)
            run.messages.append(shown)
            self.publish("message", shown)
            if text.startswith("recording to ") and run.recording is None:
                run.recording = text[len("recording to "):]
                self._save(run)
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
        try:
            if run.proc is not None:
                while run.proc.poll() is None:
                    await asyncio.sleep(POLL_S)
            else:  # taken up again: not our child, its end is looked for, its code not known
                while self._alive(run):
                    await asyncio.sleep(POLL_S)
            await asyncio.sleep(POLL_S)  # the last datagrams in
            self._finish(run, run.proc.returncode if run.proc is not None else None)
        except Exception:  # never a panel that shows a run going on for ever
            log.exception("the end of the run of %s not handled", run.serial)
            run.finished = True
            self.publish("status", self.status())

    def _alive(self, run: Run) -> bool:
        return run.pid is not None and runstate.is_the_run(
            run.pid, run.identity, run.folder / "live.sock")

    def _finish(self, run: Run, code: int | None) -> None:
        result = _read_json(run.folder / "result.json")
        if result is None and run.recording is not None:  # its output gone: its recording's
            result = runstate.from_recording(Path(run.recording))
        run.result = result
        if code is None and result is not None and isinstance(result.get("exit_code"), int):
            code = result["exit_code"]
        if run.result is not None and isinstance(run.result.get("recording"), str):
            run.recording = run.result["recording"]
        err = _read_text(run.folder / "stderr.txt")
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
        run.finished = True
        run.ended_utc = _now_utc()
        self._save(run)
        self._changed(run)
        self._close_transport()
        self.publish("ended", {"run": run.view(words=self.words)})

    def _save(self, run: Run) -> None:
        if self.state_file is not None and run is self.run:
            runstate.save(self.state_file, run.saved(self.settings.out_dir))

    async def resume(self) -> None:
        """At the panel's start: take up the run its state file names. Still going on (the
        same process: its pid and start time, its command line), it is shown running again,
        its live data received at the same socket, Stop sends it SIGINT, its end is looked for
        and its verdict read from its own files; ended meanwhile, its verdict is shown (from
        its output, else its recording); nothing to show, the panel starts idle."""
        if self.state_file is None or self.busy:
            return
        data = runstate.load(self.state_file)
        if data is None:
            return
        try:
            run = Run(int(data["run_id"]), str(data["serial"]), str(data["operator"]),
                      str(data["profile"]), Path(str(data["folder"])),
                      kind=str(data.get("kind") or "test"))
        except (KeyError, TypeError, ValueError) as e:
            log.warning("the panel's state in %s not taken up: %s", self.state_file, e)
            return
        run.adopted = True
        if (run.folder.parent.name.startswith("benchctl-panel-")
                and run.folder.parent.parent == Path(tempfile.gettempdir())):
            self._old_dirs.append(run.folder.parent)
        run.pid = data.get("pid") if isinstance(data.get("pid"), int) else None
        run.identity = str(data.get("identity") or "")
        run.recording = data.get("recording") if isinstance(data.get("recording"), str) \
            else None
        run.started_utc = str(data.get("started_utc") or "")
        run.stop_requested = bool(data.get("stop_requested"))
        self._next_id = max(self._next_id, run.id + 1)
        self.last_operator = run.operator
        if data.get("ended"):
            result = data.get("result")
            run.result = result if isinstance(result, dict) else None
            run.state = str(data.get("state") or "")
            run.error = str(data.get("error") or "")
            run.refused = bool(data.get("refused"))
            code = data.get("exit_code")
            run.exit_code = code if isinstance(code, int) else None
            run.ended_utc = str(data.get("ended_utc") or "")
            run.finished = True
            self.run = run
            self._changed(run)  # the station's heartbeat: its last outcome
            return
        if not self._alive(run):  # it ended while no panel watched
            self.run = run
            self._finish(run, None)
            if run.result is None and not run.error:
                self.run = None  # nothing to show of it
                runstate.remove(self.state_file)
            return
        run.state = "running"
        run.messages.append({"text": self.words(REATTACHED), "detail": ""})
        self.run = run
        try:
            run.folder.mkdir(mode=0o700, parents=True, exist_ok=True)
            await self._listen(run)
        except OSError as e:  # shown running all the same, Stop works; its live data lost
            log.warning("the run's live data (pid %s) not taken up: %s", run.pid, e)
        log.warning("took up the run of %s again (pid %s)", run.serial, run.pid)
        self._changed(run)
        self._waiter = asyncio.get_running_loop().create_task(self._wait(run))
        self.publish("status", self.status())

    def _changed(self, run: Run) -> None:
        if self.on_change is None:
            return
        try:
            self.on_change(run)
        except Exception as e:  # the heartbeat is the line view's, never the panel's trouble
            log.warning("station state not published: %s: %s", type(e).__name__, e)

    def stop(self) -> bool:
        """SIGINT to the run going on (Ctrl-C's path); False when none is. A run taken up
        again gets it only while it is still the same process."""
        run = self.run
        if run is None or run.ended or (run.proc is None and run.pid is None):
            return False
        if run.stop_requested:  # once: the run is already on its way out
            return True
        if run.proc is not None:
            with contextlib.suppress(ProcessLookupError):
                run.proc.send_signal(signal.SIGINT)
        elif self._alive(run) and run.pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(run.pid, signal.SIGINT)
        else:
            return False  # ended: its end is on its way to the page
        run.stop_requested = True
        self._save(run)
        self.publish("stopping", {"id": run.id})
        return True

    def dismiss(self) -> bool:
        """Put away an ended run's verdict (the form again); False while one is going on."""
        if self.busy:
            return False
        self.run = None
        if self.state_file is not None:
            runstate.remove(self.state_file)
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
        if run is not None and not run.ended and run.pid is not None:
            log.warning("the run of %s (pid %d) goes on without the panel and ends by itself "
                        "(a panel started again takes it up); to stop it as Stop would: "
                        "kill -INT %d", run.serial, run.pid, run.pid)
            if run.adopted:
                shutil.rmtree(self._tmp, ignore_errors=True)  # its files are the old panel's
            return
        shutil.rmtree(self._tmp, ignore_errors=True)
        for old in self._old_dirs:  # an earlier panel's files of a run taken up, now ended
            shutil.rmtree(old, ignore_errors=True)


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return ""


def _read_json(path: Path) -> dict[str, Any] | None:
    """The run's JSON output (None: none, or not a whole object)."""
    text = _read_text(path)
    try:
        obj = json.loads(text) if text.strip() else None
    except ValueError:
        return None
    return obj if isinstance(obj, dict) else None
