"""The operator's terminal: the live block fits 80 columns and never scrolls,
shows serial and operator, the limit beside the running σ, the stand's health with a warning as
it climbs, and a final banner with the verdict; log lines without a terminal as before;
``benchctl analyze`` says when a recording is aborted or incomplete (text and JSON)."""

from __future__ import annotations

import dataclasses
import io
import json
import math
import re
import shutil
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from run_fakes import FakeSensor, FakeStand, bench_config, sine_motion

from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.run.display import (
    WIDTH,
    LogDisplay,
    SafeDisplay,
    Snapshot,
    TtyDisplay,
    format_block,
    health_warning,
)
from benchctl.run.prepare import RunOptions
from benchctl.run.session import Session

ANSI = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
LONG_SERIAL = "SN-" + "9" * 60
LONG_OPERATOR = "Operator With A Very Long Name Indeed"


def _screen(text: str) -> list[str]:
    """What a terminal shows line by line (escapes removed)."""
    return [ANSI.sub("", ln) for ln in text.split("\n")]


def _snap(**kw: object) -> Snapshot:
    base: dict[str, object] = dict(
        state="running", elapsed_s=65.0, remaining_s=1200.0,
        stand_deg={"roll": -12.345, "pitch": 3.21}, instrument_deg={"roll": -12.3, "pitch": 3.2},
        tracking_error_deg={"roll": 0.012, "pitch": -0.004},
        sigma_deg={"roll": 0.2831, "pitch": 0.101}, missed_cycles=3, instrument_samples=123456,
        serial=LONG_SERIAL, operator=LONG_OPERATOR, limit_deg=0.4, cycles=6500, rejoins=0)
    base.update(kw)
    return Snapshot(**base)  # type: ignore[arg-type]


def test_live_block_fits_80_columns_and_shows_who_limit_health() -> None:
    buf = io.StringIO()
    d = TtyDisplay(buf, fps=1e9, width=80)
    d.update(_snap())
    d.message("precheck stand at zero: ok — " + "y " * 50 + "x" * 120)
    d.update(_snap(missed_cycles=4))
    lines = [ln for ln in _screen(buf.getvalue()) if ln]
    # a message wrapped at words; a word longer than the line whole on its own (the terminal
    # folds it), never cut
    assert any(ln.strip() == "x" * 120 for ln in lines)
    assert max(len(ln) for ln in lines if "x" * 120 not in ln) <= 80
    text = "\n".join(lines)
    assert "serial SN-999" in text and "operator" in text  # cut to fit, still there
    sigma = next(ln for ln in lines if "σ (running est.)" in ln)
    assert "0.283°" in sigma and "limit 0.4°" in sigma
    health = next(ln for ln in lines if "health" in ln)
    assert "missed cycles 3" in health and "rejoins 0" in health
    assert "WARNING" not in text
    # the block is redrawn in place: the cursor goes up by the lines it drew, every time
    block = format_block(_snap())
    ups = re.findall(r"\x1b\[(\d+)F", buf.getvalue())
    assert ups and {int(n) for n in ups} == {len(block)}


def test_health_warning_as_it_climbs() -> None:
    assert health_warning(_snap()) == ""
    assert "missed 1.5 % of cycles" in health_warning(_snap(missed_cycles=100, cycles=6500))
    assert "+12 missed cycles" in health_warning(_snap(missed_cycles=15), previous_missed=3)
    assert health_warning(_snap(missed_cycles=15), previous_missed=10) == ""
    assert "2 rejoin(s)" in health_warning(_snap(rejoins=2))
    buf = io.StringIO()
    d = TtyDisplay(buf, fps=1e9, width=80)
    d.update(_snap(missed_cycles=3))
    d.update(_snap(missed_cycles=40))  # +37 since the last drawing
    last = _screen(buf.getvalue())[-2]
    assert last.strip().startswith("WARNING stand health: +37 missed cycles"), last
    d.update(_snap(missed_cycles=41))  # the climb stopped: the warning stays up a while
    assert "WARNING" in _screen(buf.getvalue())[-2]
    assert all(len(ln) <= 80 for ln in _screen(buf.getvalue()))


def test_health_warning_only_when_the_motion_is_touched() -> None:
    """Buffered and table modes play on the stand's clock: missed polls are a count on the
    health line, never a warning; an underrun or a rejoin is, in any mode."""
    for mode in ("buffered", "table"):
        many = _snap(mode=mode, missed_cycles=400, cycles=6500)
        assert health_warning(many) == ""
        assert health_warning(many, previous_missed=3) == ""
        health = next(ln for ln in format_block(many) if "health" in ln)
        assert "missed polls 400" in health and "missed cycles" not in health
        assert "1 underrun(s)" in health_warning(_snap(mode=mode, underruns=1))
        assert "2 rejoin(s)" in health_warning(_snap(mode=mode, rejoins=2))
    stream = _snap(mode="stream", missed_cycles=400, cycles=6500)
    assert "missed 6.2 % of cycles" in health_warning(stream)
    assert "missed cycles 400" in next(ln for ln in format_block(stream) if "health" in ln)
    # on the screen: a buffered run's missed polls climbing leave no warning up
    buf = io.StringIO()
    d = TtyDisplay(buf, fps=1e9, width=80)
    d.update(_snap(mode="buffered", missed_cycles=3))
    d.update(_snap(mode="buffered", missed_cycles=400))
    assert "WARNING" not in buf.getvalue()
    assert "missed polls 400" in _screen(buf.getvalue())[-3]
    d.update(_snap(mode="buffered", missed_cycles=400, underruns=1))
    assert "WARNING stand health: 1 underrun(s)" in _screen(buf.getvalue())[-2]
    assert "underruns 1" in _screen(buf.getvalue())[-3]


def test_running_sigma_settles_before_it_is_judged() -> None:
    """The running σ is an estimate: "settling" (no value beside the limit) until the fade-in
    and one whole period are over, then its values against the limit; never judged without a
    period."""
    from benchctl.run.display import sigma_judgement, sigma_text

    early = _snap(elapsed_s=30.0, sigma_judged_after_s=62.5, sigma_deg={"roll": 0.61})
    assert sigma_judgement(early) == "settling"
    text = sigma_text(early)
    assert "settling" in text and "00:32 to go" in text and "0.61" not in text
    assert "σ (running est.)" in text
    ok = _snap(elapsed_s=70.0, sigma_judged_after_s=62.5)
    assert sigma_judgement(ok) == "within"
    assert "0.283°" in sigma_text(ok) and "over" not in sigma_text(ok)
    over = _snap(elapsed_s=70.0, sigma_judged_after_s=62.5,
                 sigma_deg={"roll": 0.61, "pitch": 0.52})
    assert sigma_judgement(over) == "over"
    assert sigma_text(over).endswith("limit 0.4° (roll, pitch over)")
    assert len(sigma_text(over)) <= 80
    nan = _snap(elapsed_s=70.0, sigma_judged_after_s=62.5, sigma_deg={"roll": math.nan})
    assert sigma_judgement(nan) == "settling"
    never = _snap(elapsed_s=700.0, sigma_judged_after_s=None)
    assert sigma_judgement(never) == "" and sigma_text(never).endswith("(not judged live)")
    # on a colour terminal: over the limit in yellow (an estimate, not the verdict's red)
    buf = io.StringIO()
    d = TtyDisplay(buf, fps=1e9, width=80, colour=True)
    d.update(early)
    assert "\x1b[33m  σ" not in buf.getvalue() and "\x1b[32m  σ" not in buf.getvalue()
    d.update(over)
    assert "\x1b[33m  σ (running est.) roll" in buf.getvalue()
    d.update(ok)
    assert "\x1b[32m  σ (running est.) roll" in buf.getvalue()


def test_final_banner_and_log_lines() -> None:
    buf = io.StringIO()
    d = TtyDisplay(buf, fps=1e9, width=80)
    d.update(_snap())
    d.verdict("FAIL", "roll σ 0.5012° limit 0.4° FAIL\nreport /runs/x/report.html")
    d.close()  # the block is not drawn again below the banner
    lines = _screen(buf.getvalue())
    banner_at = next(i for i, ln in enumerate(lines) if "FAIL" in ln and "=" in ln)
    assert lines[banner_at - 1] == "=" * WIDTH and len(lines[banner_at]) == WIDTH
    assert "σ (running" not in "\n".join(lines[banner_at:])
    assert "report /runs/x/report.html" in lines[banner_at + 2]
    # without a terminal: one line per state change and per period, the verdict one more
    log = io.StringIO()
    ld = LogDisplay(log, period_s=3600)
    ld.state("running", "")
    ld.update(_snap())
    ld.update(_snap())  # within the period: nothing
    ld.verdict("PASS", "roll σ 0.2°\nreport r.html")
    out = log.getvalue().splitlines()
    assert len(out) == 3 and out[0].endswith("state → running")
    assert "limit 0.4°" in out[1] and "serial " + LONG_SERIAL in out[1]
    assert out[2].endswith("verdict PASS | roll σ 0.2° | report r.html")


def test_safe_display_without_a_verdict_method() -> None:
    class Old:
        def __init__(self) -> None:
            self.said: list[str] = []

        def state(self, state: str, reason: str = "") -> None: ...
        def update(self, snap: Snapshot) -> None: ...
        def message(self, text: str) -> None:
            self.said.append(text)

        def close(self) -> None: ...

    old = Old()
    s = SafeDisplay(old)  # type: ignore[arg-type]
    s.verdict("PASS", "σ ok")
    assert old.said == ["PASS: σ ok"] and not s.failed


@pytest.fixture(scope="module")
def run_on_a_terminal(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A real session (fake devices) drawing on an 80-column terminal, on simulated time."""
    tmp = tmp_path_factory.mktemp("tty")
    clock = VirtualClock()
    with clock.running():
        return _run_on_a_terminal(tmp, clock)


def _run_on_a_terminal(tmp: Path, clock: VirtualClock) -> tuple[Path, str]:
    stand = FakeStand(clock=clock)
    buf = io.StringIO()
    # table mode: a streaming stand on a busy host holds and rejoins, and a window the
    # departures spoil is not judged (INCONCLUSIVE); this is about the display, not that
    prep = sine_motion(stand.axes, duration_s=5.0, mode="table", fade_s=0.5)
    # the lines on k/2 s: a periodic motion, its running σ judged after the fade-in and 2 s
    tables = {a: dataclasses.replace(t, period_s=2.0) for a, t in (prep.plan.tables or {}).items()}
    prep = dataclasses.replace(prep, plan=dataclasses.replace(prep.plan, tables=tables))
    sess = Session(bench_config(tmp), prep, RunOptions("SN-TTY-1", "dana"),
                   display=TtyDisplay(buf, fps=20, width=80),
                   device_factory=lambda c, p: (stand, FakeSensor(stand)), clock=clock)
    res = sess.run()
    assert res.state == "done" and res.recording is not None, res.reason
    return res.recording, buf.getvalue()


def test_a_run_on_an_80_column_terminal(run_on_a_terminal: tuple[Path, str]) -> None:
    folder, out = run_on_a_terminal
    lines = _screen(out)
    # within 80 columns, but for a word longer than that (a path): whole on a line of its own
    assert all(len(ln) <= 80 or len(ln.split()) == 1 for ln in lines)
    text = "\n".join(lines)
    assert "serial SN-TTY-1 operator dana" in text
    # the running σ: settling until the fade-in and one period are over, then judged
    settling = text.index("σ (running est.) settling: judged after one period")
    judged = re.search(r"σ \(running est\.\) roll +\d+\.\d{3}°.*limit 0\.4°$", text, re.M)
    assert judged is not None and judged.start() > settling
    # table mode: the stand plays on its own clock, missed polls are a count, not a warning
    assert "health      missed polls" in text and "WARNING" not in text
    head = next(i for i, ln in enumerate(lines) if " PASS " in ln and ln.startswith("="))
    assert "limit 0.4°  PASS" in lines[head + 1]
    # the report's path whole, never cut: on the line of "report", or on its own after it
    # when longer than the line (a parallel worker's temporary folder, popen-gwN/)
    report = f"report {folder / 'report.html'}"
    assert lines[head + 2] == report or lines[head + 2:head + 4] == [
        "report", str(folder / "report.html")]


def test_analyze_says_aborted_or_incomplete(run_on_a_terminal: tuple[Path, str], tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    done, _ = run_on_a_terminal
    assert main(["analyze", str(done), "--axis", "roll"]) == 0
    assert "NOTE" not in capsys.readouterr().out
    assert main(["analyze", str(done), "--axis", "roll", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    integrity = doc["recording"].pop("integrity")
    assert doc["recording"].pop("timing_offset_s") == 0.0  # no timing calibration in its config
    assert doc["recording"] == {"state": "done", "reason": "PASS", "note": None}
    assert integrity["status"] == "verified" and integrity["problems"] == []

    aborted = tmp_path / "aborted"
    shutil.copytree(done, aborted)
    end = json.loads((aborted / "end.json").read_text())
    end.update(state="aborted", reason="stand fault: E-stop")
    (aborted / "end.json").write_text(json.dumps(end))
    assert main(["analyze", str(aborted)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("benchctl analyze: NOTE: the run was ABORTED (stand fault: E-stop)")
    assert main(["analyze", str(aborted), "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)["recording"]
    assert rec["state"] == "aborted" and "ABORTED" in rec["note"]

    killed = tmp_path / "killed"
    shutil.copytree(done, killed)
    (killed / "end.json").unlink()
    assert main(["analyze", str(killed), "--axis", "roll"]) == 0
    assert "NOTE: the recording is INCOMPLETE" in capsys.readouterr().out
    assert main(["analyze", str(killed), "--axis", "roll", "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)["recording"]
    assert rec["state"] == "incomplete" and "INCOMPLETE" in rec["note"]


def test_log_records_go_above_the_block_not_through_it() -> None:
    """A warning logged while the block is up (from any thread) is shown above it by the display;
    the console handler writing to the same terminal is held meanwhile, and released at the
    end."""
    import logging
    import threading

    buf = io.StringIO()
    console = logging.StreamHandler(buf)
    console.setLevel(logging.WARNING)
    root = logging.getLogger()
    root.addHandler(console)
    try:
        d = TtyDisplay(buf, fps=1e9, width=80)
        d.update(_snap())
        t = threading.Thread(target=logging.getLogger("benchctl.test").warning,
                             args=("serial mismatch: typed %r, instrument reports %r",
                                   "x" * 70, "1"))
        t.start()
        t.join()
        d.update(_snap())
        # the record came once, through the display: wrapped within 80 columns, above a block
        text = "\n".join(_screen(buf.getvalue()))
        assert text.count("WARNING: serial mismatch") == 1
        assert "benchctl.test:" not in text  # not the console handler's format
        # within 80 columns, but for a word longer than a line: whole on its own
        assert all(len(ln) <= 80 or len(ln.split()) == 1 for ln in _screen(buf.getvalue()))
        d.close()
        assert console.filters == [] and len(root.handlers) >= 1
        logging.getLogger("benchctl.test").warning("after the run")
        assert "after the run" in buf.getvalue()  # the console handler prints again
    finally:
        root.removeHandler(console)


def _read_all(master: int) -> str:
    """What the terminal received so far (the master end, without waiting)."""
    import os
    import select

    out = b""
    while select.select([master], [], [], 0)[0]:
        chunk = os.read(master, 65536)
        if not chunk:
            break
        out += chunk
    return out.decode("utf-8", "replace")


@pytest.mark.parametrize(("env", "coloured"), [({}, True), ({"NO_COLOR": "1"}, False),
                                                ({"TERM": "dumb"}, False)])
def test_colour_on_a_terminal_unless_no_color(monkeypatch: pytest.MonkeyPatch,
                                              vclock: VirtualClock, env: dict[str, str],
                                              coloured: bool) -> None:
    import sys

    from terminal import on_terminal

    from benchctl.run.display import make_display

    monkeypatch.delenv("NO_COLOR", raising=False)
    monkeypatch.setenv("TERM", "xterm-256color")
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    with on_terminal(monkeypatch) as master:
        d = make_display(sys.stderr, clock=vclock)
        assert isinstance(d, TtyDisplay) and d.colour is coloured
        d.update(_snap(missed_cycles=3))
        vclock.sleep(1.0)
        d.update(_snap(missed_cycles=3, rejoins=1))
        d.verdict("FAIL", "roll σ 0.5012° limit 0.4° FAIL")
        d.close()
        seen = _read_all(master)
    assert "FAIL" in seen
    assert ("\x1b[1;31m" in seen) is coloured and ("\x1b[33m" in seen) is coloured
    assert (re.search(r"\x1b\[[0-9;]*m", seen) is not None) is coloured


def test_no_colour_without_a_terminal(monkeypatch: pytest.MonkeyPatch,
                                     vclock: VirtualClock) -> None:
    from benchctl.run.display import colour_wanted, make_display

    monkeypatch.delenv("NO_COLOR", raising=False)
    buf = io.StringIO()
    d = make_display(buf, clock=vclock)
    assert isinstance(d, LogDisplay) and not colour_wanted(buf)
    d.update(_snap(rejoins=1))
    d.verdict("FAIL", "roll σ 0.5°")
    assert "\x1b" not in buf.getvalue()


# --- the end of a run at 80×24: the summary wrapped at words, the banner last ---

_WORD = st.text(alphabet=st.sampled_from("abcdefgh°σ…/.-_0123456789"), min_size=1, max_size=12)


@settings(max_examples=300, deadline=None)
@given(words=st.lists(_WORD, min_size=1, max_size=40),
       gaps=st.lists(st.integers(1, 3), min_size=40, max_size=40),
       indent=st.integers(0, 8), width=st.integers(20, 120))
def test_wrap_words_never_cuts_a_word(words: list[str], gaps: list[int], indent: int,
                                      width: int) -> None:
    """Wrapped at words: no line longer than the width, no word cut, all words kept in order
    (words of at most 12 characters, widths from 20)."""
    from benchctl.run.display import wrap_words

    text = " " * indent + "".join(w + " " * g for w, g in zip(words, gaps, strict=False))
    lines = wrap_words(text.rstrip(), width)
    assert all(len(ln) <= width for ln in lines)
    assert [w for ln in lines for w in ln.split()] == words
    assert len(lines) == 1 or all(ln.strip() for ln in lines)


def test_wrap_words_keeps_a_fitting_line_and_a_long_word_whole() -> None:
    from benchctl.run.display import wrap_words

    assert wrap_words("  roll  σ = 0.2104°  limit 0.4°", 80) == ["  roll  σ = 0.2104°  limit 0.4°"]
    path = "/runs/" + "x" * 90 + "/report.html"
    assert wrap_words(f"report {path} here", 80) == ["report", path, "  here"]
    assert wrap_words("a\n\nb", 80) == ["a", "", "b"]


def test_fit_rows_less_detail_first() -> None:
    from benchctl.run.display import fit_rows

    lines = ["PASS   serial X", "  decision rule: simple", "profile p", *(
        f"        detail {i} " + "word " * 20 for i in range(6)), "  warning: keep me",
        "  recording /r"]
    out = fit_rows(lines, 79, 10, "/r/report.txt")
    assert len(out) <= 10 and all(len(ln) <= 79 for ln in out)
    assert out[0] == "PASS   serial X" and "  warning: keep me" in out
    # the most indented went first, from the bottom: two rows each, four of them
    assert out[-1] == "  … 4 line(s) of detail left out: /r/report.txt"
    assert any("detail 1" in ln for ln in out) and not any("detail 2" in ln for ln in out)
    assert "  decision rule: simple" in out and "  recording /r" in out
    assert fit_rows(lines[:3], 79, 10) == lines[:3]  # it fits: as it is


class _Screen:
    """The rows a terminal shows after ``text``: newlines, carriage returns, cursor up to a
    line's start (``ESC[nF``) and erase below (``ESC[J``); colour ignored; a line longer than
    ``columns`` folds."""

    def __init__(self, columns: int, rows: int) -> None:
        self.columns, self.rows = columns, rows
        self.lines: list[str] = [""]
        self.y = 0

    def feed(self, text: str) -> None:
        for tok in re.findall(r"\x1b\[[0-9;]*[A-Za-z]|\r|\n|[^\x1b\r\n]+", text):
            if tok == "\n":
                self.y += 1
                if self.y == len(self.lines):
                    self.lines.append("")
            elif tok == "\r" or tok.endswith("m"):
                continue
            elif tok.endswith("F"):
                self.y = max(0, self.y - int(tok[2:-1] or 1))
                self.lines[self.y] = ""
            elif tok.endswith("J"):
                del self.lines[self.y + 1:]
                self.lines[self.y] = ""
            else:
                self.lines[self.y] += tok

    def shown(self) -> list[str]:
        folded = [ln[i:i + self.columns] for ln in self.lines
                  for i in range(0, max(len(ln), 1), self.columns)]
        return folded[-self.rows:]


@pytest.mark.parametrize("verdict", ["PASS", "ABORTED"])
def test_a_run_ends_with_its_banner_at_80x24(monkeypatch: pytest.MonkeyPatch,
                                             vclock: VirtualClock, tmp_path: Path,
                                             verdict: str) -> None:
    """A whole run (fake devices, simulated time; passed, or aborted by an E-stop) on an
    80×24 pseudo-terminal, stdout and stderr both on it, as ``benchctl run`` ends it: the
    verdict's banner is the last thing on the screen, the summary above it wrapped at words
    within 80 columns, summary and banner within the 24 rows (one for the prompt)."""
    import os
    import sys
    import threading

    from terminal import on_terminal

    from benchctl.cli.run import print_outcome, summary_lines
    from benchctl.run.display import make_display

    end = "\x1b]END\x07"
    got: list[bytes] = []
    with on_terminal(monkeypatch, stdout=True, size=(80, 24)) as master:
        def drain() -> None:
            while not b"".join(got[-2:]).endswith(end.encode()):
                got.append(os.read(master, 65536))

        reader = threading.Thread(target=drain, name="pty-drain")
        reader.start()
        try:
            display = make_display(sys.stderr, clock=vclock, hold_banner=True)
            assert isinstance(display, TtyDisplay) and display.width == 79
            stand = FakeStand(clock=vclock)
            if verdict == "ABORTED":
                stand.estop_at = 2.0
            prep = sine_motion(stand.axes, duration_s=5.0, mode="table", fade_s=0.5)
            res = Session(bench_config(tmp_path), prep, RunOptions("SN-80x24", "dana"),
                          display=display, device_factory=lambda c, p: (stand, FakeSensor(stand)),
                          clock=vclock).run()
            assert res.state == ("done" if verdict == "PASS" else "aborted"), res.reason
            print_outcome(res, display)
        finally:
            sys.stderr.write(end)
            sys.stderr.flush()
            reader.join()
    text = b"".join(got).decode("utf-8", "replace").replace(end, "")
    screen = _Screen(80, 24)
    screen.feed(text)
    shown = screen.shown()
    rows = [ln for ln in shown]
    while rows and not rows[-1]:
        rows.pop()
    assert rows[-1] == "=" * 79, rows  # the banner closes the screen
    head = max(i for i, ln in enumerate(rows) if f" {verdict} " in ln and ln.startswith("="))
    assert rows[head - 1] == "=" * 79
    assert ("limit 0.4°  PASS" if verdict == "PASS" else "E-stop") in rows[head + 1]
    start = "PASS   serial SN-80x24" if verdict == "PASS" else "ABORTED: "
    # the summary above the banner, its first line on the same screen, a row left for the
    # prompt; wrapped at words within 79 columns (a word longer than that whole on its own)
    first = next(i for i, ln in enumerate(rows) if ln.startswith(start))
    assert len(rows) - first <= 23
    logical = list(screen.lines)
    while logical and not logical[-1]:
        logical.pop()
    lfirst = max(i for i, ln in enumerate(logical) if ln.startswith(start))
    lbar = max(i for i, ln in enumerate(logical)
               if f" {verdict} " in ln and ln.startswith("=")) - 1
    above = logical[lfirst:lbar]
    assert all(len(ln) <= 79 or len(ln.split()) == 1 for ln in above)
    note = next((i for i, ln in enumerate(above) if ln.startswith("  … ")), len(above))
    kept = [w for ln in above[:note] for w in ln.split()]
    words = [w for ln in summary_lines(res) for w in ln.split()]
    if note == len(above):
        assert kept == words  # nothing left out: every word, in order, none cut
    else:  # less detail: the words shown are the summary's, in order, none cut
        assert ("report.txt" if verdict == "PASS" else "end.json") in "".join(above[note:])
        it = iter(words)
        assert all(any(w == v for v in it) for w in kept)
