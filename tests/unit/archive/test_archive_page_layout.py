"""The history page's charts and table: runs on one day get distinct x labels (their times, not
one date repeated), a day's aborted runs are visible beside its yield bar, and a long abort
reason wraps inside the table instead of pushing it off a 1280 px wide page (measured in
headless Chromium)."""

from __future__ import annotations

import re
from html.parser import HTMLParser
from pathlib import Path

import pytest
from archive_helpers import make_record
from browser import browser, page_errors

from benchctl.archive.history import run_labels
from benchctl.archive.store import Archive
from benchctl.cli import main

LONG_REASON = ("stand loop: StandFault: modbus-tcp 10.20.30.40:502 unit 1: stand fault 10 "
               "(servo amplifier overcurrent on axis roll; the drive reports "
               + "x" * 60 + ") while ramping to zero after the heartbeat watchdog " * 3)


class _Svg(HTMLParser):
    """The x labels of the σ chart and the rects and texts of the yield chart."""

    def __init__(self) -> None:
        super().__init__()
        self.svg = 0
        self.texts: list[list[str]] = []  # per svg
        self.rects: list[list[str]] = []
        self._in_text = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "svg":
            self.svg += 1
            self.texts.append([])
            self.rects.append([])
        elif tag == "rect" and self.svg:
            self.rects[-1].append(a.get("class") or "")
        self._in_text = tag == "text"

    def handle_endtag(self, tag: str) -> None:
        if tag == "text":
            self._in_text = False

    def handle_data(self, data: str) -> None:
        if self._in_text and self.svg:
            self.texts[-1].append(data.strip())


def _store(url: str) -> None:
    with Archive(url) as a:
        for i, (hour, outcome) in enumerate([("08:02", "PASS"), ("09:15", "FAIL"),
                                             ("11:40", "ABORTED"), ("14:05", "PASS")]):
            abort = {"kind": "equipment", "reason": LONG_REASON} if outcome == "ABORTED" \
                else None
            a.store(make_record(f"20261120T{hour.replace(':', '')}00Z_INC-9", serial="INC-9",
                                outcome=outcome, sigma=0.3 + 0.01 * i, abort=abort,
                                start=f"2026-11-20T{hour}:00.000+00:00"))
        a.store(make_record("20261121T080000Z_INC-9", serial="INC-9", outcome="ABORTED",
                            abort={"kind": "operator", "reason": "interrupted by SIGINT"},
                            start="2026-11-21T08:00:00.000+00:00"))


def test_run_labels_are_distinct() -> None:
    days = ["2026-11-20T08:02:00.000+00:00", "2026-11-21T08:02:00.000+00:00"]
    assert run_labels(days) == ["2026-11-20", "2026-11-21"]
    one_day = ["2026-11-20T08:02:00.000+00:00", "2026-11-20T09:15:00.000+00:00"]
    assert run_labels(one_day) == ["11-20 08:02", "11-20 09:15"]
    one_minute = ["2026-11-20T08:02:01.000+00:00", "2026-11-20T08:02:30.000+00:00"]
    assert run_labels(one_minute) == ["11-20 08:02:01", "11-20 08:02:30"]
    same = ["2026-11-20T08:02:01.000+00:00"] * 3
    assert run_labels(same) == ["11-20 08:02 #1", "11-20 08:02 #2", "11-20 08:02 #3"]


def test_history_page_labels_aborted_runs_and_a_long_reason(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    url = f"sqlite:///{tmp_path / 'archive.sqlite'}"
    _store(url)
    page = tmp_path / "h.html"
    assert main(["history", "INC-9", "--url", url, "--html", str(page)]) == 0
    capsys.readouterr()
    html = page.read_text(encoding="utf-8")
    svg = _Svg()
    svg.feed(html)
    assert svg.svg == 2  # σ over the runs, the unit's yield per day
    # σ chart: the four runs on 2026-11-20 each with its own time (was "2026-11-20" × 4)
    labels = [t for t in svg.texts[0] if re.fullmatch(r"\d\d-\d\d \d\d:\d\d", t)]
    assert labels == ["11-20 08:02", "11-20 09:15", "11-20 11:40", "11-20 14:05",
                      "11-21 08:00"]
    # yield chart: a grey bar for each day with aborted runs, with its count; a day of only
    # aborted runs has no yield but its aborted runs show
    assert svg.rects[1].count("yield") == 2 and svg.rects[1].count("aborted") == 2
    assert svg.texts[1].count("1 ab.") == 2
    assert "2026-11-21: 1 run(s): 0 pass, 0 fail, 0 inconclusive, 1 aborted" in html
    assert "grey: aborted runs" in html

    # the table inside a 1280 px page: a copy of the page that measures itself (the page
    # has no script of its own)
    probe = tmp_path / "probe.html"
    probe.write_text(html.replace("</body>", (
        "<script>const t = document.querySelector('table');"
        "document.body.setAttribute('data-table-right', "
        "String(Math.ceil(t.getBoundingClientRect().right)));"
        "document.body.setAttribute('data-page-width', "
        "String(document.documentElement.scrollWidth));</script></body>")),
        encoding="utf-8")
    dom = browser(["--window-size=1280,900", "--dump-dom"], probe, tmp_path)
    assert dom.returncode == 0, dom.stderr[-2000:]
    assert page_errors(dom.stderr) == [], dom.stderr[-3000:]
    right = re.search(r'data-table-right="(\d+)"', dom.stdout)
    width = re.search(r'data-page-width="(\d+)"', dom.stdout)
    assert right and width, dom.stdout[-2000:]
    assert int(width.group(1)) <= 1280 and int(right.group(1)) <= 1280, (right, width)
    assert LONG_REASON.strip()[:60] in dom.stdout  # the reason is there, whole, wrapped
