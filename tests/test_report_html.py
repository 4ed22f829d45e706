"""report.html (issue 11 item 2): one self-contained HTML file per run, Jinja2-autoescaped, SVG
figures inline, no script, no external resource, printable on A4 — checked as text here and in
a real browser (the distribution's headless Chromium, installed by .ci/run): it loads without
an error from the page, holds its figures, and prints to an A4 PDF.

The runs are real sessions against the fake stand and instrument (tests/run_fakes.py), on
simulated time: the report is the one the run itself wrote."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from pathlib import Path
from typing import Any

import pytest
from browser import browser, page_errors, pdf_pages
from run_fakes import FakeSensor, FakeStand, sine_motion

from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.config import parse_config
from benchctl.report.html import REPORT_HTML, build_context, render_html
from benchctl.results.record import load_record
from benchctl.run.session import RunOptions, RunResult, Session

NASTY_SERIAL = "<script>alert('x')</script>&SN"
NASTY_OPERATOR = 'O"Brien <b>'
SECTIONS = ("verdict", "sigma", "measurements", "identity", "warnings", "files")


def _config(tmp: Path) -> Any:
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
        "run": {"limit_sigma_deg": 0.4, "output_dir": str(tmp), "precheck_window_s": 0.5},
    }
    return parse_config(data, tmp / "bench.yaml")


def _run(tmp: Path, fault_at: float | None = None, gain: float = 1.0) -> RunResult:
    """A session on the fakes, on simulated time (a VirtualClock of its own: the runs are
    module fixtures)."""
    clock = VirtualClock()
    with clock.running():
        stand = FakeStand(clock=clock)
        stand.fault_at = fault_at
        sensor = FakeSensor(stand, gain=gain)
        # table mode: the stand plays the table itself; the passing run's report is the subject
        prep = sine_motion(stand.axes, duration_s=6.0, mode="table", fade_s=0.5)
        sess = Session(_config(tmp), prep, RunOptions(NASTY_SERIAL, NASTY_OPERATOR),
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
    # warnings: the serial mismatch the record warns about is in the list
    assert "serial mismatch" in html
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
    assert "precheck: static agreement" in html  # the prechecks it passed
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
    # the summary, the measurements and each axis on its own page: several A4 pages
    assert 2 <= len(pages) <= 20, len(pages)
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
