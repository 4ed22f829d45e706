"""The JUnit XML of ``benchctl plan`` (``benchctl.plan.junit``): a measurement not judged (no
limit, a period not excited) is a property of the judged test case it goes with, never a
skipped test (a green run had 18 skipped); every test case carries its real time, from the
step's recorded events (a precheck its own, what the motion measured the motion's) and the
action's own time for setup and cleanup (every case had time 0)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from junitparser import JUnitXml, Properties, Skipped

from benchctl.plan.junit import write_junit
from benchctl.plan.runner import ActionResult, PlanResult, StepResult


def _m(name: str, axis: str | None, value: Any, outcome: str, *, high: float | None = None,
       rule: str = "simple", unit: str | None = "deg", note: str | None = None,
       decisive: bool = True, ci95: list[float] | None = None) -> dict[str, Any]:
    return {"name": name, "axis": axis, "value": value, "unit": unit, "low": None, "high": high,
            "ci95": ci95, "outcome": outcome, "rule": rule, "decisive": decisive, "note": note}


MEASUREMENTS = [
    _m("precheck: stand answers", None, True, "PASS", rule="check", unit=None, note="SIM"),
    _m("precheck: instrument answers", None, True, "PASS", rule="check", unit=None,
       note="SIM-INCL"),
    _m("precheck: instrument streams", None, True, "PASS", rule="check", unit=None,
       note="100 Hz"),
    _m("sigma", "roll", 0.31, "PASS", high=0.4, ci95=[0.3, 0.32]),
    _m("mean error", "roll", 0.05, "NOT_JUDGED"),
    _m("delay", "roll", 0.09, "NOT_JUDGED", unit="s"),
    _m("gain at 3 s", "roll", 0.98, "PASS", unit=None, high=1.01),
    _m("phase at 3 s", "roll", -10.6, "NOT_JUDGED", ci95=[-11.0, -10.2]),
    _m("gain at 7 s", "roll", None, "NOT_JUDGED", unit=None, high=1.01,
       note="not excited by the profile"),
    _m("delay", "pitch", 0.1, "NOT_JUDGED", unit="s"),  # no judged pitch measurement
    _m("serial match", None, True, "PASS", rule="check", unit=None, decisive=False,
       note="typed 'SN', instrument reports 'SN'"),
]


def _events(folder: Path) -> Path:
    """A recording's events: prechecks from 10.0 s to 11.5 s, motion from 11.6 s, the
    verdict at 41.5 s."""
    folder.mkdir(parents=True)
    ev = [{"t_host": 10.0, "kind": "state", "from": "idle", "to": "prechecks"},
          {"t_host": 10.2, "kind": "precheck", "name": "stand answers", "ok": True},
          {"t_host": 10.5, "kind": "precheck", "name": "instrument answers", "ok": True},
          {"t_host": 11.5, "kind": "precheck", "name": "instrument streams", "ok": True},
          {"t_host": 11.6, "kind": "motion_start"},
          {"t_host": 41.5, "kind": "verdict", "verdict": "PASS"}]
    (folder / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in ev))
    return folder


def _result(tmp_path: Path, recording: Path | None) -> PlanResult:
    r = PlanResult("p", None, "SN", "ana", None, duration_s=33.0)
    r.setup.append(ActionResult("setup", 0, "Clear?", "stand_at_rest", "ok", "at rest",
                                duration_s=2.5))
    r.steps.append(StepResult("dyn", "p.yaml", "PASS", duration_s=32.0, recording=recording,
                              record={"measurements": MEASUREMENTS}))
    r.cleanup.append(ActionResult("cleanup", 0, None, "ramp_to_zero", "ok", "at zero",
                                  duration_s=0.75))
    return r


def _props(case: Any) -> dict[str, str]:
    return {p.name: p.value for ps in case.iterchildren(Properties) for p in ps}


def test_not_judged_measurements_are_properties_never_skipped(tmp_path: Path) -> None:
    path = write_junit(_result(tmp_path, _events(tmp_path / "rec")), tmp_path / "j.xml")
    xml = JUnitXml.fromfile(str(path))
    assert (xml.tests, xml.failures, xml.errors, xml.skipped) == (9, 0, 0, 0)
    suites = {s.name: s for s in xml}
    cases = {c.name: c for c in suites["dyn"]}
    assert list(cases) == ["precheck: stand answers", "precheck: instrument answers",
                           "precheck: instrument streams", "roll: sigma", "roll: gain at 3 s",
                           "pitch: delay", "serial match"]
    assert not any(isinstance(r, Skipped) for c in cases.values() for r in c.result)
    assert _props(cases["roll: sigma"]) == {
        "roll: mean error": "0.05 deg (not judged: no limit)",
        "roll: delay": "0.09 s (not judged: no limit)",
        "roll: gain at 7 s": "not measured (not judged: not excited by the profile)",
    }
    assert _props(cases["roll: gain at 3 s"]) == {
        "roll: phase at 3 s": "-10.6 deg, 95 % interval [-11, -10.2] (not judged: no limit)"}
    # said in words too, under the judged measurement's own outcome
    out = cases["roll: sigma"].system_out or ""
    assert out.splitlines()[0].startswith("PASS: roll: sigma = 0.31 deg")
    assert "NOT_JUDGED: roll: delay = 0.09 s, limits no limit" in out
    # a NOT_JUDGED measurement with nothing judged on its axis keeps a case, passed
    assert list(cases["pitch: delay"].result) == []
    assert (cases["pitch: delay"].system_out or "").startswith("NOT_JUDGED: pitch: delay")
    assert _props(cases["serial match"]) == {}


def test_every_case_has_its_real_time(tmp_path: Path) -> None:
    path = write_junit(_result(tmp_path, _events(tmp_path / "rec")), tmp_path / "j.xml")
    xml = JUnitXml.fromfile(str(path))
    suites = {s.name: s for s in xml}
    times = {c.name: c.time for c in suites["dyn"]}
    assert times["precheck: stand answers"] == 0.2
    assert times["precheck: instrument answers"] == 0.3
    assert times["precheck: instrument streams"] == 1.0
    assert times["roll: sigma"] == times["roll: gain at 3 s"] == 30.0  # 11.5 → the verdict
    assert times["pitch: delay"] == 30.0
    assert times["serial match"] == 0.3  # the instrument's identity, read when it answered
    assert [c.time for c in suites["setup"]] == [2.5] and suites["setup"].time == 2.5
    assert [c.time for c in suites["cleanup"]] == [0.75] and suites["cleanup"].time == 0.75
    assert suites["dyn"].time == 32.0


def test_without_the_events_what_the_motion_measured_takes_the_step_time(
    tmp_path: Path,
) -> None:
    path = write_junit(_result(tmp_path, tmp_path / "gone"), tmp_path / "j.xml")
    times = {c.name: c.time for s in JUnitXml.fromfile(str(path)) if s.name == "dyn" for c in s}
    assert times["roll: sigma"] == 32.0 and times["precheck: stand answers"] == 0.0
