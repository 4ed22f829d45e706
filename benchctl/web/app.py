"""The station panel's web application (FastAPI): the station page, its live events
(server-sent events) and the few requests that change anything — start, stop, put away a
verdict — each checked against cross-site use (``benchctl.web.security``).

Everything the browser loads comes from this package (``templates/``, ``static/``); the
Content-Security-Policy header forbids anything else, so a page that tried would fail loudly.
"""

from __future__ import annotations

import asyncio
import contextlib
import urllib.parse
from collections.abc import AsyncIterator, Awaitable, Callable
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request, Response
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, RedirectResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel
from starlette.responses import StreamingResponse

from benchctl import __version__
from benchctl.archive.service import settings_for
from benchctl.config import load_config
from benchctl.errors import InputError
from benchctl.text import OPERATOR_MAX, SERIAL_MAX, check_operator, check_serial
from benchctl.web.i18n import script_texts, translations
from benchctl.web.line import LineArchive, line_router
from benchctl.web.lineheartbeat import HeartbeatPublisher
from benchctl.web.linepages import environment
from benchctl.web.panelrun import Run
from benchctl.web.runstate import state_path
from benchctl.web.security import Guard
from benchctl.web.settings import PanelSettings
from benchctl.web.station import Station, sse
from benchctl.web.station_beat import beat_of
from benchctl.web.wording import _

HERE = Path(__file__).parent
COOKIE = "benchctl_panel"
KEEPALIVE_S = 15.0
#: the panel's pages: nothing from anywhere but the panel, no inline script or style
CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; "
       "connect-src 'self'; form-action 'self'; frame-ancestors 'none'; base-uri 'none'")
#: a run's report (benchctl.report: one self-contained file, its styles inline)
REPORT_CSP = ("default-src 'none'; style-src 'unsafe-inline'; img-src 'self' data:; "
              "frame-ancestors 'none'; base-uri 'none'; form-action 'none'")
OPEN_PATHS = ("/login", "/static/", "/favicon.ico")
LOGIN_MAX_BYTES = 4096  # the login form: a token and a CSRF token (urlencoded)


class Refused(Exception):
    """A value the form sent refused: ``text`` in the operator's language, ``detail`` the
    check's own English."""

    def __init__(self, text: str, detail: str) -> None:
        super().__init__(detail)
        self.text = text
        self.detail = detail


class SerialIn(BaseModel):
    serial: str


class StartIn(BaseModel):
    serial: str
    operator: str
    profile: str  # a key of the page's list: "0", "1"… a profile, "plan-0"… a plan


class AnswerIn(BaseModel):
    id: int
    yes: bool


def _error(status: int, text: str, detail: str = "") -> JSONResponse:
    """A refused request: ``error`` in the operator's language, ``detail`` the technical
    English (shown as a secondary line)."""
    return JSONResponse({"error": text, "detail": detail}, status_code=status)


def create_app(settings: PanelSettings) -> FastAPI:
    """The panel for one station (``settings``); its runs start as child processes."""
    cfg = load_config(settings.config)
    pattern = cfg.unit.serial_pattern
    pattern_where = f"unit.serial_pattern of {settings.config}"
    profiles = {str(i): p for i, p in enumerate(settings.profiles)}
    plans = {f"plan-{i}": p for i, p in enumerate(settings.plans)}
    guard = Guard(settings.token_scrypt, require_token=settings.require_token,
                  origins=settings.origins)
    # the line view beside the panel, and this station's heartbeat into the same archive (the
    # runs' own: the config's archive: section, else the SQLite file in the output folder)
    source = LineArchive(settings_for(cfg, settings.out_dir).url)
    beat = HeartbeatPublisher(source.publish, cfg.station)

    def heartbeat(run: Run) -> None:
        state, fields = beat_of(run, cfg.unit.part_number)
        beat.set(state, **fields)

    # the current run kept in the station's working folder (the runs' output folder), for a
    # panel started again to take it up (benchctl.web.runstate)
    out_dir = settings.out_dir if settings.out_dir is not None else cfg.run.output_dir
    station = Station(settings, on_change=heartbeat,
                      state_file=state_path(Path(out_dir), settings.port))
    w = station.words
    env = environment(translations(settings.lang))  # the web pages' one Jinja2 environment
    texts = script_texts(settings.lang)
    busy_text = _("A run is going on at this station: one run per stand.")

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        beat.start()
        await station.resume()  # a run left going by an earlier panel, or its verdict
        try:
            yield
        finally:
            await station.close()
            beat.stop()  # the last state once more (a thread of its own; bounded wait)
            source.close()

    app = FastAPI(title="benchctl station panel", version=__version__, lifespan=lifespan,
                  docs_url=None, redoc_url=None, openapi_url=None)
    app.state.station = station
    app.state.guard = guard
    app.mount("/static", StaticFiles(directory=HERE / "static"), name="static")
    # /line, /history: behind the same access rules, in the station's language
    app.include_router(line_router(source, translations=translations(settings.lang),
                                   lang=settings.lang))

    def page(name: str, request: Request, **values: Any) -> HTMLResponse:
        session = request.cookies.get(COOKIE)
        html = env.get_template(name).render(
            lang=settings.lang, csrf=guard.csrf_token(session), station=cfg.station,
            version=__version__, **values)
        return HTMLResponse(html)

    @app.middleware("http")
    async def checks(request: Request,
                     call_next: Callable[[Request], Awaitable[Response]]) -> Response:
        host = request.headers.get("host", "")
        path = request.url.path
        if not guard.host_allowed(host):
            return _headers(Response(
                w(_("This address is not served: open the panel by its own address.")) +
                f" (host {host!r})", status_code=400, media_type="text/plain"))
        if request.method not in ("GET", "HEAD"):
            cross = w(_("Refused: the request did not come from this panel's page."))
            if not guard.origin_ok(request.headers.get("origin"),
                                   request.headers.get("referer"), host):
                return _headers(_error(403, cross, "cross-site request refused (Origin)"))
            if path.startswith("/api/") and not guard.csrf_ok(
                    request.cookies.get(COOKIE), request.headers.get("x-csrf-token")):
                return _headers(_error(403, cross, "cross-site request refused (CSRF token)"))
        if not path.startswith(OPEN_PATHS) and not guard.authenticated(
                request.cookies.get(COOKIE)):
            if path.startswith("/api/"):
                return _headers(_error(401, w(_("Log in first.")), "log in first"))
            return _headers(RedirectResponse("/login", status_code=303))
        response = await call_next(request)
        return _headers(response, report=path.startswith("/runs/"))  # a page's own kept

    @app.get("/", response_class=HTMLResponse)
    async def index(request: Request) -> HTMLResponse:
        data = {"texts": texts, "csrf": guard.csrf_token(request.cookies.get(COOKIE)),
                "limit": cfg.run.limit_sigma_deg}
        return page("station/station.html.j2", request, profiles=[
            (key, p.stem) for key, p in profiles.items()],
            plans=[(key, p.stem) for key, p in plans.items()],
            duration=settings.duration_s, serial_pattern=pattern,
            data=data, auth=guard.require_token)

    @app.get("/login", response_class=HTMLResponse)
    async def login_page(request: Request) -> HTMLResponse:
        return page("station/login.html.j2", request, failed=False)

    @app.post("/login")
    async def login(request: Request) -> Response:
        body = await request.body()
        if len(body) > LOGIN_MAX_BYTES:
            return _error(413, w(_("The request is too large.")), "request too large")
        form = urllib.parse.parse_qs(body.decode("utf-8", "replace"))
        session = request.cookies.get(COOKIE)
        if not guard.csrf_ok(session, (form.get("csrf") or [""])[0]):
            return _error(403, w(_("Refused: the request did not come from this panel's page.")),
                          "cross-site request refused (CSRF token)")
        sid = guard.login((form.get("token") or [""])[0])
        if sid is None:
            refused = page("station/login.html.j2", request, failed=True)
            refused.status_code = 401
            return refused
        resp = RedirectResponse("/", status_code=303)
        resp.set_cookie(COOKIE, sid, httponly=True, samesite="strict",
                        secure=any(o.startswith("https:") for o in guard.origins))
        return resp

    @app.post("/api/logout")
    async def logout(request: Request) -> JSONResponse:
        guard.logout(request.cookies.get(COOKIE))
        resp = JSONResponse({"ok": True})
        resp.delete_cookie(COOKIE)
        return resp

    @app.get("/api/status")
    async def status(trace: int = 0) -> JSONResponse:
        """The station's state as JSON (scripts, tests); the plot's points only when asked
        (``?trace=N``: the last N; the page gets them with its event stream)."""
        return JSONResponse(station.status(max(0, min(trace, 3000))))

    def serial_of(value: str) -> str:
        try:
            return check_serial(value, "serial", pattern, pattern_where)
        except InputError as e:
            raise Refused(w.refused_text("serial", value, SERIAL_MAX, pattern), str(e)) from None

    def operator_of(value: str) -> str:
        try:
            return check_operator(value, "operator")
        except InputError as e:
            raise Refused(w.refused_text("operator", value, OPERATOR_MAX), str(e)) from None

    @app.post("/api/check-serial")
    async def check(body: SerialIn) -> JSONResponse:
        try:
            serial = serial_of(body.serial)
        except Refused as e:
            return _error(400, e.text, e.detail)
        return JSONResponse({"serial": serial})

    @app.post("/api/start")
    async def start(body: StartIn) -> JSONResponse:
        try:
            serial = serial_of(body.serial)
            operator = operator_of(body.operator)
            if body.profile not in profiles and body.profile not in plans:
                return _error(400, w(_("This profile is not one this station offers.")),
                              f"profile {body.profile!r}: not one this station offers")
            if station.busy:
                return _error(409, w(busy_text))
            if body.profile in plans:
                run = await station.start(serial, operator, plans[body.profile], kind="plan")
            else:
                run = await station.start(serial, operator, profiles[body.profile])
        except Refused as e:
            return _error(400, e.text, e.detail)
        except InputError as e:  # two Starts at once: the other one started
            return _error(409, w(busy_text), str(e))
        except OSError as e:  # the child could not be started
            return _error(500, w(_("The run could not be started.")), str(e))
        return JSONResponse({"id": run.id})

    @app.post("/api/stop")
    async def stop() -> JSONResponse:
        if not station.stop():
            return _error(409, w(_("No run is going on.")))
        return JSONResponse({"ok": True})

    @app.post("/api/answer")
    async def answer(body: AnswerIn) -> JSONResponse:
        if not station.answer(body.id, body.yes):
            return _error(409, w(_("This question is no longer waiting for an answer.")))
        return JSONResponse({"ok": True})

    @app.post("/api/dismiss")
    async def dismiss() -> JSONResponse:
        if not station.dismiss():
            return _error(409, w(busy_text))
        return JSONResponse({"ok": True})

    @app.get("/favicon.ico")
    async def favicon() -> FileResponse:  # asked for by pages without an icon of their own
        return FileResponse(HERE / "static" / "favicon.svg", media_type="image/svg+xml")

    @app.get("/runs/{run_id}/report")
    async def report(run_id: int) -> Response:
        return _report(station.report_file(run_id))

    @app.get("/runs/{run_id}/steps/{step}/report")
    async def step_report(run_id: int, step: int) -> Response:
        return _report(station.report_file(run_id, step))

    def _report(path: Path | None) -> Response:
        if path is None:
            return Response(w(_("There is no report for this run.")), status_code=404,
                            media_type="text/plain")
        return FileResponse(path, media_type="text/html")

    @app.get("/api/events")
    async def events(request: Request) -> StreamingResponse:
        return StreamingResponse(_stream(station, request), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store",
                                          "X-Accel-Buffering": "no"})

    return app


async def _stream(station: Station, request: Request) -> AsyncIterator[str]:
    """One browser's events: the whole state, then each change; the whole state again after
    the browser fell behind; a comment now and then so proxies keep the line open."""
    watcher = station.watch()
    try:
        yield sse("status", station.status())
        while not await request.is_disconnected():
            try:
                text = await asyncio.wait_for(watcher.queue.get(), KEEPALIVE_S)
            except TimeoutError:
                yield ": keepalive\n\n"
                continue
            if watcher.stale:
                watcher.stale = False
                while not watcher.queue.empty():
                    watcher.queue.get_nowait()
                yield sse("status", station.status())
                continue
            yield text
    finally:
        station.unwatch(watcher)


def _headers(response: Response, report: bool = False) -> Response:
    """The panel's security headers, where the response has none of its own (the line view's
    pages bring their own policy)."""
    h = response.headers
    h.setdefault("Content-Security-Policy", REPORT_CSP if report else CSP)
    h.setdefault("X-Content-Type-Options", "nosniff")
    h.setdefault("Referrer-Policy", "same-origin")
    h.setdefault("X-Frame-Options", "DENY")
    return response
