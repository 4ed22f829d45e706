"""The line view and the archive's history pages, served live: a FastAPI router for the
station server to include, and a minimal app of its own.

For the station server (``benchctl serve``)::

    from benchctl.web.line import LineArchive, line_router
    from benchctl.web.lineheartbeat import HeartbeatPublisher
    from benchctl.web.linestations import StationState

    line = LineArchive(settings.url)            # the bench's archive; opened on first use
    app.include_router(line_router(line))       # GET /line, /line/data.json, /history, …
    ...                                         # at shutdown (its lifespan): line.close()

    beat = HeartbeatPublisher(line.publish, "bench-2")    # benchctl.web.lineheartbeat
    beat.start()                                # idle, published at once, then every 5 s
    beat.set(StationState.RUNNING, serial="INC-0042", part_number="IN-100", operator="anna",
             run_id=run_id, started_utc=start, phase="ramp-in")      # on each change
    beat.set(StationState.IDLE, last_outcome="PASS", last_serial="INC-0042",
             last_run_id=run_id, last_end_utc=end)
    ...                                         # at shutdown: beat.stop()

``HeartbeatPublisher`` publishes from its own thread and logs a database out of reach: the
server never waits for it. ``StationBoard.publish`` (or ``publish_station_state(url, …)``,
one-off) is the call underneath, raising ``ArchiveError`` when it cannot write.

Routes (their names for ``request.url_for``):

- ``GET /line`` (``line_view``): every station's state, today's runs, the yield per station and
  per part number, the control charts of σ per part number; ``?day=YYYY-MM-DD`` another UTC
  day, ``?days=N`` the yields' window, ``?points=N`` a chart's points, ``?refresh=S`` the
  page's own reload (0: none);
- ``GET /line/data.json`` (``line_data``): the same as JSON;
- ``GET /history`` (``history_page``): the history page of ``benchctl history --html``,
  ``?serial=``, ``?station=``, ``?since=`` as its options;
- ``GET /history.json`` (``history_data``): ``benchctl history --json``.

Every page is self-contained HTML (inline CSS and SVG, no script, no external resource),
every value escaped (Jinja2 autoescape), sent with a Content-Security-Policy that allows no
script and nothing from elsewhere. The archive out of reach is a 503 page saying so.
``create_line_app(url)`` is the router alone in an app (``/`` → ``/line``), for a desk
without a station and for the tests.
"""

from __future__ import annotations

import gettext
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from datetime import date
from typing import Any

from fastapi import APIRouter, FastAPI, Query, Request
from fastapi.responses import HTMLResponse, JSONResponse, RedirectResponse, Response

from benchctl.archive.history import html_page
from benchctl.archive.rows import utc_naive
from benchctl.archive.store import Archive, shown
from benchctl.clock import REAL, LockLike
from benchctl.errors import ArchiveError
from benchctl.jsonout import plain
from benchctl.web import linedata
from benchctl.web.linepages import environment, render_line
from benchctl.web.linestations import STALE_AFTER_S, StationBoard, StationState

CSP = ("default-src 'none'; style-src 'unsafe-inline'; img-src 'self'; "
       "base-uri 'none'; form-action 'self'; frame-ancestors 'self'")
HEADERS = {"Content-Security-Policy": CSP, "X-Content-Type-Options": "nosniff",
           "Referrer-Policy": "same-origin", "Cache-Control": "no-store"}
PAGE_BUSY_TIMEOUT_S = 10.0  # a page waits this long for a lock, as `benchctl history` does


class LineArchive:
    """The archive the pages read, opened on first use — and again on the next request
    after it could not be (a station server starts whether or not the database answers).
    ``close()`` at the server's shutdown. Thread-safe."""

    def __init__(self, url: str, *, connect_timeout_s: float = 2.0,
                 busy_timeout_s: float = PAGE_BUSY_TIMEOUT_S) -> None:
        self.url = url
        self.name = shown(url)
        self._connect_timeout_s = connect_timeout_s
        self._busy_timeout_s = busy_timeout_s
        self._archive: Archive | None = None
        self._board: StationBoard | None = None
        self._lock: LockLike = REAL.lock()

    def get(self) -> tuple[Archive, StationBoard]:
        """The open archive and its stations' board (``ArchiveError`` when it cannot be
        opened now)."""
        with self._lock:
            if self._archive is None:
                a = Archive(self.url, connect_timeout_s=self._connect_timeout_s,
                            busy_timeout_s=self._busy_timeout_s)
                self._archive, self._board = a, StationBoard(a)
            assert self._board is not None
            return self._archive, self._board

    def publish(self, station: str, state: StationState | str, **fields: Any) -> None:
        """``StationBoard.publish`` on this archive, opened first when it is not yet
        (``ArchiveError`` when it cannot be): what ``HeartbeatPublisher`` calls."""
        self.get()[1].publish(station, state, **fields)

    def close(self) -> None:
        with self._lock:
            if self._archive is not None:
                self._archive.close()
            self._archive = self._board = None


def _html(body: str, status: int = 200) -> HTMLResponse:
    return HTMLResponse(body, status_code=status, headers=HEADERS)


def _json(value: Any, status: int = 200) -> JSONResponse:
    return JSONResponse(plain(value), status_code=status, headers=HEADERS)


def line_router(source: LineArchive, *, stale_after_s: float = STALE_AFTER_S,
                refresh_s: int = 10, translations: gettext.NullTranslations | None = None,
                lang: str = "en") -> APIRouter:
    """The routes above, reading ``source``. ``stale_after_s``: a station silent this long is
    offline; ``refresh_s``: the line view's own reload; ``translations``/``lang``: the pages'
    language (``benchctl.web.linepages.environment``)."""
    env = environment(translations)
    _ = (translations if translations is not None else gettext.NullTranslations()).gettext
    router = APIRouter()

    def error_page(title: str, message: str, status: int, archive_error: bool) -> HTMLResponse:
        page = env.get_template("line/error.html.j2").render(
            title=title, message=message, archive_error=archive_error, lang=lang)
        return _html(page, status)

    def unreadable(e: ArchiveError) -> HTMLResponse:
        return error_page(_("The archive cannot be read"), str(e), 503, True)

    def history_link(request: Request) -> Callable[..., str]:
        def link(serial: str | None = None, station: str | None = None) -> str:
            q = {k: v for k, v in (("serial", serial), ("station", station)) if v is not None}
            u = request.url_for("history_page").include_query_params(**q)
            return u.path + (f"?{u.query}" if u.query else "")
        return link

    def view(day: date | None, days: int, points: int) -> linedata.LineView:
        archive, board = source.get()
        return linedata.line_view(archive, board, day=day, window_days=days,
                                  chart_points=points, stale_after_s=stale_after_s)

    @router.get("/line", name="line_view", response_class=HTMLResponse)
    def line_page(request: Request, day: date | None = None,
                  days: int = Query(linedata.WINDOW_DAYS, ge=1, le=366),
                  points: int = Query(linedata.CHART_POINTS, ge=2, le=1000),
                  refresh: int = Query(refresh_s, ge=0, le=3600)) -> Response:
        try:
            v = view(day, days, points)
        except ArchiveError as e:
            return unreadable(e)
        return _html(render_line(v, history_url=history_link(request), refresh_s=refresh,
                                 env=env, lang=lang))

    @router.get("/line/data.json", name="line_data")
    def line_data(day: date | None = None,
                  days: int = Query(linedata.WINDOW_DAYS, ge=1, le=366),
                  points: int = Query(linedata.CHART_POINTS, ge=2, le=1000)) -> Response:
        try:
            return _json(linedata.view_json(view(day, days, points)))
        except ArchiveError as e:
            return _json({"error": str(e), "kind": e.kind}, 503)

    def since_of(since: str | None) -> Any:
        if since is None:
            return None
        d = utc_naive(since)
        if d is None:
            raise ValueError(since)
        return d

    def bad_since(since: str) -> str:
        return _("since = %(value)r: expected a date YYYY-MM-DD or an ISO time "
                 "YYYY-MM-DDTHH:MM[:SS][+00:00]") % {"value": since}

    @router.get("/history", name="history_page", response_class=HTMLResponse)
    def history_page(serial: str | None = None, station: str | None = None,
                     since: str | None = None) -> Response:
        try:
            t = since_of(since)
        except ValueError:
            return error_page(_("Bad request"), bad_since(str(since)), 400, False)
        try:
            archive = source.get()[0]
            h = linedata.history(archive, serial, station=station, since=t)
        except ArchiveError as e:
            return unreadable(e)
        return _html(html_page(h["runs"], archive=h["archive"], serial=serial,
                               sigma_series=h.get("sigma", []), yields=h["page_yields"],
                               station=station, since=None if t is None else t.isoformat()))

    @router.get("/history.json", name="history_data")
    def history_data(serial: str | None = None, station: str | None = None,
                     since: str | None = None) -> Response:
        try:
            t = since_of(since)
        except ValueError:
            return _json({"error": bad_since(str(since))}, 400)
        try:
            archive = source.get()[0]
            h = linedata.history(archive, serial, station=station, since=t)
        except ArchiveError as e:
            return _json({"error": str(e), "kind": e.kind}, 503)
        h.pop("page_yields")
        return _json(h)

    return router


def create_line_app(url: str, **router_options: Any) -> FastAPI:
    """The line view and the history pages alone in an app (``/`` leads to ``/line``); the
    archive at ``url`` opened on the first request and closed at shutdown.
    ``router_options``: ``line_router``'s."""
    source = LineArchive(url)

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        try:
            yield
        finally:
            source.close()

    app = FastAPI(title="benchctl line view", lifespan=lifespan, docs_url=None,
                  redoc_url=None, openapi_url=None)
    app.include_router(line_router(source, **router_options))

    @app.get("/", include_in_schema=False)
    def home(request: Request) -> RedirectResponse:
        return RedirectResponse(request.url_for("line_view").path, status_code=303)

    return app


__all__ = ["CSP", "LineArchive", "create_line_app", "line_router"]
