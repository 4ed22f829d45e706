"""report.html: one self-contained HTML file per run, Jinja2-autoescaped, SVG
figures inline, no script, no external resource, printable on A4 — checked as text here and in
a real browser (the distribution's headless Chromium, installed by .ci/run): it loads without
an error from the page, holds its figures, and prints to an A4 PDF.

The runs are real sessions against the fake stand and instrument (tests/helpers/run_fakes.py),
on simulated time: the report is the one the run itself wrote."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from html import unescape
from pathlib import Path
from typing import Any

import pytest
from browser import browser, page_errors, pdf_pages, pdf_text, print_pdf
from run_fakes import FakeSensor, FakeStand, sine_motion

from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.config import parse_config
from benchctl.report.html import REPORT_HTML, build_context, render_html
from benchctl.results.record import load_record
from benchctl.run.prepare import RunOptions
from benchctl.run.session import RunResult, Session

NASTY_SERIAL = "<script>alert('x')</script>&SN"
NASTY_OPERATOR = 'O"Brien <b>'
SECTIONS = ("verdict", "sigma", "measurements", "identity", "warnings", "files", "signoff")


def _config(tmp: Path, figures: bool = True) -> Any:
    data = {
        "station": "test-bench <7>",
        "unit": {"part_number": "PN-42"},
        "stand": {
            "driver": "modbus-tcp",
            "limits": {"angle_deg": 20.0, "rate_deg_s": 50.0, "accel_deg_s2": 300.0},
            "setpoint_rate_hz": 100.0,
            "sample_rate_hz": 100.0,
            "tracking_tolerance_deg": 0.5,
            "calibration_due": "2031-05-17",
        },
        "instrument": {
            "driver": "nmea0183",
            "serial_port": "/dev/null",
            "axes": ["roll", "pitch"],
            "silence_timeout_s": 0.5,
            "static_tolerance_deg": 0.2,
        },
        "run": {"limit_sigma_deg": 0.4, "output_dir": str(tmp), "precheck_window_s": 0.5,
                "figures": figures},
    }
    return parse_config(data, tmp / "bench.yaml")


def _run(tmp: Path, fault_at: float | None = None, gain: float = 1.0,
         figures: bool = True) -> RunResult:
    """A session on the fakes, on simulated time (a VirtualClock of its own: the runs are
    module fixtures)."""
    clock = VirtualClock()
    with clock.running():
        stand = FakeStand(clock=clock)
        stand.fault_at = fault_at
        sensor = FakeSensor(stand, gain=gain)
        # table mode: the stand plays the table itself; the passing run's report is the subject
        prep = sine_motion(stand.axes, duration_s=6.0, mode="table", fade_s=0.5)
        sess = Session(_config(tmp, figures), prep, RunOptions(NASTY_SERIAL, NASTY_OPERATOR),
                       device_factory=lambda c, p: (stand, sensor), clock=clock)
        return sess.run()


@pytest.fixture(scope="module")
def passed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    res = _run(tmp_path_factory.mktemp("passed"), gain=1.02)
    assert res.state == "done" and res.reason == "PASS", res.reason
    assert res.recording is not None
    return res.recording


@pytest.fixture(scope="module")
def aborted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    res = _run(tmp_path_factory.mktemp("aborted"), fault_at=1.0)
    assert res.state == "aborted" and res.recording is not None
    return res.recording, res.reason


def _external_refs(html: str) -> list[str]:
    """Every src=/href=/url() that is not a fragment of the page itself."""
    refs = re.findall(r'(?:src|href)\s*=\s*["\']([^"\']*)["\']', html, re.I)
    refs += re.findall(r"url\(\s*['\"]?([^)'\"]*)", html, re.I)
    return [r for r in refs if not r.startswith("#")]


def _common_checks(html: str) -> None:
    assert html.startswith("<!DOCTYPE html>")
    assert "<script" not in html.lower()  # no JavaScript at all (the serial's is escaped)
    assert "&lt;script&gt;" in html and NASTY_SERIAL not in html
    assert _external_refs(html) == []
    assert not re.search(r"<(?:link|img|iframe|object|embed)\b", html, re.I)
    assert "@page { size: A4" in html and "@media print" in html
    for s in SECTIONS:
        assert f'id="{s}"' in html, s


def test_report_of_a_passing_run(passed: Path) -> None:
    html = (passed / REPORT_HTML).read_text(encoding="utf-8")
    _common_checks(html)
    assert 'class="verdict PASS"' in html
    assert "O&#34;Brien &lt;b&gt;" in html and "test-bench &lt;7&gt;" in html
    # σ, interval and ν per axis; the rule; the measurements with limits and outcomes
    report = json.loads((passed / "report.json").read_text())
    roll = report["axes"]["roll"]
    assert f"{roll['sigma']:.4f}" in html
    assert f"{roll['sigma_ci95'][0]:.4f} … {roll['sigma_ci95'][1]:.4f}" in html
    assert f"{roll['dof']:.3g}" in html
    assert "Decision rule:</strong> simple" in html
    assert html.count("<tr><td>sigma") == 1 and "gain at 5 s" in html
    # the figures: error PSD, gain/phase/coherence, the time-trace excerpt; the tables
    for cls in ("psd", "frf", "trace"):
        assert f'<figure class="{cls}"><svg' in html, cls
    assert 'class="gain-table"' in html and 'class="decomposition"' in html
    assert "cumulative σ" in html or "cumulative" in html
    # who, what, when, where
    rec = load_record(passed)
    for text in ("PN-42", "2031-05-17", rec["unit"]["reported_serial"], rec["software"]["version"],
                 rec["config_sha256"] or "—", rec["start_utc"], rec["end_utc"], "fake-sine",
                 "serial S1", "serial I1", "DOES NOT MATCH"):
        assert text in html, text
    # warnings: the serial mismatch the record warns about is in the list; its measurement
    # is informative, a WARNING, and a PASS report shows no FAIL anywhere
    assert "serial mismatch" in html
    row = re.search(r"<tr><td>serial match.*?</tr>", html, re.S)
    assert row is not None and '<td class="WARNING">WARNING</td>' in row.group(0)
    assert 'class="FAIL"' not in html and ">FAIL<" not in html
    # every data file of the recording with its SHA-256, and the recording's own
    data = rec["data"]
    assert 'class="data-files"' in html and data["recording_sha256"] in html
    for f in data["files"]:
        assert re.search(rf"<td>{re.escape(f['name'])}</td><td class=\"n\">{f['bytes']}</td>"
                         rf"<td class=\"hash\">{f['sha256']}</td>", html), f
    assert hashlib.sha256((passed / "stand.csv").read_bytes()).hexdigest() in html
    # the record names the report with its hash; end.json lists it
    entry = rec["files"]["report_html"]
    assert Path(entry["path"]) == passed / REPORT_HTML
    assert entry["sha256"] == hashlib.sha256((passed / REPORT_HTML).read_bytes()).hexdigest()
    assert REPORT_HTML in json.loads((passed / "end.json").read_text())["report"]


def test_report_of_an_aborted_run(aborted: tuple[Path, str]) -> None:
    folder, reason = aborted
    html = (folder / REPORT_HTML).read_text(encoding="utf-8")
    _common_checks(html)
    assert 'class="verdict ABORTED"' in html
    assert "Aborted (equipment)" in html and "fault code 7" in reason
    assert "fault code 7" in html
    # the prechecks it passed, on one group row that names them
    group = re.search(r'<tr class="group"><td>prechecks \((\d+)\)</td>.*?</tr>\s*'
                      r'<tr class="group"><td colspan="9"><small>([^<]*)</small>', html, re.S)
    assert group is not None and "static agreement" in group.group(2)
    assert f"{group.group(1)} of {group.group(1)} passed" in group.group(0)
    assert '<td class="PASS">PASS</td>' in group.group(0)
    assert "<tr><td>precheck: " not in html
    assert "No analysis" in html
    assert load_record(folder)["files"]["report_html"] is not None


def test_excitation_block_drawn_with_its_tolerance_bands(passed: Path) -> None:
    report = json.loads((passed / "report.json").read_text())
    bands = [{"centre_hz": f, "target_power": 1.0, "achieved_power": p,
              "error_db": e, "error_ci95_db": [e - 0.1, e + 0.1]}
             for f, p, e in ((0.1, 1.1, 0.41), (0.2, 0.8, -0.97), (0.4, 1.0, 0.0))]
    report["axes"]["roll"]["excitation"] = {
        "judgement": "ok", "alarm_db": 1.5, "abort_db": 3.0, "rms_error_db": 0.61,
        "variance_ratio": 0.97, "bands": bands}
    html = render_html(build_context(passed, report=report, trace=False))
    assert '<figure class="excitation"><svg' in html
    assert "alarm (±1.5 dB)" in html and "abort (±3 dB)" in html
    # without the block, no such figure
    report["axes"]["roll"]["excitation"] = None
    report["axes"]["roll"]["analysis"]["excitation"] = None
    assert 'class="excitation"' not in render_html(build_context(passed, report=report,
                                                                 trace=False))


def test_benchctl_report_rerenders(passed: Path, tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / passed.name
    shutil.copytree(passed, folder)
    (folder / REPORT_HTML).unlink()
    assert main(["report", str(folder)]) == 0
    assert capsys.readouterr().out.strip() == str(folder / REPORT_HTML)
    html = (folder / REPORT_HTML).read_text(encoding="utf-8")
    _common_checks(html)
    entry = load_record(folder)["files"]["report_html"]
    assert entry["path"] == str(folder / REPORT_HTML)
    assert entry["sha256"] == hashlib.sha256(html.encode("utf-8")).hexdigest()
    assert main(["report", str(tmp_path / "nowhere")]) == 2
    assert "no such recording folder" in capsys.readouterr().err


# ------------------------------------------------------------------------- in a real browser
def test_page_errors_are_detected(tmp_path: Path) -> None:
    """The detector below sees a page's error (so its silence on the report means something)."""
    page = tmp_path / "bad.html"
    page.write_text("<!DOCTYPE html><html><body><p>x</p>"
                    "<script>undefined_function_of_the_test()</script></body></html>")
    out = browser(["--dump-dom"], page, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert any("undefined_function_of_the_test" in ln for ln in page_errors(out.stderr)), \
        out.stderr[-3000:]


def test_report_in_headless_chromium_loads_and_prints_a4(passed: Path, tmp_path: Path) -> None:
    page = passed / REPORT_HTML
    html = page.read_text(encoding="utf-8")
    dom = browser(["--dump-dom"], page, tmp_path)
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert page_errors(dom.stderr) == [], dom.stderr[-3000:]
    # the browser parsed the page: every figure is an SVG element in its DOM
    n_svg = html.count("<svg")
    assert n_svg >= 3 and dom.stdout.count("<svg") == n_svg
    assert 'class="verdict PASS"' in dom.stdout and "&lt;script&gt;" in dom.stdout
    pdf = tmp_path / "report.pdf"
    out = browser([f"--print-to-pdf={pdf}", "--no-pdf-header-footer"], page, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert page_errors(out.stderr) == [], out.stderr[-3000:]
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF-")
    pages = pdf_pages(data)
    # a one-axis run on at most three A4 pages (test_printed_layout below: what is where)
    assert 2 <= len(pages) <= 3, len(pages)
    for w, h in pages:  # A4: 595 × 842 pt
        assert abs(w - 595.3) < 2 and abs(h - 841.9) < 2, (w, h)


def test_report_of_a_killed_run(aborted: tuple[Path, str], tmp_path: Path,
                                capsys: pytest.CaptureFixture[str]) -> None:
    """A recording left without end.json or record.json (the process was killed): the report
    says INCOMPLETE, with what meta.json knows."""
    folder = tmp_path / "killed"
    shutil.copytree(aborted[0], folder)
    for name in ("end.json", "record.json", REPORT_HTML):
        (folder / name).unlink()
    assert main(["report", str(folder), "--no-trace"]) == 0
    capsys.readouterr()
    html = (folder / REPORT_HTML).read_text(encoding="utf-8")
    _common_checks(html)
    assert 'class="verdict INCOMPLETE"' in html and "no end.json" in html
    assert "PN-42" in html and "2031-05-17" in html  # from meta.json's config


def test_health_table_names_a_rejoin_as_rejoining_the_profile(passed: Path) -> None:
    """A rejoin is the stand brought back onto the profile after missed setpoints (or an
    underrun), not a reconnection: the health table and the warnings say so."""
    report = json.loads((passed / "report.json").read_text())
    report["stats"] = {**report["stats"], "rejoins": 2}
    html = render_html(build_context(passed, report=report, trace=False))
    row = re.search(r"<th>(rejoins[^<]*)</th><td class=\"([^\"]*)\">([^<]*)</td>", html)
    assert row is not None, html
    label, cls, value = row.groups()
    assert label == "rejoins (the stand rejoined the profile after missed setpoints or an " \
        "underrun)"
    assert "warn" in cls and value.strip() == "2"
    assert "2 rejoin(s): the stand rejoined the profile after missed setpoints" in html
    assert "reconnect" not in html.lower()


def test_psd_limit_line_is_drawn_against_the_sigma_axis(passed: Path) -> None:
    """The σ limit (deg) is drawn on the axis of σ accumulated over frequency (deg), not on,
    nor beside, the PSD's density axis (deg²/Hz)."""
    from benchctl.report.figures import psd_figure

    analysis = json.loads((passed / "report.json").read_text())["axes"]["roll"]["analysis"]
    fig = psd_figure(analysis, 0.4, "roll")
    assert fig is not None
    axes = fig.get_axes()
    assert len(axes) == 2  # two panels, no twin axis sharing one panel
    by_label = {a.get_ylabel(): a for a in axes}
    psd_ax, sigma_ax = by_label["PSD, deg²/Hz"], by_label["cumulative σ, deg"]
    limits = [ln for a in axes for ln in a.get_lines() if ln.get_label().startswith("σ limit")]
    assert len(limits) == 1 and limits[0].axes is sigma_ax
    assert list(limits[0].get_ydata()) == [0.4, 0.4]
    lo, hi = sigma_ax.get_ylim()
    assert lo <= 0.4 < hi and sigma_ax.get_yscale() == "linear"
    cum = [ln for ln in sigma_ax.get_lines() if ln.get_label() == "cumulative σ"]
    assert len(cum) == 1 and max(cum[0].get_ydata()) < hi
    assert psd_ax.get_yscale() == "log"
    assert all(not ln.get_label().startswith("σ limit") for ln in psd_ax.get_lines())
    # each panel's legend names only what is on it
    assert "σ limit 0.4°" in [t.get_text() for t in sigma_ax.get_legend().get_texts()]
    assert "σ limit 0.4°" not in [t.get_text() for t in psd_ax.get_legend().get_texts()]


@pytest.fixture(scope="module")
def passed_pdf(passed: Path, tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """The passing run's report printed by headless Chromium: each page's text."""
    return pdf_text(print_pdf(passed / REPORT_HTML, tmp_path_factory.mktemp("pdf")))


def test_sign_off_block_printed_whole(passed: Path, passed_pdf: list[str]) -> None:
    """The printed report ends with a sign-off block — tested by (the operator's name
    printed), checked by, the date and the remarks, each with room to sign — kept on one page."""
    html = (passed / REPORT_HTML).read_text(encoding="utf-8")
    block = html[html.index('<section id="signoff"'):]
    assert "<th>Tested by</th><td class=\"sign\">O&#34;Brien &lt;b&gt;</td>" in block
    for text in ("<th>Checked by</th>", "<th>name</th><th>signature</th><th>date</th>",
                 "Remarks:", load_record(passed)["data"]["recording_sha256"]):
        assert text in block, text
    assert block.count('<div class="line"></div>') == 3
    last = passed_pdf[-1]
    pos = [last.find(t) for t in ("Sign-off", "Tested by", "Checked by", "Remarks")]
    assert -1 not in pos and pos == sorted(pos), last  # in that order, all on the last page
    assert 'O"Brien <b>' in last


def test_measurements_table_groups_the_prechecks() -> None:
    """The prechecks are one row (how many passed, their names); a failed one is also shown
    on its own row with its detail, and the group row is FAIL; nothing else is grouped."""
    from benchctl.report.html import measurement_rows

    def pre(name: str, ok: bool) -> dict[str, Any]:
        return {"name": f"precheck: {name}", "axis": None, "value": ok, "unit": None,
                "low": None, "high": None, "ci95": None, "outcome": "PASS" if ok else "FAIL",
                "rule": "check", "decisive": True, "note": f"{name} detail"}

    sigma = {"name": "sigma", "axis": "roll", "value": 0.2, "unit": "deg", "low": None,
             "high": 0.4, "ci95": [0.19, 0.21], "outcome": "PASS", "rule": "simple",
             "decisive": True, "note": None}
    rows = measurement_rows([pre("disk space", True), pre("stand answers", True), sigma])
    assert [r["name"] for r in rows] == ["prechecks (2)", "sigma"]
    assert rows[0]["value"] == "2 of 2 passed" and rows[0]["outcome"] == "PASS"
    assert rows[0]["note"] == "disk space, stand answers" and rows[0]["group"]
    rows = measurement_rows([pre("disk space", True), pre("static agreement", False)])
    assert [r["name"] for r in rows] == ["prechecks (2)", "precheck: static agreement"]
    assert rows[0]["outcome"] == "FAIL" and rows[0]["value"] == "1 of 2 passed"
    assert rows[1]["note"] == "static agreement detail" and not rows[1]["group"]
    assert measurement_rows([sigma]) == [{**sigma, "group": False}]


# each heading of the printed report and the text that follows it: on the same page
HEADINGS = (
    ("Dynamic error of a ship inclinometer", "PASS"),
    ("Dynamic error σ per axis", "axis"),
    ("Measurements", "Rule: how the value was judged"),
    ("Who, what, when, where", "serial"),
    ("Warnings and the stand's health", "roll"),
    ("Axis roll", "Above: the error PSD"),
    ("Gain table", "period, s"),
    ("Error decomposition", "component"),
    ("Files", "Recording:"),
    ("Sign-off", "Tested by"),
)


def test_printed_layout_of_a_one_axis_run(passed_pdf: list[str]) -> None:
    """Chromium's PDF of a one-axis run: at most 3 A4 pages; the sections in order; no heading
    left at the foot of a page away from what it heads; page 1 filled (the summary, the
    measurements and the who/what table begin on it); the last page not the files alone."""
    pages = passed_pdf
    assert len(pages) <= 3, len(pages)
    text = "\n".join(pages)
    where = [text.find(h) for h, _ in HEADINGS]
    assert -1 not in where and where == sorted(where), list(zip(HEADINGS, where, strict=True))

    def page_of(s: str, after: int = 0) -> int:
        pos = text.find(s, after)
        assert pos >= 0, s
        return _page_at(pages, pos)

    for heading, follower in HEADINGS:
        h = text.find(heading)
        assert page_of(heading) == page_of(follower, h + len(heading)), (heading, follower)
    # page 1 is the summary, full: σ, the measurements and who/what begin there
    for h in ("Dynamic error σ per axis", "Measurements", "Who, what, when, where"):
        assert h in pages[0], h
    # the last page holds the sign-off, not the files table alone
    assert "Sign-off" in pages[-1] and "Tested by" in pages[-1]


def _page_at(pages: list[str], pos: int) -> int:
    """The page holding character ``pos`` of the pages' text joined by newlines."""
    start = 0
    for i, page in enumerate(pages):
        end = start + len(page) + 1
        if pos < end:
            return i
        start = end
    return len(pages) - 1


def test_figures_of_the_same_content_drawn_once(passed: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A run draws its report twice (before and after its recording closes): the figures of
    the same analysis are drawn once; other content is drawn anew."""
    import benchctl.report.html as html

    calls: list[str] = []
    real = html.psd_svg

    def counting(an: Any, limit: Any = None, title: str = "") -> str | None:
        calls.append(title)
        return real(an, limit, title)

    monkeypatch.setattr(html, "psd_svg", counting)
    report = json.loads((passed / "report.json").read_text())
    report["axes"]["roll"]["limit"] = 0.3999  # content not drawn before in this process
    first = render_html(build_context(passed, report=report, trace=False))
    again = render_html(build_context(passed, report=report, trace=False))
    assert len(calls) == 1 and first == again
    report["axes"]["roll"]["limit"] = 0.3998
    render_html(build_context(passed, report=report, trace=False))
    assert len(calls) == 2


def test_health_of_a_run_that_ran_no_cycle() -> None:
    """A run refused at a precheck has its lateness and round-trip percentiles null: the
    health table shows a dash (it raised TypeError, and report.html was not written)."""
    from benchctl.report.html import _health

    rows = dict((what, value) for what, value, _warn in _health(
        {"cycles": 0, "cycle_lateness_s": {"p50": None, "p99": None},
         "stand_rtt_s": {"p50": 0.004, "p99": None}}))
    assert rows["cycle lateness p50 / p99"] == "— / — ms"
    assert rows["stand round trip p50 / p99"] == "4 / — ms"


def test_a_run_without_figures_says_so_and_benchctl_report_draws_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``run.figures: false`` (a CI bench, a campaign): no analysis PNG, report.html without
    figures and saying so (with the command that draws them); the verdict, the tables and
    the record are as with figures. ``benchctl report`` on the recording then draws them."""
    res = _run(tmp_path / "nofig", gain=1.02, figures=False)
    assert res.state == "done" and res.reason == "PASS" and res.recording is not None
    rec = res.recording
    assert not list(rec.glob("analysis_*.png"))
    html = (rec / REPORT_HTML).read_text(encoding="utf-8")
    _common_checks(html)
    assert "<svg" not in html and 'class="gain-table"' in html
    assert "run.figures: false" in html and f"benchctl report {rec}" in html
    assert load_record(rec)["outcome"] == "PASS"
    assert main(["report", str(rec)]) == 0
    capsys.readouterr()
    html = (rec / REPORT_HTML).read_text(encoding="utf-8")
    for cls in ("psd", "frf", "trace"):
        assert f'<figure class="{cls}"><svg' in html, cls
    assert "run.figures: false" not in html


def test_analysis_warnings_state_the_skew_and_timing_in_the_interval() -> None:
    """The report's per-axis notes: a skew taken out (ppm, drift over the record) and σ's
    interval holding timing (with the statistical one beside it); nothing of either when
    there is none."""
    from benchctl.report.html import _analysis_warnings

    an = {"timing": {"timing_share": 0.002, "skew_ppm": 199.8, "skew_corrected": True,
                     "skew_drift_s": 0.1798, "timing_in_interval": True,
                     "sigma_ci95_statistical": [0.28101, 0.28312]}}
    notes = _analysis_warnings("roll", an)
    assert "roll: the instrument's stamps drift +199.8 ppm against the stand's (+180 ms over " \
           "the record), corrected" in notes
    assert "roll: σ's interval includes timing (statistical alone 0.28101 … 0.28312°)" in notes
    quiet = _analysis_warnings("roll", {"timing": {"timing_share": 0.0, "skew_ppm": 0.3,
                                                   "skew_corrected": False,
                                                   "timing_in_interval": False}})
    assert not any("drift" in n or "interval" in n for n in quiet)


def test_the_budget_of_sigma_per_axis(passed: Path) -> None:
    """σ's uncertainty budget, as report.json states it, in a table under σ's: each
    contribution with its type and u (or what it is instead), u_c, U and k."""
    html = (passed / REPORT_HTML).read_text(encoding="utf-8")
    b = json.loads((passed / "report.json").read_text())["axes"]["roll"]["budget"]
    assert b["sigma_of"] == "sigma"
    assert '<p class="budget"><strong>Uncertainty budget of σ</strong>' in html
    assert "(sigma, the σ above" in html
    for c in b["contributions"]:
        assert c["name"] in unescape(html), c["name"]
    assert "non-stationarity (–) <em>not assessed</em>" in html  # a flag, never a number
    assert f"expanded U = {b['expanded']:.2g}° (k = 2)" in html
