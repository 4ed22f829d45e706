"""Acceptance plans on the simulated bench, end to end.

- ``plans/ci_short.yaml`` as shipped, through ``benchctl plan --yes --junit --json`` on
  config/sim_virtual.yaml (its simulators started once for the plan, the whole plan on
  simulated time from the config's epoch): exit 0, JUnit XML with one test
  case per measurement and the counts that the records imply, each step's record.json valid and
  judged by the step's limits, plan.json valid and equal to the --json output, the runs in the
  archive that ``benchctl history`` reads. One plan run shared by these checks.
- on an in-process bench (``benchmarks/live_bench.py``): a σ limit the instrument cannot meet →
  FAIL, exit 1, ``on_fail: stop`` skips the next step, cleanup runs; an instrument that falls silent
  mid-plan → that step ABORTED (an ``<error>``), its record stored ABORTED, the next step
  skipped, cleanup ran and left the stand at rest, exit 2; a step timeout ends the step through
  the run's abort path (record ABORTED with the timeout's reason), exit 2. These on simulated
  time (the ``vclock`` fixture); Ctrl-C, a real SIGINT, on the host's (``realtime``).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml
from junitparser import Error, Failure, JUnitXml, Properties, Skipped
from live_bench import FOCUSED, live_bench
from repo_paths import ROOT

from benchctl.cli import main
from benchctl.cli.plan import summary
from benchctl.clock import REAL, Clock, EventLike
from benchctl.clock.virtual import VirtualClock
from benchctl.plan import PlanResult, parse_plan, run_plan
from benchctl.plan.record import load_plan_record
from benchctl.results.record import load_record

# the shared plan run is a module fixture (on simulated time): its time counts toward the first
# test that uses it
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

SERIAL = "0001"  # the tests' simulated instrument reports serial 1: the serial match passes
# plans/ci_short.yaml runs on config/sim.yaml, whose simulated instrument reports its own
PLAN_SERIAL = str(yaml.safe_load((ROOT / "config/sim.yaml").read_text())
                  ["sim"]["instrument"]["serial_number"])

SHORT_ROLL = """
name: plan_short_roll
description: a short roll for the plan tests
reference: ci_short, shortened
kind: roll_spectrum
duration_s: {duration}
fade_in_s: 2
fade_out_s: 2
seed: 3
band_hz: [0.2, 0.6]
axes:
  roll: {{model: exp_cos, sigma_deg: 1.5, period_s: 5.0, damping: 0.2}}
"""


@pytest.fixture(scope="module")
def ci_plan(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """plans/ci_short.yaml as shipped, once for the module, through the CLI, on the simulated
    bench on simulated time: ``--config config/sim_virtual.yaml`` (config/sim.yaml with
    ``sim.clock: virtual``) runs the whole plan on a VirtualClock."""
    out = tmp_path_factory.mktemp("ci_plan")
    junit = out / "ci_short.xml"
    stdout, stderr = io.StringIO(), io.StringIO()
    t0 = time.monotonic()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = main(["plan", str(ROOT / "plans/ci_short.yaml"), "--serial", PLAN_SERIAL, "--yes",
                     "--config", str(ROOT / "config/sim_virtual.yaml"),
                     "--junit", str(junit), "--out", str(out / "runs"), "--json", "--quiet"])
    return {"code": code, "json": json.loads(stdout.getvalue()), "junit": junit,
            "out": out / "runs", "seconds": time.monotonic() - t0, "stderr": stderr.getvalue()}


def _kinds(case: Any) -> list[str]:
    return [type(r).__name__ for r in case.result]


def test_ci_plan_passes_with_exit_0(ci_plan: dict[str, Any]) -> None:
    rec = ci_plan["json"]
    assert ci_plan["code"] == 0, rec["reason"]
    assert (rec["outcome"], rec["exit_code"]) == ("PASS", 0)
    assert [s["name"] for s in rec["steps"]] == ["linearity", "dynamic error"]
    assert [s["status"] for s in rec["steps"]] == ["PASS", "PASS"]
    assert [a["status"] for a in rec["setup"]] == ["ok", "ok"]
    assert [a["status"] for a in rec["cleanup"]] == ["ok", "ok"]
    assert rec["cleanup"][0]["check"] == "ramp_to_zero"
    assert "at zero" in rec["cleanup"][0]["detail"]
    # the plan record on disk is the --json output, and valid against its schema
    folders = list(ci_plan["out"].glob("plan_*"))
    assert len(folders) == 1
    assert load_plan_record(folders[0]) == rec
    # the simulators started once for the plan (on simulated time: in this process), not by
    # each step's run
    err = ci_plan["stderr"]
    assert err.count("starting the simulators for the plan") == 1, err
    assert not any((Path(s["recording"]) / "sim.log").exists() for s in rec["steps"])


def test_a_plan_on_a_virtual_config_runs_on_simulated_time(ci_plan: dict[str, Any]) -> None:
    """``sim.clock: virtual``: run_plan enters a VirtualClock from the config's epoch (as
    run_test does): every stamp is simulated time, never the host's, and the plan's
    simulated minute and more takes a fraction of it on the host."""
    rec = ci_plan["json"]
    assert rec["start_utc"].startswith("2026-01-01T00:0"), rec["start_utc"]
    assert all(s["start_utc"].startswith("2026-01-01T00:0") for s in rec["steps"])
    (folder,) = ci_plan["out"].glob("plan_*")
    assert folder.name.startswith("plan_20260101T000")
    assert rec["duration_s"] > 60.0  # the steps' profiles: 41 s and 25 s of motion, and more
    assert ci_plan["seconds"] < rec["duration_s"]


def test_ci_plan_junit_counts(ci_plan: dict[str, Any]) -> None:
    rec = ci_plan["json"]
    xml = JUnitXml.fromfile(str(ci_plan["junit"]))
    suites = {s.name: s for s in xml}
    assert list(suites) == ["setup", "linearity", "dynamic error", "cleanup"]
    totals = {"tests": 0, "failures": 0, "errors": 0, "skipped": 0}
    for step in rec["steps"]:
        suite = suites[step["name"]]
        ms = step["record"]["measurements"]
        cases = list(suite)
        # one test case per judged measurement, in the record's order; the NOT_JUDGED ones
        # (no limit, a period not excited) are properties of the case they go with, never
        # skipped tests
        judged = [m for m in ms if m["outcome"] != "NOT_JUDGED"]
        assert [c.name for c in cases] == [
            f"{m['axis']}: {m['name']}" if m["axis"] else m["name"] for m in judged]
        props = [p.name for c in cases for ps in c.iterchildren(Properties) for p in ps]
        assert sorted(props) == sorted(f"{m['axis']}: {m['name']}" for m in ms
                                       if m["outcome"] == "NOT_JUDGED")
        expected = {
            "tests": len(judged),
            "failures": sum(m["decisive"] and m["outcome"] in ("FAIL", "INCONCLUSIVE")
                            for m in ms),
            "errors": 0,
            "skipped": 0,
        }
        assert expected["failures"] == 0 and len(props) > 0
        got = {"tests": len(cases),
               "failures": sum("Failure" in _kinds(c) for c in cases),
               "errors": sum("Error" in _kinds(c) for c in cases),
               "skipped": sum("Skipped" in _kinds(c) for c in cases)}
        assert got == expected, step["name"]
        assert (suite.tests, suite.failures, suite.errors, suite.skipped) == tuple(
            expected.values())
        for k, v in expected.items():
            totals[k] += v
        by_name = {c.name: c for c in cases}
        assert _kinds(by_name["roll: sigma"]) == []  # passed
        # every case its real time: the motion's for what it measured, a precheck its own
        assert by_name["roll: sigma"].time > 0.5 * step["duration_s"]
        assert by_name["precheck: instrument streams"].time > 0.5  # a 1 s window
        assert sum(c.time for c in cases if c.name.startswith("precheck: ")) < 10.0
    totals["tests"] += 4  # two setup actions, two cleanup actions: passed
    assert (xml.tests, xml.failures, xml.errors, xml.skipped) == tuple(totals.values())
    # the sine steps' gain at 7 and 10 s: a period the profile does not excite → a property
    lin = {c.name: c for c in suites["linearity"]}
    assert "roll: gain at 10 s" not in lin
    sigma_props = {p.name: p.value for ps in lin["roll: sigma"].iterchildren(Properties)
                   for p in ps}
    assert sigma_props["roll: gain at 10 s"] == ("not measured (not judged: not excited by the "
                                                 "profile)")
    phase = {p.name: p.value for ps in lin["roll: gain at 3 s"].iterchildren(Properties)
             for p in ps}
    assert list(phase) == ["roll: phase at 3 s"] and phase["roll: phase at 3 s"].endswith(
        "(not judged: no limit)")
    assert _kinds(lin["roll: linearity spread"]) == []


def test_ci_plan_step_records_are_valid_and_judged_by_the_step_limits(
    ci_plan: dict[str, Any],
) -> None:
    steps = {s["name"]: s for s in ci_plan["json"]["steps"]}
    for step in steps.values():
        rec = load_record(step["record_path"])  # valid against benchctl-record/1
        assert rec == step["record"]
        assert rec["outcome"] == "PASS" and rec["unit"]["serial"] == PLAN_SERIAL
        assert rec["unit"]["serial_match"] is True  # the simulated instrument's 1018h sub 4
        assert Path(step["recording"]).is_dir()
    lin = {(m["axis"], m["name"]): m for m in steps["linearity"]["record"]["measurements"]}
    assert (lin["roll", "gain at 3 s"]["low"], lin["roll", "gain at 3 s"]["high"]) == (0.95, 1.01)
    assert lin["roll", "gain at 3 s"]["outcome"] == "PASS"
    assert lin["roll", "linearity spread"]["high"] == 0.03
    assert lin["roll", "sigma"]["high"] == 3.0
    dyn = {(m["axis"], m["name"]): m for m in steps["dynamic error"]["record"]["measurements"]}
    assert dyn["roll", "sigma"]["high"] == 0.4 and dyn["roll", "sigma"]["outcome"] == "PASS"


def test_ci_plan_runs_are_in_the_archive(
    ci_plan: dict[str, Any], capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    assert main(["history", PLAN_SERIAL, "--out", str(ci_plan["out"]), "--json"]) == 0
    hist = json.loads(capsys.readouterr().out)
    ids = {Path(s["recording"]).name for s in ci_plan["json"]["steps"]}
    assert {r["run_id"] for r in hist["runs"]} == ids
    assert {r["outcome"] for r in hist["runs"]} == {"PASS"}


# ------------------------------------------------------------------- in-process bench plans
def _profile(tmp_path: Path, name: str, duration: float) -> Path:
    p = tmp_path / f"{name}.yaml"
    p.write_text(SHORT_ROLL.format(duration=duration))
    return p


def _plan(tmp_path: Path, steps: list[dict[str, Any]], **extra: Any) -> Any:
    data = {"name": "sim_plan", "operator": "ci", "steps": steps,
            "cleanup": [{"check": "ramp_to_zero"}], **extra}
    return parse_plan(data, tmp_path / "plan.yaml")


@contextlib.contextmanager
def _when_step_moves(out: Path, action: Any, nth: int = 2,
                     clock: Clock = REAL) -> Iterator[EventLike]:
    """Call ``action`` once the ``nth`` recording in ``out`` shows 2 s of motion (on ``clock``:
    the run's, whose time the recording's ``t_host`` is)."""
    stop, done = clock.event(), clock.event()

    def watch() -> None:
        while not stop.is_set():
            recs = sorted(p.parent for p in out.glob("2*/meta.json"))
            if len(recs) >= nth and (recs[nth - 1] / "events.jsonl").is_file():
                for line in (recs[nth - 1] / "events.jsonl").read_text().splitlines():
                    if '"motion_start"' in line and clock.monotonic() - json.loads(line)[
                            "t_host"] >= 2.0:
                        action()
                        done.set()
                        return
            stop.wait(0.1)

    t = clock.thread(watch, name="plan-test-watch")
    t.start()
    try:
        yield done
    finally:
        stop.set()
        t.join()


def test_a_failing_limit_exits_1_stops_the_plan_and_runs_cleanup(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    roll = _profile(tmp_path, "roll12", 12)
    with live_bench(tmp_path, clock=vclock) as b:
        plan = _plan(tmp_path, [
            {"name": "tight", "profile": str(roll), "limits": {"sigma_deg": 0.01},
             "on_fail": "stop"},
            {"name": "never", "profile": str(roll)},
        ])
        res = run_plan(plan, serial=SERIAL, config=b.config_path, yes=True, clock=vclock,
                       junit=tmp_path / "fail.xml")
        at_rest = b.stand_at_rest()
    assert (res.outcome, res.exit_code) == ("FAIL", 1), res.reason
    assert [s.status for s in res.steps] == ["FAIL", "SKIPPED"]
    assert "on_fail: stop" in res.steps[1].reason
    assert [a.status for a in res.cleanup] == ["ok"] and at_rest
    rec = load_record(res.steps[0].record_path or "")
    sigma = next(m for m in rec["measurements"] if m["name"] == "sigma")
    assert (sigma["high"], sigma["outcome"]) == (0.01, "FAIL") and rec["exit_code"] == 1
    xml = JUnitXml.fromfile(str(tmp_path / "fail.xml"))
    suites = {s.name: s for s in xml}
    sig = next(c for c in suites["tight"] if c.name == "roll: sigma")
    assert [type(r) for r in sig.result] == [Failure]
    assert sig.result[0].type == "FAIL"
    assert [type(r) for c in suites["never"] for r in c.result] == [Skipped]
    assert (xml.failures, xml.errors) == (1, 0)
    # the summary: a line per step, the judged measurements under it, then the outcome
    text = summary(res).splitlines()
    assert text[1].split()[:2] == ["FAIL", "tight"]
    assert any(line.split()[:5] == ["FAIL", "roll", "sigma", "=", f"{sigma['value']:.4g}"]
               for line in text)
    assert any(line.split()[:2] == ["SKIPPED", "never"] for line in text)
    assert text[-3].split()[:3] == ["FAIL", "exit", "1"]
    assert text[-2:] == [f"plan record {res.record_path}", f"JUnit XML {res.junit}"]


def test_a_fault_mid_plan_aborts_the_step_runs_cleanup_and_exits_2(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    roll = _profile(tmp_path, "roll12", 12)
    out = tmp_path / "runs"
    with live_bench(tmp_path, clock=vclock) as b:
        plan = _plan(tmp_path, [
            {"name": "first", "profile": str(roll), "on_fail": "continue"},
            {"name": "faulted", "profile": str(roll), "on_fail": "continue"},
            {"name": "after", "profile": str(roll)},
        ], setup=[{"check": "stand_at_rest"}])
        with _when_step_moves(out, lambda: b.instrument.inject("silent"),
                              clock=vclock) as injected:
            res: PlanResult = run_plan(plan, serial=SERIAL, config=b.config_path, yes=True,
                                       clock=vclock, out_dir=out, junit=tmp_path / "fault.xml")
        assert injected.is_set()
        at_rest = b.stand_at_rest()
    assert (res.outcome, res.exit_code) == ("ABORTED", 2)
    assert [s.status for s in res.steps] == ["PASS", "ABORTED", "SKIPPED"]
    faulted = res.steps[1]
    assert faulted.abort is not None and faulted.abort["kind"] == "equipment"
    assert not faulted.timed_out
    assert "faulted" in res.reason
    # the aborted run's record is stored, ABORTED, valid
    rec = load_record(faulted.record_path or "")
    assert rec["outcome"] == "ABORTED" and rec["abort"]["kind"] == "equipment"
    assert (Path(faulted.recording or "") / "end.json").is_file()
    # cleanup ran and brought the stand to rest
    assert [a.status for a in res.cleanup] == ["ok"] and at_rest
    xml = JUnitXml.fromfile(str(tmp_path / "fault.xml"))
    suites = {s.name: s for s in xml}
    run_case = next(c for c in suites["faulted"] if c.name == "run")
    assert [type(r) for r in run_case.result] == [Error]
    assert run_case.result[0].type == "ABORTED"
    assert "equipment" in (run_case.result[0].message or "")
    assert (suites["faulted"].errors, suites["first"].errors, suites["first"].failures) == (
        1, 0, 0)
    assert [type(r) for c in suites["after"] for r in c.result] == [Skipped]
    assert xml.errors == 1
    assert load_plan_record(res.record_path or "")["steps"][1]["record"] == rec


def test_a_step_timeout_ends_the_step_through_the_abort_path(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    long_roll = _profile(tmp_path, "roll60", 60)
    with live_bench(tmp_path, clock=vclock) as b:
        plan = _plan(tmp_path, [{"name": "slow", "profile": str(long_roll), "timeout_s": 12}])
        res = run_plan(plan, serial=SERIAL, config=b.config_path, yes=True, clock=vclock)
        at_rest = b.stand_at_rest()
    assert (res.outcome, res.exit_code) == ("ABORTED", 2)
    step = res.steps[0]
    assert step.status == "ABORTED" and step.timed_out
    assert "its timeout_s (12 s) ran out" in step.reason
    rec = load_record(step.record_path or "")
    assert rec["outcome"] == "ABORTED" and "timeout_s (12 s)" in rec["abort"]["reason"]
    end = json.loads((Path(step.recording or "") / "end.json").read_text())
    assert end["state"] == "aborted"
    assert [a.status for a in res.cleanup] == ["ok"] and at_rest


def test_the_plan_timeout_ends_the_running_step_and_skips_the_rest(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    long_roll = _profile(tmp_path, "roll60", 60)
    with live_bench(tmp_path, clock=vclock) as b:
        plan = _plan(tmp_path, [{"name": "slow", "profile": str(long_roll)},
                                {"name": "next", "profile": str(long_roll)}], timeout_s=12)
        res = run_plan(plan, serial=SERIAL, config=b.config_path, yes=True, clock=vclock)
        at_rest = b.stand_at_rest()
    assert (res.outcome, res.exit_code) == ("ABORTED", 2) and res.timed_out
    assert [s.status for s in res.steps] == ["ABORTED", "SKIPPED"]
    assert res.steps[0].timed_out
    assert "the plan's timeout_s (12 s) ran out" in res.steps[0].reason
    rec = load_record(res.steps[0].record_path or "")
    assert rec["outcome"] == "ABORTED"
    assert [a.status for a in res.cleanup] == ["ok"] and at_rest


@pytest.mark.realtime  # a real SIGINT to this process (the "Ctrl-C in a plan")
def test_ctrl_c_during_a_step_stops_the_plan_and_cleanup_still_runs(tmp_path: Path) -> None:
    """SIGINT while the first step moves: the run takes it (the stand brought to rest, the
    record ABORTED by the operator), the plan stops there and its cleanup runs. The run's own
    side of it (a real SIGINT mid-motion on the host's time: the one cleanup path, every step
    of it, the recording closed ``aborted`` and readable, the handler there before given back)
    is checked here too: that was tests/unit/run/test_run_session.py's one real-time test."""
    from benchctl.evaluate import analyze_recording
    from benchctl.recording import load_recording

    roll = _profile(tmp_path, "roll20", 20)
    out = tmp_path / "runs"
    before = signal.getsignal(signal.SIGINT)
    # about the signal: the mounting check's tilt and the host check left out (FOCUSED)
    with live_bench(tmp_path, run=FOCUSED) as b:
        plan = _plan(tmp_path, [{"name": "one", "profile": str(roll), "on_fail": "continue"},
                                {"name": "two", "profile": str(roll)}])
        with _when_step_moves(out, lambda: os.kill(os.getpid(), signal.SIGINT), nth=1) as sent:
            res = run_plan(plan, serial=SERIAL, config=b.config_path, yes=True, out_dir=out)
        assert sent.is_set()
        at_rest = b.stand_at_rest()
    assert (res.outcome, res.exit_code) == ("ABORTED", 2) and res.interrupted
    assert [s.status for s in res.steps] == ["ABORTED", "SKIPPED"]
    step = res.steps[0]
    assert step.abort is not None and step.abort["kind"] == "operator"
    assert "interrupted by SIGINT" in step.reason
    assert load_record(step.record_path or "")["abort"]["kind"] == "operator"
    assert [a.status for a in res.cleanup] == ["ok"] and at_rest
    # the run's one cleanup path, every step of it, the stand left disabled
    steps = {s["step"]: s for s in step.abort["shutdown"]}
    for name in ("stop loops", "ramp to zero", "disable", "read final state", "stop instrument",
                 "record shutdown", "close recording", "close stand", "close instrument"):
        assert steps[name]["ok"], (name, step.abort["shutdown"])
    assert "(servo off" in steps["final angle"]["detail"], steps["final angle"]
    # the recording: closed aborted with the signal's reason, moving when it came, readable
    rec = load_recording(step.recording or "")
    assert rec.state == "aborted" and rec.end is not None
    assert "interrupted by SIGINT" in rec.end["reason"]
    assert [e["to"] for e in rec.events if e["kind"] == "state"][-1] == "aborted"
    assert rec.end["stats"]["setpoints_sent"] > 50
    assert math.isfinite(analyze_recording(rec.path, "roll").sigma)
    assert signal.getsignal(signal.SIGINT) is before  # the run gave its handler back
