"""The line view in a real browser: served by uvicorn over HTTP from a real PostgreSQL with
two stations, opened in the distribution's headless Chromium (a machine without it fails):
no error from the page — its Content-Security-Policy blocks nothing it needs — the charts
are SVG in the DOM, and the archive's hostile texts stay text."""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
import uvicorn
from archive_helpers import free_port
from browser import chromium, page_errors
from line_helpers import DAY, HOSTILE_OPERATOR, HOSTILE_STATION, fill_two_stations

from benchctl.archive.store import Archive
from benchctl.web.line import create_line_app
from benchctl.web.linestations import StationBoard


@pytest.fixture
def served(line_archive: Archive, line_url: str) -> Iterator[str]:
    """The line app on a free loopback port, in a thread; its base URL."""
    fill_two_stations(line_archive)
    board = StationBoard(line_archive)
    board.publish("bench-1", "running", serial="A09", operator=HOSTILE_OPERATOR,
                  started_utc=datetime.now(UTC) - timedelta(minutes=2))
    board.publish(HOSTILE_STATION, "idle")
    port = free_port()
    server = uvicorn.Server(uvicorn.Config(create_line_app(line_url), host="127.0.0.1",
                                           port=port, log_level="warning", lifespan="on"))
    thread = threading.Thread(target=server.run, name="line-uvicorn")
    thread.start()
    deadline = time.monotonic() + 60.0
    while not server.started:  # up, or given up on
        assert thread.is_alive(), "the server stopped before it started"
        assert time.monotonic() < deadline, "the server did not start within 60 s"
        thread.join(0.05)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(60.0)
        assert not thread.is_alive()


@pytest.mark.slow
def test_line_view_in_headless_chromium(served: str, tmp_path: Path) -> None:
    url = f"{served}/line?day={DAY}&refresh=0"
    cmd = [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
           "--disable-extensions", f"--user-data-dir={tmp_path / 'profile'}",
           "--enable-logging=stderr", "--v=0", "--window-size=1280,900", "--dump-dom", url]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert out.returncode == 0, out.stderr[-2000:]
    assert page_errors(out.stderr) == [], out.stderr[-3000:]
    assert "Content-Security-Policy" not in out.stderr, out.stderr[-3000:]
    dom = out.stdout
    assert "<h1>Line view</h1>" in dom
    assert dom.count("<svg") == 4  # two part numbers: individuals and moving range each
    assert dom.count('class="point') == 11  # IN-100's 8 and IN-200's 3 σ
    assert "<script" not in dom and "<img" not in dom
    assert "&lt;script&gt;alert(\"op\")&lt;/script&gt;" in dom
    assert "&lt;svg onload=alert(2)&gt;" in dom
