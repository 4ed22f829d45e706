"""The panel's view of a station (``benchctl.web.station``), without a child process: what a
run's datagrams become, a browser that falls behind, the verdict screen's content."""

from __future__ import annotations

import asyncio
import json
import shutil
import time
from pathlib import Path
from typing import Any

from repo_paths import ROOT

from benchctl.web.panelrun import Run, outcome
from benchctl.web.settings import PanelSettings
from benchctl.web.station import QUEUE_EVENTS, Station, Watcher


def station(tmp: Path) -> Station:
    return Station(PanelSettings(config=ROOT / "config/sim.yaml",
                                 profiles=(ROOT / "profiles/paper_vessel_roll_short120.yaml",)))


def test_a_browser_that_falls_behind_gets_the_whole_state_again() -> None:
    async def go() -> Watcher:
        w = Watcher()
        for i in range(QUEUE_EVENTS + 10):
            w.push(f"event: snapshot\ndata: {i}\n\n")  # never waits
        return w

    w = asyncio.run(go())
    assert w.stale  # its backlog dropped: the stream sends "status" next
    assert w.queue.qsize() < QUEUE_EVENTS


def test_datagrams_become_the_live_view(tmp_path: Path) -> None:
    st = station(tmp_path)
    try:
        w = st.watch()
        run = Run(1, "SN", "op", "short", tmp_path)
        st.run = run
        st.on_live(run, {"kind": "state", "state": "running", "reason": ""})
        st.on_live(run, {"kind": "snapshot", "state": "running", "elapsed_s": 1.0,
                         "stand_deg": {"roll": 1.5}, "instrument_deg": {"roll": 1.4}})
        st.on_live(run, {"kind": "snapshot", "state": "running", "elapsed_s": None})
        st.on_live(run, {"kind": "message", "text": "<b>x</b>"})
        st.on_live(run, {"kind": "prompt", "id": 0, "text": "Clear?", "timeout_s": 600})
        st.on_live(run, {"kind": "prompt", "id": 0, "text": "Clear?", "timeout_s": 600})
        view = st.status()["run"]
        assert view["state"] == "running"
        assert view["messages"] == [{"text": "", "detail": "<b>x</b>"}]  # not known: a detail
        assert view["trace"] == [{"t": 1.0, "stand": {"roll": 1.5},
                                  "instrument": {"roll": 1.4}}]  # a point needs a time
        assert view["prompt"]["text"] == "Clear?"
        events = [w.queue.get_nowait().split("\n")[0][len("event: "):]
                  for _ in range(w.queue.qsize())]
        assert events == ["state", "snapshot", "snapshot", "message", "prompt"]  # asked once
    finally:
        shutil.rmtree(st._tmp, ignore_errors=True)


def result_run(tmp: Path, result: dict[str, Any], code: int) -> Run:
    run = Run(3, "SN", "op", "short", tmp)
    run.result, run.exit_code = result, code
    return run


def test_the_verdict_screen_of_an_abort_says_what_to_do(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "report.html").write_text("<html></html>")
    res = {"verdict": "ABORTED", "state": "aborted", "reason": "tracking error 0.6°",
           "recording": str(rec), "abort": {"kind": "equipment", "stand": {
               "text": "roll +3.000°; MOVING, servo on; NOT at zero", "at_rest": False,
               "at_zero": False, "commands": ["benchctl stand home --config c.yaml"]}}}
    o = outcome(result_run(tmp_path, res, 2))
    assert o["verdict"] == "ABORTED" and o["kind"] == "equipment"
    assert o["next"] == ["benchctl stand home --config c.yaml"]
    assert o["report"] is True and o["at_rest"] is False


def test_the_verdict_screen_of_a_pass_holds_sigma_its_interval_and_limit(tmp_path: Path) -> None:
    res = json.loads(json.dumps({"verdict": "PASS", "state": "done", "recording": None,
                                 "axes": {"roll": {"sigma": 0.22, "sigma_ci95": [0.19, 0.28],
                                                   "limit": 0.4, "verdict": "PASS"}}}))
    o = outcome(result_run(tmp_path, res, 0))
    assert o["axes"] == [{"axis": "roll", "axis_name": "roll", "sigma": 0.22,
                          "ci": [0.19, 0.28], "limit": 0.4, "verdict": "PASS", "word": "PASS"}]
    assert o["report"] is False


def test_a_run_that_did_not_start_says_why(tmp_path: Path) -> None:
    run = Run(4, "SN", "op", "short", tmp_path)
    run.exit_code, run.error, run.refused = 2, "stand x is in use by benchctl run", True
    o = outcome(run)
    assert o["verdict"] == "ERROR" and o["refused"] and "in use" in o["reason"]


# ---- a panel started again (benchctl.web.runstate): the run it left going, or its verdict
def saved_run(tmp: Path, st: Station, pid: int, ident: str, **more: Any) -> Path:
    """The state an earlier panel left for its run: its folder (socket, output) in ``tmp``."""
    folder = tmp / "old-panel" / "run-7"
    folder.mkdir(parents=True)
    assert st.state_file is not None
    from benchctl.web import runstate

    runstate.save(st.state_file, {
        "run_id": 7, "serial": "SN-7", "operator": "ana", "profile": "short", "kind": "test",
        "folder": str(folder), "socket": str(folder / "live.sock"), "pid": pid,
        "identity": ident, "recording": None, "started_utc": "2026-01-01T00:00:00+00:00",
        "stop_requested": False, "ended": False, **more})
    return folder


def stand_in_run(sock: Path) -> Any:
    """A stand-in for a run left going: a process whose command line is a run's (``--live`` at
    the panel's socket), up and waiting, that ends on SIGINT as a run does at Ctrl-C. It handles
    SIGINT whatever it inherited, as a run does (``benchctl.exits``: a shell without job control
    starts its background commands with SIGINT ignored, a loaded CI run's included)."""
    import subprocess
    import sys

    child = subprocess.Popen([sys.executable, "-c",
                              "import signal, time; "
                              "signal.signal(signal.SIGINT, signal.default_int_handler); "
                              "print('up', flush=True); time.sleep(120)", "--live",
                              str(sock)], stdout=subprocess.PIPE, text=True)
    assert child.stdout is not None and child.stdout.readline() == "up\n"
    return child


def restarted(tmp: Path) -> Station:
    return Station(PanelSettings(config=ROOT / "config/sim.yaml", profiles=(
        ROOT / "profiles/paper_vessel_roll_short120.yaml",), lang="ru"),
        state_file=tmp / "runs" / ".benchctl-panel-8350.json")


def test_a_run_left_going_is_taken_up_its_live_data_received_and_stopped(
        tmp_path: Path) -> None:
    import signal

    from benchctl.web import runstate
    from benchctl.web.live import LivePublisher

    st = restarted(tmp_path)
    sock = tmp_path / "old-panel" / "run-7" / "live.sock"
    child = stand_in_run(sock)
    try:
        ident = runstate.identity(child.pid)
        assert ident is not None
        folder = saved_run(tmp_path, st, child.pid, ident)
        stale = socket_file(folder / "live.sock")  # the dead panel's socket, still there

        async def go() -> dict[str, Any]:
            await st.resume()
            view = st.status()["run"]
            assert view["adopted"] and not view["ended"] and view["serial"] == "SN-7"
            assert view["messages"][0]["text"].startswith("Панель была перезапущена")
            pub = LivePublisher(folder / "live.sock")  # what the run sends arrives again
            assert pub.send("snapshot", state="running", elapsed_s=12.5,
                            stand_deg={"roll": 1.0})
            deadline = time.monotonic() + 60  # generous: a loaded machine
            while st.run is not None and st.run.snapshot is None:
                assert time.monotonic() < deadline, "the datagram sent was not received"
                await asyncio.sleep(0.02)
            assert st.stop()  # SIGINT, to this same process
            while st.busy:
                assert time.monotonic() < deadline, (
                    f"the run's end not seen; the process: {child.poll()} (None: running)")
                await asyncio.sleep(0.05)
            view = st.status()["run"]
            await st.close()
            return view

        view = asyncio.run(go())
        stale.close()
    finally:
        if child.poll() is None:
            child.kill()
        child.wait(30)
    assert child.returncode == -signal.SIGINT or child.returncode == 1  # KeyboardInterrupt
    assert view["snapshot"]["elapsed_s"] == 12.5
    o = view["outcome"]
    assert o["verdict"] == "ABORTED" and o["word"] == "ПРЕРВАНО"
    assert o["headline"] == "Испытание остановлено, не успев записать результат."
    saved = json.loads((tmp_path / "runs" / ".benchctl-panel-8350.json").read_text())
    assert saved["ended"] and saved["stop_requested"]


def socket_file(path: Path) -> Any:
    import socket

    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(str(path))
    return s


def test_a_recycled_pid_is_not_taken_for_the_run(tmp_path: Path) -> None:
    """The pid alive but another process (its start time, its command line not the run's):
    never signalled; the run ended meanwhile, its verdict from its own output."""
    import os

    st = restarted(tmp_path)
    folder = saved_run(tmp_path, st, os.getpid(), "x:1")
    rec = tmp_path / "runs" / "20260101T000000Z_SN-7"
    rec.mkdir(parents=True)
    (rec / "report.html").write_text("<html></html>")
    (folder / "result.json").write_text(json.dumps({
        "verdict": "PASS", "state": "done", "recording": str(rec), "exit_code": 0,
        "axes": {"roll": {"sigma": 0.2, "sigma_ci95": [0.19, 0.21], "limit": 0.4,
                          "verdict": "PASS"}}}))

    async def go() -> None:
        await st.resume()
        await st.close()

    asyncio.run(go())
    assert st.run is not None and st.run.ended and not st.busy
    o = st.status()["run"]["outcome"]
    assert o["verdict"] == "PASS" and o["word"] == "ГОДЕН" and o["report"] is True
    assert o["axes"][0]["axis_name"] == "крен" and o["exit_code"] == 0
    assert st.report_file(7) == rec / "report.html"
    assert st.stop() is False  # nothing to stop: this pid is not the run
    assert st.dismiss() and not (tmp_path / "runs" / ".benchctl-panel-8350.json").exists()


def test_its_output_gone_the_verdict_is_read_from_its_recording(tmp_path: Path) -> None:
    """The panel's files of the run gone (only its recording left): an aborted run's verdict
    from its ``record.json``; nothing at all to show, the panel starts idle."""
    st = restarted(tmp_path)
    rec = tmp_path / "runs" / "20260101T000000Z_SN-7"
    rec.mkdir(parents=True)
    (rec / "record.json").write_text(json.dumps({
        "outcome": "ABORTED", "exit_code": 2, "abort": {
            "kind": "operator", "source": "signal", "error": "SafetyAbort",
            "reason": "signal: interrupted by SIGINT",
            "stand": {"known": True, "axes": {"roll": {"angle_deg": 0.0, "rate_deg_s": 0.0}},
                      "enabled": False, "fault_code": 0, "estop": False, "at_rest": True,
                      "at_zero": True, "commands": []}}}))
    folder = saved_run(tmp_path, st, 999_999_999, "x:1", recording=str(rec))
    shutil.rmtree(folder)

    async def go(s: Station) -> None:
        await s.resume()
        await s.close()

    asyncio.run(go(st))
    o = st.status()["run"]["outcome"]
    assert o["verdict"] == "ABORTED" and o["exit_code"] == 2
    assert o["headline"] == "Остановлено оператором (кнопка «Стоп» или Ctrl-C в терминале)."
    assert o["stand_text"] == "Стенд: крен +0,000°. В покое. Привод выключен. В нуле."
    # a state naming nothing left to show: idle
    (rec / "record.json").unlink()
    again = restarted(tmp_path)
    saved_run(tmp_path / "other", again, 999_999_999, "x:1")
    shutil.rmtree(tmp_path / "other")
    asyncio.run(go(again))
    assert again.run is None and not again.state_file.exists()  # type: ignore[union-attr]


def test_a_plan_taken_up_again_gets_its_questions_answered(tmp_path: Path) -> None:
    """A plan left going: its question, published again, reaches the new panel, whose answer
    is written where the plan waits for it (the earlier panel's answers folder)."""

    from benchctl.web import runstate
    from benchctl.web.live import LivePublisher

    st = restarted(tmp_path)
    sock = tmp_path / "old-panel" / "run-7" / "live.sock"
    child = stand_in_run(sock)
    try:
        ident = runstate.identity(child.pid)
        assert ident is not None
        folder = saved_run(tmp_path, st, child.pid, ident, kind="plan")
        (folder / "answers").mkdir()

        async def go() -> None:
            await st.resume()
            assert st.run is not None and st.run.kind == "plan" and st.busy
            LivePublisher(folder / "live.sock").send("prompt", id=0, text="Unit mounted?",
                                                     timeout_s=600)
            while st.run.prompt is None:
                await asyncio.sleep(0.02)
            assert st.answer(0, True)
            child.kill()  # the plan ends (its result not written): the panel sees it go
            while st.busy:
                await asyncio.sleep(0.05)
            await st.close()

        asyncio.run(go())
    finally:
        if child.poll() is None:
            child.kill()
        child.wait(30)
    assert (folder / "answers" / "prompt-0.answer").read_text() == "yes"
    assert st.run is not None and st.run.ended
