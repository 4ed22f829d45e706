"""The panel's view of a station (``benchctl.web.station``), without a child process: what a
run's datagrams become, a browser that falls behind, the verdict screen's content."""

from __future__ import annotations

import asyncio
import json
import shutil
from pathlib import Path
from typing import Any

from repo_paths import ROOT

from benchctl.web.settings import PanelSettings
from benchctl.web.station import QUEUE_EVENTS, Run, Station, Watcher, outcome


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
