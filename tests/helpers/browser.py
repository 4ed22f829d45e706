"""Headless Chromium for the tests of the HTML pages (the run's report, the history page): the
distribution's package, installed by .ci/run. A test that needs it and cannot find it fails."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest


def chromium() -> str:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    pytest.fail("Chromium not found (chromium or chromium-browser on PATH): .ci/run installs "
                "the distribution's package; this test needs it")


def browser(args: list[str], page: Path, tmp: Path) -> subprocess.CompletedProcess[str]:
    """Chromium headless on ``page`` with ``args`` (``--dump-dom``, ``--print-to-pdf=…``), its
    own profile in ``tmp``, its log on stderr."""
    cmd = [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
           "--disable-extensions", f"--user-data-dir={tmp / 'profile'}",
           "--enable-logging=stderr", "--v=0", *args, page.resolve().as_uri()]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)


def page_errors(stderr: str) -> list[str]:
    """Lines the page itself logged: console messages and uncaught exceptions (Chromium's
    own messages about D-Bus or the GPU are not the page's)."""
    return [ln for ln in stderr.splitlines()
            if "CONSOLE" in ln or "Uncaught" in ln or "Failed to load resource" in ln]


def pdf_pages(pdf: bytes) -> list[tuple[float, float]]:
    """Each page's MediaBox (width, height) in points."""
    boxes = re.findall(rb"/Type\s*/Page\b(?!s).*?/MediaBox\s*\[\s*([\d.]+)\s+([\d.]+)\s+"
                       rb"([\d.]+)\s+([\d.]+)\s*\]", pdf, re.S)
    if not boxes:  # MediaBox before /Type in the dictionary
        boxes = re.findall(rb"/MediaBox\s*\[\s*([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s*\]",
                           pdf)
    return [(float(c) - float(a), float(d) - float(b)) for a, b, c, d in boxes]


def pdf_text(pdf: Path) -> list[str]:
    """The text of each page of a PDF, in reading order (pypdf), NFKC-normalised (the font's
    ligatures, "ﬀ", read as their letters)."""
    import unicodedata

    from pypdf import PdfReader

    return [unicodedata.normalize("NFKC", page.extract_text() or "")
            for page in PdfReader(str(pdf)).pages]


def print_pdf(page: Path, tmp: Path) -> Path:
    """``page`` printed to ``tmp/<name>.pdf`` by headless Chromium (no header or footer);
    fails the test on a browser error or an error from the page."""
    pdf = tmp / (page.stem + ".pdf")
    out = browser([f"--print-to-pdf={pdf}", "--no-pdf-header-footer"], page, tmp)
    assert out.returncode == 0, out.stderr[-2000:]
    assert page_errors(out.stderr) == [], out.stderr[-3000:]
    assert pdf.read_bytes().startswith(b"%PDF-")
    return pdf
