"""What the line view shows, read from the archive and the stations' heartbeats: every
station's state, today's runs, the yield per station and per part number, and per part number
and axis the series of σ with its control-chart statistics (``benchctl.web.linestats``).

Days are UTC days, as in the archive (``benchctl history``). "Now" is the database's clock
(``StationBoard.read``), so the page and the staleness of the heartbeats agree whichever
computer shows the page. Language-free: the page (``benchctl.web.linepages``) says it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import date, datetime, timedelta
from typing import Any

from sqlalchemy import and_, func, select

from benchctl.archive import history as h
from benchctl.archive.rows import iso
from benchctl.archive.schema import measurements, runs
from benchctl.archive.store import Archive
from benchctl.web.linestations import (
    STALE_AFTER_S,
    Heartbeat,
    Presence,
    StationBoard,
    presence,
    transaction,
)
from benchctl.web.linestats import ChartStats, Tally, chart_stats, tally

WINDOW_DAYS = 7  # the yields' longer window
CHART_POINTS = 50  # a control chart's newest points per part number and axis


@dataclass(frozen=True)
class LastRun:
    """A station's last finished run: from its heartbeat or the archive, whichever ended
    later."""

    outcome: str | None
    serial: str | None
    run_id: str | None
    end_utc: datetime | None


@dataclass(frozen=True)
class StationLine:
    """One station's row of the line view."""

    station: str
    presence: Presence
    heartbeat: Heartbeat | None
    age_s: float | None  # of its heartbeat
    elapsed_s: float | None  # of its run in progress
    last: LastRun | None
    today: Tally


@dataclass(frozen=True)
class GroupYield:
    """The yield of one station or part number, today and over the window."""

    key: str | None  # a station, or a part number (None: none recorded)
    today: Tally
    window: Tally


@dataclass(frozen=True)
class ChartPoint:
    run_id: str
    serial: str
    station: str
    start_utc: datetime | None
    sigma: float
    outcome: str | None  # the σ measurement's outcome


@dataclass(frozen=True)
class PartChart:
    """The control chart of σ for one part number and axis, oldest point first."""

    part_number: str | None
    axis: str | None
    points: tuple[ChartPoint, ...]
    usl: float | None  # the σ limit of the newest run
    limits_differ: bool  # the runs shown were judged against more than one limit
    stats: ChartStats


@dataclass(frozen=True)
class LineView:
    archive: str  # the archive's name, password hidden
    now_utc: datetime  # the database's clock
    day: date
    window_days: int
    stale_after_s: float
    stations: tuple[StationLine, ...]
    runs_today: tuple[dict[str, Any], ...]  # Archive.history's rows
    yield_by_station: tuple[GroupYield, ...]
    yield_by_part: tuple[GroupYield, ...]
    charts: tuple[PartChart, ...]


def _day_start(d: date) -> datetime:
    return datetime(d.year, d.month, d.day)


def _verdicts_since(archive: Archive, since: datetime) -> list[Any]:
    q = (select(runs.c.station, runs.c.part_number, runs.c.outcome, runs.c.start_utc)
         .where(runs.c.start_utc >= since))
    with transaction(archive, "read the runs' verdicts") as conn:
        return list(conn.execute(q))


def _yields(rows: Sequence[Any], field: str, today: datetime,
            end: datetime) -> tuple[GroupYield, ...]:
    """The verdicts of ``rows`` (from the window's start on) per ``field``: from ``today``
    on, and all of them, up to ``end``."""
    groups: dict[str | None, tuple[list[str], list[str]]] = {}
    for r in rows:
        if r.start_utc is None or r.start_utc >= end:
            continue
        t, w = groups.setdefault(getattr(r, field), ([], []))
        w.append(r.outcome)
        if r.start_utc >= today:
            t.append(r.outcome)
    order = sorted(groups, key=lambda k: (k is None, k or ""))
    return tuple(GroupYield(k, tally(groups[k][0]), tally(groups[k][1])) for k in order)


def _last_runs(archive: Archive) -> dict[str, LastRun]:
    """Each station's newest run in the archive."""
    rank = func.row_number().over(partition_by=runs.c.station,
                                  order_by=(runs.c.start_utc.desc(), runs.c.run_id.desc()))
    inner = select(runs.c.station, runs.c.outcome, runs.c.serial, runs.c.run_id,
                   runs.c.end_utc, rank.label("rank")).subquery()
    q = select(inner).where(inner.c.rank == 1)
    with transaction(archive, "read the stations' last runs") as conn:
        return {r.station: LastRun(r.outcome, r.serial, r.run_id, r.end_utc)
                for r in conn.execute(q)}


def _newer(told: LastRun | None, archived: LastRun | None) -> LastRun | None:
    """The station's last run: what its heartbeat told, unless the archive holds a run
    that ended later (runs made without its server); an end not known loses to one known."""
    if told is None or archived is None:
        return told or archived
    if told.end_utc is None:
        return archived if archived.end_utc is not None else told
    if archived.end_utc is None or told.end_utc >= archived.end_utc:
        return told
    return archived


def _station_lines(heartbeats: Sequence[Heartbeat], last: dict[str, LastRun],
                   today: dict[str | None, Tally], now: datetime,
                   stale_after_s: float) -> tuple[StationLine, ...]:
    by_name = {h.station: h for h in heartbeats}
    out = []
    for name in sorted(set(by_name) | set(last)):
        hb = by_name.get(name)
        p = presence(hb, now, stale_after_s)
        age = None if hb is None else max(0.0, (now - hb.updated_utc).total_seconds())
        elapsed = None
        if p is Presence.RUNNING and hb is not None and hb.started_utc is not None:
            elapsed = max(0.0, (now - hb.started_utc).total_seconds())
        told = LastRun(hb.last_outcome, hb.last_serial, hb.last_run_id, hb.last_end_utc) \
            if hb is not None and hb.last_outcome is not None else None
        out.append(StationLine(name, p, hb, age, elapsed, _newer(told, last.get(name)),
                               today.get(name, tally([]))))
    return tuple(out)


def sigma_charts(archive: Archive, points: int = CHART_POINTS,
                 part_number: str | None = None) -> tuple[PartChart, ...]:
    """Per part number and axis, the newest ``points`` σ of runs that reached a verdict
    (aborted runs measured nothing to judge), oldest first, with their chart statistics."""
    key = (runs.c.part_number, measurements.c.axis)
    rank = func.row_number().over(partition_by=key,
                                  order_by=(runs.c.start_utc.desc(), runs.c.run_id.desc()))
    cond = [measurements.c.name == "sigma", measurements.c.value.is_not(None),
            runs.c.outcome != "ABORTED"]
    if part_number is not None:
        cond.append(runs.c.part_number == part_number)
    inner = (select(runs.c.part_number, measurements.c.axis, runs.c.run_id, runs.c.serial,
                    runs.c.station, runs.c.start_utc, measurements.c.value,
                    measurements.c.high, measurements.c.outcome, rank.label("rank"))
             .join(measurements, measurements.c.run_id == runs.c.run_id)
             .where(and_(*cond)).subquery())
    q = select(inner).where(inner.c.rank <= points)
    series: dict[tuple[str | None, str | None], list[Any]] = {}
    with transaction(archive, "read the σ per part number") as conn:
        for r in conn.execute(q):
            series.setdefault((r.part_number, r.axis), []).append(r)
    out = []
    for (part, axis) in sorted(series, key=lambda k: (k[0] is None, k[0] or "", k[1] or "")):
        rows = sorted(series[(part, axis)], key=lambda r: r.rank, reverse=True)
        usl = rows[-1].high
        limits = {r.high for r in rows}
        values = [float(r.value) for r in rows]
        out.append(PartChart(
            part_number=part, axis=axis,
            points=tuple(ChartPoint(r.run_id, r.serial, r.station, r.start_utc,
                                    float(r.value), r.outcome) for r in rows),
            usl=usl, limits_differ=len(limits) > 1,
            stats=chart_stats(values, usl)))
    return tuple(out)


def line_view(archive: Archive, board: StationBoard, *, day: date | None = None,
              window_days: int = WINDOW_DAYS, chart_points: int = CHART_POINTS,
              stale_after_s: float = STALE_AFTER_S) -> LineView:
    """Everything the line view shows, read now (``day``: today on the database's clock)."""
    now, beats = board.read()
    d = now.date() if day is None else day
    start, end = _day_start(d), _day_start(d) + timedelta(days=1)
    since = min(start, end - timedelta(days=window_days))
    rows = _verdicts_since(archive, since)
    today_runs = [r for r in archive.history(since=start)
                  if r["start_utc"] is not None and r["start_utc"] < iso(end)]
    by_station = _yields(rows, "station", start, end)
    last = _last_runs(archive)
    return LineView(
        archive=archive.name, now_utc=now, day=d, window_days=window_days,
        stale_after_s=stale_after_s,
        stations=_station_lines(beats, last, {g.key: g.today for g in by_station}, now,
                                stale_after_s),
        runs_today=tuple(today_runs),
        yield_by_station=by_station,
        yield_by_part=_yields(rows, "part_number", start, end),
        charts=sigma_charts(archive, chart_points),
    )


def _tally_json(t: Tally) -> dict[str, Any]:
    return {"runs": t.runs, "pass": t.passed, "fail": t.failed,
            "inconclusive": t.inconclusive, "aborted": t.aborted, "yield": t.yield_}


def _chart_json(c: PartChart) -> dict[str, Any]:
    st, lim = c.stats, c.stats.limits
    return {
        "part_number": c.part_number, "axis": c.axis, "sigma_limit": c.usl,
        "limits_differ": c.limits_differ, "n": len(c.points),
        "mean": None if lim is None else lim.centre,
        "mr_bar": None if lim is None else lim.mr_bar,
        "ucl": None if lim is None else lim.ucl, "lcl": None if lim is None else lim.lcl,
        "mr_ucl": None if lim is None else lim.mr_ucl, "s": st.s, "cpk": st.cpk,
        "points": [{"run_id": p.run_id, "serial": p.serial, "station": p.station,
                    "start_utc": iso(p.start_utc), "sigma": p.sigma, "outcome": p.outcome,
                    "beyond": i in st.beyond, "run": i in st.run}
                   for i, p in enumerate(c.points)],
    }


def _station_json(s: StationLine) -> dict[str, Any]:
    hb = s.heartbeat
    running = s.presence is Presence.RUNNING and hb is not None
    return {
        "station": s.station, "state": s.presence.value,
        "phase": hb.phase if running and hb is not None else None,
        "serial": hb.serial if running and hb is not None else None,
        "part_number": hb.part_number if running and hb is not None else None,
        "operator": hb.operator if running and hb is not None else None,
        "run_id": hb.run_id if running and hb is not None else None,
        "started_utc": iso(hb.started_utc) if running and hb is not None else None,
        "elapsed_s": s.elapsed_s, "heartbeat_utc": None if hb is None else iso(hb.updated_utc),
        "heartbeat_age_s": s.age_s,
        "last": None if s.last is None else {
            "outcome": s.last.outcome, "serial": s.last.serial, "run_id": s.last.run_id,
            "end_utc": iso(s.last.end_utc)},
        "today": _tally_json(s.today),
    }


def view_json(v: LineView) -> dict[str, Any]:
    """The line view as one JSON object (``/line/data.json``): the same figures as the page,
    the tallies with the archive's keys (``runs``, ``pass``, ``fail``, ``inconclusive``,
    ``aborted``, ``yield``)."""
    return {
        "archive": v.archive, "now_utc": iso(v.now_utc), "day": v.day.isoformat(),
        "window_days": v.window_days, "stale_after_s": v.stale_after_s,
        "stations": [_station_json(s) for s in v.stations],
        "runs_today": list(v.runs_today),
        "yield_by_station": [{"station": g.key, "today": _tally_json(g.today),
                              "window": _tally_json(g.window)} for g in v.yield_by_station],
        "yield_by_part": [{"part_number": g.key, "today": _tally_json(g.today),
                           "window": _tally_json(g.window)} for g in v.yield_by_part],
        "charts": [_chart_json(c) for c in v.charts],
    }


def history(archive: Archive, serial: str | None = None, *, station: str | None = None,
            since: datetime | None = None) -> dict[str, Any]:
    """What ``benchctl history [SERIAL] [--station S] [--since T] --json`` prints, and the
    arguments of its page (``benchctl.archive.history.html_page``): ``runs``,
    ``yield_per_day`` (the unit's, or the stations'), with a serial ``sigma`` and ``yield``
    (and ``station_yield_per_day`` with a station too), and ``page_yields``, the page's bars."""

    rows = archive.history(serial, since=since, station=station)
    listed = {r["run_id"] for r in rows}
    series = [s for s in archive.sigma_series(serial) if s["run_id"] in listed] \
        if serial else []
    stations = (archive.station_yield(station, since=since)
                if station is not None or not serial else [])
    yields = h.unit_yield_per_day(serial, rows) if serial else stations
    out: dict[str, Any] = {"archive": archive.name, "runs": rows, "yield_per_day": yields}
    if serial:
        out["sigma"] = series
        out["yield"] = h.unit_yield(serial, rows)
        if station is not None:
            out["station_yield_per_day"] = stations
    out["page_yields"] = [*yields, *stations] if serial else yields
    return out


__all__ = ["CHART_POINTS", "WINDOW_DAYS", "ChartPoint", "GroupYield", "LastRun", "LineView",
           "PartChart", "StationLine", "history", "line_view", "sigma_charts", "view_json"]
