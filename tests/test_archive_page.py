"""The history page in a real browser (headless Chromium from the distribution, installed by
.ci/run): it loads without a page error, its plots are SVG in the DOM, the archive's texts
stay text, and it prints to A4 PDF."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
from archive_helpers import make_record

from benchctl.archive.store import Archive
from benchctl.cli import main


def _chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    pytest.fail("Chromium not found (chromium or chromium-browser on PATH): .ci/run installs "
                "the distribution's package; this test needs it")


def _browser(args: list[str], page: Path, tmp: Path) -> subprocess.CompletedProcess[str]:
    cmd = [_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
           "--disable-extensions", f"--user-data-dir={tmp / 'profile'}",
           "--enable-logging=stderr", "--v=0", *args, page.resolve().as_uri()]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)


def _page_errors(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines()
            if "CONSOLE" in ln or "Uncaught" in ln or "Failed to load resource" in ln]


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
    dom = _browser(["--dump-dom"], page, tmp_path)
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert _page_errors(dom.stderr) == [], dom.stderr[-3000:]
    assert dom.stdout.count("<svg") == html.count("<svg") == 3  # σ, yield of two stations
    assert dom.stdout.count("<circle") == 24  # a marker per run and axis
    assert "&lt;img src=x onerror=alert(1)&gt;" in dom.stdout
    pdf = tmp_path / "history.pdf"
    out = _browser([f"--print-to-pdf={pdf}", "--no-pdf-header-footer"], page, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert _page_errors(out.stderr) == [], out.stderr[-3000:]
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF-")
    boxes = re.findall(rb"/MediaBox\s*\[\s*([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s*\]", data)
    assert boxes
    for x0, y0, x1, y1 in boxes:  # A4: 595 × 842 pt
        assert abs(float(x1) - float(x0) - 595.3) < 2 and abs(float(y1) - float(y0) - 841.9) < 2
