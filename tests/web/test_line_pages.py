"""The line view and the history pages served live (FastAPI's TestClient) from a real
PostgreSQL with two stations: what each figure says, every archive text escaped, nothing
loaded from elsewhere, the history pages the same as `benchctl history` writes, the archive
out of reach said as such, the router under a prefix, every text through gettext."""

from __future__ import annotations

import gettext
import json
import re
from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from html.parser import HTMLParser
from pathlib import Path

import pytest
from archive_helpers import free_port
from fastapi import FastAPI
from fastapi.testclient import TestClient
from line_helpers import (
    DAY,
    HOSTILE_OPERATOR,
    HOSTILE_REASON,
    HOSTILE_SERIAL,
    HOSTILE_STATION,
    age_heartbeat,
    fill_two_stations,
)

from benchctl.archive.store import Archive
from benchctl.cli import main
from benchctl.web.line import LineArchive, create_line_app, line_router
from benchctl.web.linestations import StationBoard

ACTIVE = ("<script", "<img", "<svg onload", "<iframe", "<link", "@import", "url(")


class _Page(HTMLParser):
    """Tags with their attributes, and the text of chosen elements by class."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.text_by_class: dict[str, list[str]] = {}
        self._open: list[str | None] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        self.tags.append((tag, a))
        if tag not in ("meta", "line", "br", "polyline"):
            self._open.append(a.get("class"))

    def handle_endtag(self, tag: str) -> None:
        if self._open and tag not in ("meta", "line", "br", "polyline"):
            self._open.pop()

    def handle_data(self, data: str) -> None:
        for cls in self._open:
            for c in (cls or "").split():
                self.text_by_class.setdefault(c, []).append(data.strip())

    def count(self, tag: str, cls: str | None = None) -> int:
        return sum(1 for t, a in self.tags
                   if t == tag and (cls is None or cls in (a.get("class") or "").split()))


def parse(html: str) -> _Page:
    p = _Page()
    p.feed(html)
    return p


def assert_inert(html: str) -> None:
    """Nothing active from the archive's texts, and nothing loaded from elsewhere."""
    for bad in ACTIVE:
        assert bad not in html, bad
    for tag, attrs in parse(html).tags:
        for k in ("src", "href", "action"):
            v = attrs.get(k)
            assert v is None or not re.match(r"^\s*(\w+:|//)", v), (tag, k, v)


@pytest.fixture
def filled(line_archive: Archive) -> Archive:
    fill_two_stations(line_archive)
    board = StationBoard(line_archive)
    board.publish("bench-1", "running", serial="A09", part_number="IN-100",
                  operator=HOSTILE_OPERATOR, started_utc=datetime.now(UTC) - timedelta(minutes=3))
    board.publish("bench-2", "idle", last_outcome="ABORTED", last_serial="B04",
                  note="<b>waiting</b> for the operator")
    board.publish(HOSTILE_STATION, "running", serial="Z1<i>")  # shown through gettext
    age_heartbeat(line_archive, HOSTILE_STATION, 3600)
    return line_archive


# a fresh heartbeat stays fresh however loaded the machine is between its writing and the
# page (the silent station's is an hour old)
STALE_S = 600.0


@pytest.fixture
def client(filled: Archive, line_url: str) -> Iterator[TestClient]:
    with TestClient(create_line_app(line_url, stale_after_s=STALE_S)) as c:
        yield c


def test_line_view_page(client: TestClient) -> None:
    r = client.get("/line", params={"day": DAY})
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert "script-src" not in r.headers["content-security-policy"]
    assert r.headers["content-security-policy"].startswith("default-src 'none'")
    html = r.text
    assert_inert(html)
    for hostile in (HOSTILE_OPERATOR, HOSTILE_SERIAL, HOSTILE_STATION):
        assert hostile.replace("<", "&lt;").replace(">", "&gt;").replace('"', "&#34;") in html
    page = parse(html)
    assert page.count("tr", "station") == 3
    states = [t for t in page.text_by_class.get("state", []) if t]
    assert states == ["offline", "running", "idle"]  # the silent one ("<" first), bench-1, -2
    assert "was running Z1&lt;i&gt;" in html  # a value in a translated message, escaped
    assert "&lt;b&gt;waiting&lt;/b&gt; for the operator" in html
    assert page.count("tr", "run") == 5  # today's runs
    # the charts: IN-100 and IN-200 (roll), each an individuals and a moving-range chart
    assert page.count("svg", "individuals") == 2 and page.count("svg", "moving-range") == 2
    assert page.text_by_class["mean"][0] == "0.315"
    assert page.text_by_class["cpk"][0] == "0.51"  # 0.085 / (3 √(0.0214/7))
    assert page.count("line", "line-usl") == 2
    assert "Western Electric rule 1" in html and "Western Electric rule 4" in html
    assert "Cpk = (σ limit − mean) / (3 s)" in html
    yields = page.text_by_class["yield-station"]
    assert "80 %" in yields and "50 %" in yields
    assert '<meta http-equiv="refresh" content="10">' in html


def test_line_view_links_to_the_history_pages(client: TestClient) -> None:
    page = parse(client.get("/line", params={"day": DAY, "refresh": 0}).text)
    links = [a["href"] for t, a in page.tags if t == "a" and a.get("href")]
    unit = next(h for h in links if h is not None and "B03" in h)
    assert unit.startswith("/history?serial=B03%22%3E%3Cimg")  # the serial, encoded
    r = client.get(unit)
    assert r.status_code == 200
    assert_inert(r.text)
    assert "unit B03&#34;&gt;&lt;img src=x onerror=alert(1)&gt;" in r.text
    station = next(h for h in links if h is not None and "station=%3Csvg" in h)
    assert client.get(station).status_code == 200


def test_history_pages_are_the_commands(client: TestClient, line_url: str, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    def same(served: str, written: str) -> None:
        made = re.compile(r"made \d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00")
        assert made.sub("made …", served) == made.sub("made …", written)

    for args in ([], ["A07"], ["--station", "bench-2"], ["A07", "--station", "bench-1"],
                 ["--since", "2026-11-20"]):
        out = tmp_path / "h.html"
        assert main(["history", *args, "--url", line_url, "--html", str(out)]) == 0
        capsys.readouterr()
        q: dict[str, str] = {}
        if args and not args[0].startswith("--"):
            q["serial"] = args[0]
        for k in ("station", "since"):
            if f"--{k}" in args:
                q[k] = args[args.index(f"--{k}") + 1]
        r = client.get("/history", params=q)
        assert r.status_code == 200
        same(r.text, out.read_text(encoding="utf-8"))
        assert main(["history", *args, "--url", line_url, "--json"]) == 0
        assert client.get("/history.json", params=q).json() == json.loads(capsys.readouterr().out)
    html = client.get("/history").text
    assert_inert(html)
    assert HOSTILE_REASON not in html and "&lt;/td&gt;&lt;/tr&gt;" in html


def test_line_data_json(client: TestClient) -> None:
    d = client.get("/line/data.json", params={"day": DAY}).json()
    assert d["day"] == DAY and d["window_days"] == 7
    assert [s["state"] for s in d["stations"]] == ["offline", "running", "idle"]
    gone, b1, b2 = d["stations"]
    assert gone["serial"] is None and gone["heartbeat_age_s"] >= 3600
    assert (b1["serial"], b1["part_number"], b1["operator"]) == ("A09", "IN-100",
                                                                 HOSTILE_OPERATOR)
    assert 170 <= b1["elapsed_s"] < 180 + 300  # 3 min, on a loaded machine
    assert b2["last"]["outcome"] == "ABORTED" and b2["today"] == {
        "runs": 3, "pass": 1, "fail": 0, "inconclusive": 1, "aborted": 1, "yield": 0.5}
    assert [(g["part_number"], g["window"]["runs"], g["window"]["yield"])
            for g in d["yield_by_part"]] == [("IN-100", 6, pytest.approx(5 / 6)),
                                             ("IN-200", 4, pytest.approx(1 / 3))]
    assert [r["serial"] for r in d["runs_today"]][:2] == ["A06", "A07"]
    c100 = d["charts"][0]
    assert (c100["part_number"], c100["axis"], c100["n"]) == ("IN-100", "roll", 8)
    assert c100["mean"] == pytest.approx(0.315, abs=1e-9)
    assert c100["ucl"] == pytest.approx(0.315 + 2.66 * 0.38 / 7, abs=1e-9)
    assert c100["sigma_limit"] == 0.4 and not any(p["beyond"] for p in c100["points"])


def test_bad_queries(client: TestClient) -> None:
    r = client.get("/history", params={"since": "<b>soon</b>"})
    assert r.status_code == 400 and "&lt;b&gt;soon" in r.text and "<b>" not in r.text
    assert client.get("/history.json", params={"since": "x"}).status_code == 400
    assert client.get("/line", params={"days": 0}).status_code == 422
    assert client.get("/line", params={"day": "tomorrow"}).status_code == 422
    r = client.get("/", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/line"


def test_a_drifting_batch_is_flagged_on_the_page(line_archive: Archive, line_url: str) -> None:
    from line_helpers import record

    stable = [0.28, 0.29, 0.27, 0.28, 0.30, 0.27, 0.29, 0.28, 0.27, 0.29, 0.28, 0.30]
    drift = [0.31, 0.32, 0.32, 0.33, 0.33, 0.34, 0.34, 0.35]
    for i, s in enumerate(stable + drift):
        line_archive.store(record(i, f"2026-11-{1 + i:02d}T08:00", "bench-1", f"C{i:02d}",
                                  "IN-300", "PASS", s, 0.4))
    with TestClient(create_line_app(line_url)) as c:
        page = parse(c.get("/line", params={"refresh": 0}).text)
    assert page.count("circle", "point") == 20
    assert page.count("circle", "run") == 20  # 12 under the centre, then 8 above it
    assert page.count("circle", "beyond") >= 1
    assert page.count("li") == 20  # each flagged point listed
    assert float(page.text_by_class["cpk"][0]) < 1.33


def test_archive_out_of_reach_is_a_503_page() -> None:
    url = f"postgresql+psycopg://bench@127.0.0.1:{free_port()}/nowhere"
    with TestClient(create_line_app(url)) as c:
        r = c.get("/line")
        assert r.status_code == 503 and "unreachable" in r.text
        assert "The archive cannot be read" in r.text
        assert c.get("/history").status_code == 503
        j = c.get("/line/data.json")
        assert j.status_code == 503 and j.json()["kind"] == "unreachable"


def test_router_under_a_prefix(filled: Archive, line_url: str) -> None:
    source = LineArchive(line_url)
    app = FastAPI()
    app.include_router(line_router(source, stale_after_s=STALE_S), prefix="/station")
    try:
        with TestClient(app) as c:
            page = parse(c.get("/station/line", params={"day": DAY}).text)
            hrefs = [a["href"] for t, a in page.tags if t == "a" and a.get("href")]
            assert hrefs and all(h is not None and h.startswith("/station/history")
                                 for h in hrefs)
            assert c.get(hrefs[0]).status_code == 200
    finally:
        source.close()


# what the pages show untranslated: verdicts (the record's values) and symbols
SYMBOLS = r"\s*(PASS|FAIL|INCONCLUSIVE|ABORTED|σ|s|MR̄|Cpk)\s*"


class _Marked(gettext.NullTranslations):
    """A translation that marks every message it is asked for."""

    def gettext(self, message: str) -> str:
        return f"⟦{message}⟧"

    def ngettext(self, msgid1: str, msgid2: str, n: int) -> str:
        return f"⟦{msgid1 if n == 1 else msgid2}⟧"


def test_every_heading_goes_through_gettext(filled: Archive, line_url: str) -> None:
    source = LineArchive(line_url)
    app = FastAPI()
    app.include_router(line_router(source, translations=_Marked(), lang="xx"))
    try:
        with TestClient(app) as c:
            html = c.get("/line", params={"day": DAY}).text
            bad = c.get("/history", params={"since": "x"}).text
    finally:
        source.close()
    assert '<html lang="xx">' in html
    head = html.split("</head>")[0]
    assert re.search(r"<title>⟦.*⟧</title>", head)
    for tag in ("h1", "h2", "h3", "th", "dt"):
        for text in re.findall(rf"<{tag}[^>]*>(.*?)</{tag}>", html, re.S):
            if text.strip() and not re.fullmatch(SYMBOLS, text):
                assert "⟦" in text, (tag, text)
    assert "⟦Bad request⟧" in bad and "⟦since = " in bad


def test_a_part_number_with_one_run(line_archive: Archive, line_url: str) -> None:
    from line_helpers import record

    line_archive.store(record(0, "2026-11-20T08:00", "bench-1", "D1", "IN-400", "PASS", 0.2,
                              0.4))
    with TestClient(create_line_app(line_url)) as c:
        html = c.get("/line", params={"day": DAY}).text
    page = parse(html)
    assert page.count("svg", "individuals") == 1 and page.count("svg", "moving-range") == 0
    assert "One point: no control limits yet" in html
    assert page.text_by_class["cpk"][0] == "—"
    assert page.count("line", "line-usl") == 1 and page.count("line", "line-ucl") == 0
