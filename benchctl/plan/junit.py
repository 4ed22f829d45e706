"""A plan's result as JUnit XML (``xml.etree``), for the tools of a production line or CI.

::

    <testsuites name=PLAN tests failures errors skipped time>
      <testsuite name="setup" …>      one <testcase> per setup action (if any)
      <testsuite name=STEP …>         one per step, in the plan's order
        <properties>                  serial, operator, status, recording, record, profile
        <testcase classname="PLAN.STEP" name="roll: sigma" time="0">
          <failure type="FAIL" message="…"/>           a decisive measurement FAILed
          <failure type="INCONCLUSIVE" message="…"/>   guarded rule: its interval straddles
          <skipped message="NOT_JUDGED: …"/>           no limit, or a period not excited
        </testcase>
        …                             one <testcase> per measurement of the step's record
        <testcase name="run"><error type="ABORTED" …/></testcase>   an aborted step
        <testcase name="run"><error type="ERROR" …/></testcase>     a step that could not start
        <testcase name="run"><skipped …/></testcase>                a step not run
      <testsuite name="cleanup" …>    one <testcase> per cleanup action (if any)

Every attribute and text is readable XML 1.0 whatever a serial, an operator or a device
reported: a character XML forbids (a control character) is written as a visible escape
(``\x1b``, ``benchctl.text.for_xml``).

An informative measurement (the serial match, the excitation fidelity: ``decisive`` false)
never fails its test case: its outcome is in the case's ``<system-out>``. A setup or cleanup
action that failed is an ``<error>``, as is a prompt interrupted by a signal (type
INTERRUPTED) or a setup prompt left unanswered (UNANSWERED: its input ended or its time ran
out); a prompt answered no in the setup a ``<failure>``; an action skipped a ``<skipped>``.
"""

from __future__ import annotations

import io
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchctl.fileout import atomic_write_bytes
from benchctl.text import for_xml

if TYPE_CHECKING:
    from benchctl.plan.runner import ActionResult, PlanResult, StepResult


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


def _measurement_case(parent: ET.Element, classname: str, m: dict[str, Any]) -> str:
    """One <testcase>; returns its kind: pass | failure | skipped."""
    case = ET.SubElement(parent, "testcase", classname=classname, name=_case_name(m), time="0")
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
    outcome = m.get("outcome")
    if not m.get("decisive") and outcome in ("FAIL", "INCONCLUSIVE"):
        ET.SubElement(case, "system-out").text = f"informative, {outcome}: {text}"
        return "pass"
    if outcome in ("FAIL", "INCONCLUSIVE"):
        ET.SubElement(case, "failure", type=str(outcome), message=f"{outcome}: {text}")
        return "failure"
    if outcome == "NOT_JUDGED":
        ET.SubElement(case, "skipped", message=f"NOT_JUDGED: {text}")
        return "skipped"
    ET.SubElement(case, "system-out").text = f"{outcome}: {text}"
    return "pass"


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
    suite = _suite(root, phase, None, 0.0)
    kinds = []
    for a in actions:
        label = " + ".join(x for x in (f"prompt {a.prompt!r}" if a.prompt else None,
                                       a.check) if x)
        case = ET.SubElement(suite, "testcase", classname=f"{plan}.{phase}",
                             name=f"{a.index + 1}: {label}", time="0")
        if a.status == "failed":
            ET.SubElement(case, "error", type="ERROR", message=a.detail)
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
    kinds = [_measurement_case(suite, classname, m) for m in s.measurements]
    if s.status in ("ABORTED", "ERROR", "SKIPPED"):
        case = ET.SubElement(suite, "testcase", classname=classname, name="run",
                             time=f"{s.duration_s:.3f}")
        if s.status == "SKIPPED":
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
