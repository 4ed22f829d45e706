"""A plan's result as JUnit XML (``xml.etree``), for the tools of a production line or CI.

::

    <testsuites name=PLAN tests failures errors skipped time>
      <testsuite name="setup" …>      one <testcase> per setup action (if any)
      <testsuite name=STEP …>         one per step, in the plan's order
        <properties>                  serial, operator, status, recording, record, profile
        <testcase classname="PLAN.STEP" name="roll: sigma" time="26.1">
          <properties>                                 the NOT_JUDGED measurements with it
            <property name="roll: delay" value="0.0903 s (not judged: no limit)"/>
          </properties>
          <failure type="FAIL" message="…"/>           a decisive measurement FAILed
          <failure type="INCONCLUSIVE" message="…"/>   guarded rule: its interval straddles
          <system-out>PASS: …</system-out>             passed (and the properties in words)
        </testcase>
        …                             one <testcase> per judged measurement of the record
        <testcase name="run"><error type="ABORTED" …/></testcase>   an aborted step
        <testcase name="run"><error type="ERROR" …/></testcase>     a step that could not start
        <testcase name="run"><skipped …/></testcase>                a step not run
      <testsuite name="cleanup" …>    one <testcase> per cleanup action (if any)

Every attribute and text is readable XML 1.0 whatever a serial, an operator or a device
reported: a character XML forbids (a control character) is written as a visible escape
(``\x1b``, ``benchctl.text.for_xml``).

An informative measurement (the serial match, the excitation fidelity: ``decisive`` false)
never fails its test case: its outcome is in the case's ``<system-out>``. A measurement NOT
judged (no limit: the mean error, the delay, a phase; a period the profile does not excite) is
no test case of its own and never a skipped test: it is a ``<property>`` of the judged
measurement it goes with (a phase with the gain at its period, the rest with the axis's σ).
Every test case carries its real time (``_timings``): a precheck its own, what the motion
measured the motion's and its analysis's, a setup or cleanup action its own. A setup or cleanup
action that failed is an ``<error>``, as is a prompt interrupted by a signal (type
INTERRUPTED) or a setup prompt left unanswered (UNANSWERED: its input ended or its time ran
out); a prompt answered no in the setup a ``<failure>``; an action skipped a ``<skipped>``.
"""

from __future__ import annotations

import io
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchctl.fileout import atomic_write_bytes
from benchctl.outcomes import Outcome
from benchctl.text import for_xml

if TYPE_CHECKING:
    from benchctl.plan.result import ActionResult, PlanResult, StepResult


def _num(v: Any) -> str:
    if isinstance(v, bool) or v is None:
        return str(v)
    if isinstance(v, float):
        return f"{v:.6g}" if math.isfinite(v) else "nan"
    return str(v)


def _limits(m: dict[str, Any]) -> str:
    lo, hi = m.get("low"), m.get("high")
    unit = f" {m['unit']}" if m.get("unit") not in (None, "1") else ""
    if lo is not None and hi is not None:
        return f"[{_num(lo)}, {_num(hi)}]{unit}"
    if hi is not None:
        return f"≤ {_num(hi)}{unit}"
    if lo is not None:
        return f"≥ {_num(lo)}{unit}"
    return "no limit"


def _case_name(m: dict[str, Any]) -> str:
    return f"{m['axis']}: {m['name']}" if m.get("axis") else str(m["name"])


def _text(m: dict[str, Any]) -> str:
    """A measurement in words: its value, limits, rule, interval and note."""
    unit = f" {m['unit']}" if m.get("unit") not in (None, "1") else ""
    if m.get("rule") == "check":  # a precheck or the serial match: passed or not, and why
        text = f"{_case_name(m)}: {m.get('note') or m.get('value')}"
    else:
        text = (f"{_case_name(m)} = {_num(m.get('value'))}{unit}, limits {_limits(m)}, "
                f"rule {m.get('rule')}")
    if m.get("ci95") is not None:
        text += f", 95 % interval [{_num(m['ci95'][0])}, {_num(m['ci95'][1])}]"
    if m.get("note") and m.get("rule") != "check":
        text += f" ({m['note']})"
    return text


def _measurement_case(parent: ET.Element, classname: str, m: dict[str, Any], seconds: float,
                      extra: list[dict[str, Any]]) -> str:
    """One <testcase> taking ``seconds``, with the NOT_JUDGED measurements ``extra`` that go
    with it as its properties; returns its kind: pass | failure | skipped."""
    case = ET.SubElement(parent, "testcase", classname=classname, name=_case_name(m),
                         time=f"{seconds:.3f}")
    if extra:
        props = ET.SubElement(case, "properties")
        for x in extra:
            ET.SubElement(props, "property", name=_case_name(x), value=_not_judged(x))
    text = _text(m)
    outcome = m.get("outcome")
    if not m.get("decisive") and outcome in (Outcome.FAIL, Outcome.INCONCLUSIVE):
        ET.SubElement(case, "system-out").text = f"informative, {outcome}: {text}"
        return "pass"
    if outcome in (Outcome.FAIL, Outcome.INCONCLUSIVE):
        ET.SubElement(case, "failure", type=str(outcome), message=f"{outcome}: {text}")
        return "failure"
    if outcome == Outcome.NOT_JUDGED:  # only when no judged measurement could take it along
        ET.SubElement(case, "system-out").text = f"NOT_JUDGED: {text}"
        return "pass"
    out = [f"{outcome}: {text}"] + [f"NOT_JUDGED: {_text(x)}" for x in extra]
    ET.SubElement(case, "system-out").text = "\n".join(out)
    return "pass"


def _not_judged(m: dict[str, Any]) -> str:
    """A NOT_JUDGED measurement as a property's value: its value and unit, or why none."""
    unit = f" {m['unit']}" if m.get("unit") not in (None, "1") else ""
    v = m.get("value")
    shown = (f"{_num(v)}{unit}" if v is not None else "not measured") + (
        f", 95 % interval [{_num(m['ci95'][0])}, {_num(m['ci95'][1])}]"
        if m.get("ci95") is not None else "")
    why = m.get("note") or ("no limit" if m.get("low") is None and m.get("high") is None
                            else "")
    return f"{shown} (not judged: {why})" if why else f"{shown} (not judged)"


def _period(name: str) -> str | None:
    """``gain at 5 s`` → ``5 s``: the period a gain or phase measurement belongs to."""
    return name.split(" at ", 1)[1] if " at " in name else None


def _host(m: dict[str, Any], judged: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The judged measurement a NOT_JUDGED one goes with: the same axis and period (a phase
    with its gain), else the same axis's σ, else its first judged measurement; one of no axis,
    the step's first judged measurement that is not a precheck. None when there is none (an
    axis with nothing judged: the measurement keeps a passing case of its own)."""
    same_axis = [j for j in judged if j.get("axis") == m.get("axis")]
    period = _period(str(m["name"]))
    for j in same_axis:
        if period is not None and _period(str(j["name"])) == period:
            return j
    for j in same_axis:
        if j["name"] == "sigma":
            return j
    if same_axis or m.get("axis"):
        return same_axis[0] if same_axis else None
    return next((j for j in judged if not str(j["name"]).startswith("precheck: ")), None)


def _timings(s: StepResult) -> dict[str, float]:
    """Seconds per measurement of a step, from its recording's events (``events.jsonl``):
    a precheck from the one before it (the first from the step's start); the serial match
    as the instrument's identity check; everything the motion measured (σ, gains, spreads,
    the excitation) the motion and its analysis, from the last precheck to the verdict — the
    time it took to measure them, the same for each. Without the events, the step's whole
    time for what the motion measured."""

    out: dict[str, float] = {}
    events: list[dict[str, Any]] = []
    path = None if s.recording is None else Path(s.recording) / "events.jsonl"
    try:
        if path is not None:
            with open(path, encoding="utf-8") as f:
                for line in f:
                    try:
                        e = json.loads(line)
                    except ValueError:
                        continue  # a torn last line: the events before it still count
                    if isinstance(e, dict) and isinstance(e.get("t_host"), int | float):
                        events.append(e)
    except OSError:
        events = []
    if not events:
        return {"motion": max(0.0, s.duration_s)}
    t_prev = float(events[0]["t_host"])
    for e in events:
        if e.get("kind") == "precheck":
            t = float(e["t_host"])
            out[f"precheck: {e.get('name')}"] = max(0.0, t - t_prev)
            t_prev = t
    out["serial match"] = out.get("precheck: instrument answers", 0.0)
    ends = [float(e["t_host"]) for e in events if e.get("kind") == "verdict"]
    t_end = ends[-1] if ends else float(events[-1]["t_host"])
    out["motion"] = max(0.0, t_end - t_prev)
    return out


def _suite(root: ET.Element, name: str, timestamp: str | None, seconds: float) -> ET.Element:
    s = ET.SubElement(root, "testsuite", name=name, time=f"{seconds:.3f}")
    if timestamp:
        s.set("timestamp", timestamp[:19])
    return s


def _count(suite: ET.Element, kinds: list[str]) -> dict[str, int]:
    c = {"tests": len(kinds), "failures": kinds.count("failure"), "errors": kinds.count("error"),
         "skipped": kinds.count("skipped")}
    for k, v in c.items():
        suite.set(k, str(v))
    return c


def _props(suite: ET.Element, items: dict[str, Any]) -> None:
    props = ET.SubElement(suite, "properties")
    for k, v in items.items():
        if v is not None:
            ET.SubElement(props, "property", name=k, value=str(v))


def _actions(root: ET.Element, plan: str, phase: str, actions: list[ActionResult]) -> list[str]:
    if not actions:
        return []
    suite = _suite(root, phase, None, sum(a.duration_s for a in actions))
    kinds = []
    for a in actions:
        label = " + ".join(x for x in (f"prompt {a.prompt!r}" if a.prompt else None,
                                       a.check) if x)
        case = ET.SubElement(suite, "testcase", classname=f"{plan}.{phase}",
                             name=f"{a.index + 1}: {label}", time=f"{a.duration_s:.3f}")
        if a.status == "failed":
            ET.SubElement(case, "error", type=Outcome.ERROR, message=a.detail)
            kinds.append("error")
        elif a.status == "interrupted" or (a.status == "unanswered" and phase == "setup"):
            ET.SubElement(case, "error", type=a.status.upper(), message=a.detail)
            kinds.append("error")
        elif a.status in ("declined", "unanswered"):
            if phase == "setup":
                ET.SubElement(case, "failure", type="DECLINED", message=a.detail)
                kinds.append("failure")
            else:  # a cleanup prompt answered no (or not at all) is a note, not a failure
                ET.SubElement(case, "system-out").text = a.detail
                kinds.append("pass")
        elif a.status == "skipped":
            ET.SubElement(case, "skipped", message=a.detail)
            kinds.append("skipped")
        else:
            if a.detail:
                ET.SubElement(case, "system-out").text = a.detail
            kinds.append("pass")
    _count(suite, kinds)
    return kinds


def _step(root: ET.Element, result: PlanResult, s: StepResult) -> list[str]:
    suite = _suite(root, s.name, s.start_utc, s.duration_s)
    _props(suite, {"plan": result.name, "serial": result.serial, "operator": result.operator,
                   "status": s.status, "profile": s.profile, "recording": s.recording,
                   "record": s.record_path, "timed_out": s.timed_out or None})
    classname = f"{result.name}.{s.name}"
    ms = s.measurements
    judged = [m for m in ms if m.get("outcome") != Outcome.NOT_JUDGED]
    along: dict[int, list[dict[str, Any]]] = {id(j): [] for j in judged}
    alone = set()  # NOT_JUDGED with no judged measurement to go with: a case of its own
    for m in ms:
        if m.get("outcome") == Outcome.NOT_JUDGED:
            host = _host(m, judged)
            if host is None:
                alone.add(id(m))
            else:
                along[id(host)].append(m)
    times = _timings(s)

    def seconds(m: dict[str, Any]) -> float:
        name = _case_name(m)
        return times.get(name, 0.0 if name.startswith("precheck: ") else times["motion"])

    kinds = [_measurement_case(suite, classname, m, seconds(m), along.get(id(m), []))
             for m in ms if m.get("outcome") != Outcome.NOT_JUDGED or id(m) in alone]
    if s.status in (Outcome.ABORTED, Outcome.ERROR, Outcome.SKIPPED):
        case = ET.SubElement(suite, "testcase", classname=classname, name="run",
                             time=f"{s.duration_s:.3f}")
        if s.status == Outcome.SKIPPED:
            ET.SubElement(case, "skipped", message=s.reason)
            kinds.append("skipped")
        else:
            kind = (s.abort or {}).get("kind")
            msg = f"{s.status}: {s.reason}" + (f" ({kind})" if kind else "")
            ET.SubElement(case, "error", type=s.status, message=msg)
            kinds.append("error")
    _count(suite, kinds)
    return kinds


def junit_tree(result: PlanResult) -> ET.ElementTree[ET.Element]:
    """The JUnit XML of a plan result (see the module notes)."""
    root = ET.Element("testsuites", name=result.name, time=f"{result.duration_s:.3f}")
    kinds = _actions(root, result.name, "setup", result.setup)
    for s in result.steps:
        kinds += _step(root, result, s)
    kinds += _actions(root, result.name, "cleanup", result.cleanup)
    _count(root, kinds)
    _xml_safe(root)
    ET.indent(root)
    return ET.ElementTree(root)


def _xml_safe(root: ET.Element) -> None:
    """Every attribute and text made readable XML 1.0 (``benchctl.text.for_xml``): a serial,
    an operator, a device's identity or a reason with a control character in it (an ESC, a
    barcode scanner's GS) is shown as an escape (``\x1d``); xml.etree would write it as it is
    and no parser could read the file back."""
    for el in root.iter():
        for k, v in el.attrib.items():
            el.set(k, for_xml(v))
        if el.text is not None:
            el.text = for_xml(el.text)


def write_junit(result: PlanResult, path: Path) -> Path:
    """Write the JUnit XML to ``path`` (UTF-8, written whole: a temporary file renamed over
    it, removed when the write fails — a full disk leaves no half file behind)."""
    tree = junit_tree(result)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    tree.write(buf, encoding="utf-8", xml_declaration=True)
    atomic_write_bytes(path, buf.getvalue())
    return path


__all__ = ["junit_tree", "write_junit"]
