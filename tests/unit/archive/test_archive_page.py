"""The history page in a real browser (headless Chromium from the distribution, installed by
.ci/run): it loads without a page error, its plots are SVG in the DOM, the archive's texts
stay text, and it prints to A4 PDF."""

from __future__ import annotations

from pathlib import Path

import pytest
from archive_helpers import make_record
from browser import browser, page_errors, pdf_pages

from benchctl.archive.store import Archive
from benchctl.cli import main


def test_history_page_in_headless_chromium(tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    url = f"sqlite:///{tmp_path / 'archive.sqlite'}"
    with Archive(url) as a:
        for i in range(12):
            sigma = 0.25 + 0.02 * i
            a.store(make_record(
                f"run{i:02d}", serial="INC-7", sigma=sigma, axes=("roll", "pitch"),
                outcome="PASS" if sigma < 0.38 else "FAIL",
                start=f"2026-11-{10 + i // 3:02d}T0{8 + i % 3}:00:00Z",
                station="bench-1" if i % 2 else "bench-2",
                operator="<img src=x onerror=alert(1)>"))
    page = tmp_path / "history.html"
    assert main(["history", "INC-7", "--url", url, "--html", str(page)]) == 0
    capsys.readouterr()
    html = page.read_text(encoding="utf-8")
    assert "<script" not in html and "<img" not in html  # escaped, nothing active
    dom = browser(["--dump-dom"], page, tmp_path)
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert page_errors(dom.stderr) == [], dom.stderr[-3000:]
    assert dom.stdout.count("<svg") == html.count("<svg") == 2  # σ, the unit's yield per day
    assert dom.stdout.count("<circle") == 24  # a marker per run and axis
    assert "&lt;img src=x onerror=alert(1)&gt;" in dom.stdout
    pdf = tmp_path / "history.pdf"
    out = browser([f"--print-to-pdf={pdf}", "--no-pdf-header-footer"], page, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert page_errors(out.stderr) == [], out.stderr[-3000:]
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF-")
    boxes = pdf_pages(data)
    assert boxes
    for w, h in boxes:  # A4: 595 × 842 pt
        assert abs(w - 595.3) < 2 and abs(h - 841.9) < 2
