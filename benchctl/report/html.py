"""``report.html``: the run's report as one self-contained HTML file in its recording folder.

Rendered with Jinja2 (autoescaping on: a serial or a note typed with ``<`` or ``&`` is shown,
never interpreted) from what the run keeps — ``report.json`` (the verdict, each axis's analysis),
``record.json`` (who, what, when, where; the measurements with limits and outcomes),
``meta.json``/``end.json`` (a run without a record) — and from the recording itself for the
time-trace excerpt. Figures are inline SVG (matplotlib's object API, ``benchctl.report.figures``);
no JavaScript, no external resource (style inline, no font or image fetched), and a print
stylesheet for A4.

- :func:`build_context` gathers the report's content (plain dicts and lists);
- :func:`render_html` renders a context; :func:`write_html` renders a recording folder's report
  into ``<folder>/report.html`` (atomically) and returns its path.

An aborted run gets a report too, with what is known: its verdict ABORTED, the kind and reason
of the abort, the shutdown's steps (step, ok, detail), who/what/when/where, the prechecks, the
stand's health and, when the motion had begun, the time-trace excerpt.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import math
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from datetime import date
from functools import cache
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from jinja2 import Environment, PackageLoader, StrictUndefined

from benchctl.analysis.departures import departure_text
from benchctl.errors import DataError
from benchctl.fileout import atomic_write_text
from benchctl.jsonout import dumps, loads_strict
from benchctl.outcomes import Outcome
from benchctl.recording import load_recording
from benchctl.report.figures import excitation_svg, frf_svg, psd_svg, trace_svg

log = logging.getLogger(__name__)
T = TypeVar("T")

REPORT_HTML = "report.html"
TEMPLATE = "report.html.j2"
TRACE_EXCERPT_S = 20.0  # the time-trace excerpt's length
# a rejoin is the stand brought back onto the profile (stream mode: after missed setpoints it
# held; buffered: after an underrun stopped it), never a reconnection of the link
REJOIN_LABEL = "rejoins (the stand rejoined the profile after missed setpoints or an underrun)"


@cache
def _environment() -> Any:
    env = Environment(
        loader=PackageLoader("benchctl.report", "templates"),
        autoescape=True,
        undefined=StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    env.filters["num"] = _num
    env.filters["pct"] = _pct
    return env


def _num(v: Any, spec: str = ".4g") -> str:
    """A number formatted by ``spec``; "—" for None or NaN; other values as text."""
    if v is None:
        return "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, int | float):
        return "—" if not math.isfinite(float(v)) else format(v, spec)
    return str(v)


def _pct(v: Any, spec: str = ".2g") -> str:
    if not isinstance(v, int | float) or not math.isfinite(float(v)):
        return "—"
    return format(100.0 * float(v), spec) + " %"


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = loads_strict(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def identity_text(d: Any) -> str:
    """A device identity as one line: vendor, model, serial, firmware (protocol)."""
    if not isinstance(d, Mapping):
        return "—"
    parts = [str(d[k]) for k in ("vendor", "model") if d.get(k)]
    if d.get("serial"):
        parts.append(f"serial {d['serial']}")
    if d.get("firmware"):
        parts.append(f"firmware {d['firmware']}")
    text = " ".join(parts) or "—"
    return text + (f" ({d['protocol']})" if d.get("protocol") else "")


def _in_folder(path: Any, folder: Path) -> str:
    """``path`` as its name when it is in ``folder`` (the recording), else as it is."""
    p = Path(str(path or ""))
    return p.name if p.parent == folder or p.parent.name == folder.name else str(path or "—")


def _verdict(report: Mapping[str, Any] | None, record: Mapping[str, Any] | None,
             end: Mapping[str, Any] | None) -> str:
    if record and record.get("outcome"):
        return str(record["outcome"])
    if report and report.get("verdict"):
        return str(report["verdict"])
    if end is None:
        return Outcome.INCOMPLETE
    return Outcome.ABORTED if end.get("state") == "aborted" else str(end.get("reason") or "?")


def _calibration_warning(due: Any, start: Any) -> str | None:
    """The stand's calibration due before the run's start: a warning."""
    try:
        d = date.fromisoformat(str(due)[:10])
        s = date.fromisoformat(str(start)[:10])
    except ValueError:
        return None
    return None if d >= s else f"the stand's calibration was due on {d} (before this run)"


def _health(stats: Mapping[str, Any]) -> list[tuple[str, str, bool]]:
    """(what, value, warn) rows of the stand's and instrument's health."""
    lat = stats.get("cycle_lateness_s") or {}
    rtt = stats.get("stand_rtt_s") or {}
    cycles = stats.get("cycles") or 0
    missed = stats.get("missed_cycles") or 0
    rows = [
        ("control cycles", _num(cycles, "d"), False),
        ("missed cycles", f"{missed}" + (f" ({100 * missed / cycles:.2g} %)" if cycles else ""),
         bool(missed) and cycles > 0 and missed / cycles > 0.01),
        (REJOIN_LABEL,
         _num(stats.get("rejoins", 0), "d"),
         bool(stats.get("rejoins"))),
        ("underruns (stand queue empty)", _num(stats.get("underruns", 0), "d"),
         bool(stats.get("underruns"))),
        ("cycle lateness p50 / p99", f"{_ms(lat, 'p50')} / {_ms(lat, 'p99')} ms", False),
        ("stand round trip p50 / p99", f"{_ms(rtt, 'p50')} / {_ms(rtt, 'p99')} ms", False),
        ("instrument samples", _num(stats.get("instrument_samples"), "d"), False),
        ("instrument samples lost", _num(stats.get("instrument_lost", 0), "d"),
         bool(stats.get("instrument_lost"))),
        ("instrument bad frames", _num(stats.get("instrument_bad_frames", 0), "d"),
         bool(stats.get("instrument_bad_frames"))),
    ]
    return rows


def _ms(d: Mapping[str, Any], key: str) -> str:
    """``d[key]`` seconds in milliseconds, or — (absent, or null: no cycle was run)."""
    v = d.get(key)
    return _num(1e3 * v, ".3g") if isinstance(v, int | float) else "—"


def _health_warnings(stats: Mapping[str, Any]) -> list[str]:
    out = []
    cycles, missed = stats.get("cycles") or 0, stats.get("missed_cycles") or 0
    if missed:
        share = f" ({100 * missed / cycles:.2g} % of {cycles})" if cycles else ""
        out.append(f"{missed} missed control cycle(s){share}")
    for key, what in (("rejoins", "rejoin(s): the stand rejoined the profile after missed "
                                  "setpoints or an underrun"),
                      ("underruns", "stand queue underrun(s)"),
                      ("instrument_lost", "instrument sample(s) lost"),
                      ("instrument_bad_frames", "bad instrument frame(s)")):
        if stats.get(key):
            out.append(f"{stats[key]} {what}")
    return out


def _analysis_warnings(axis: str, an: Mapping[str, Any]) -> list[str]:
    """Gaps in the streams and the timing's share of σ², per axis."""
    out = []
    gaps = an.get("gaps") or {}
    for who in ("device", "reference"):
        g = gaps.get(who) or {}
        if g.get("count"):
            name = "instrument" if who == "device" else "stand"
            out.append(f"{axis}: {g['count']} gap(s) in the {name} stream, "
                       f"{g.get('missing_samples', 0)} sample(s) missing, longest "
                       f"{_num(g.get('longest_s'), '.3g')} s")
    if gaps.get("excluded_samples"):
        out.append(f"{axis}: {gaps['excluded_samples']} sample(s) excluded from the analysis")
    tm = an.get("timing") or {}
    share = tm.get("timing_share")
    if isinstance(share, int | float) and math.isfinite(share):
        out.append(f"{axis}: timing (time-stamp jitter × angular rate) contributes "
                   f"{_pct(share)} of σ²")
    ppm = tm.get("skew_ppm")
    if tm.get("skew_corrected") and isinstance(ppm, int | float):
        out.append(f"{axis}: the instrument's stamps drift {ppm:+.4g} ppm against the stand's "
                   f"({1e3 * float(tm.get('skew_drift_s') or 0.0):+.3g} ms over the record), "
                   "corrected")
    stat = tm.get("sigma_ci95_statistical")
    if tm.get("timing_in_interval") and isinstance(stat, list | tuple) and len(stat) == 2:
        out.append(f"{axis}: σ's interval includes timing (statistical alone "
                   f"{_num(stat[0], '.5g')} … {_num(stat[1], '.5g')}°)")
    return out


SHORT_VALUE = 34  # characters: a who/what value this short shares its table row with another


def who_rows(who: Sequence[tuple[str, Any]]) -> list[list[tuple[str, str]]]:
    """The who/what table's rows, in order: two short items side by side, a long one (a
    SHA-256, an identity, a path) on a row of its own — half the height on paper."""
    rows: list[list[tuple[str, str]]] = []
    half: list[tuple[str, str]] = []
    for k, v in who:
        text = str(v)
        if len(text) <= SHORT_VALUE and "SHA-256" not in k:
            half.append((k, text))
            if len(half) == 2:
                rows.append(half)
                half = []
            continue
        if half:
            rows.append(half)
            half = []
        rows.append([(k, text)])
    if half:
        rows.append(half)
    return rows


PRECHECK_PREFIX = "precheck: "


def measurement_rows(measurements: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The measurements table's rows, compact: the prechecks as one group row where the first
    one stood (how many passed, their names in its note; its outcome FAIL if any failed), and
    a failed precheck also on a row of its own, with its detail. Every other measurement on
    its own row, as recorded."""
    pre = [m for m in measurements if str(m.get("name") or "").startswith(PRECHECK_PREFIX)]
    rows: list[dict[str, Any]] = []
    grouped = False
    for m in measurements:
        if m not in pre:
            rows.append({**m, "group": False})
            continue
        if grouped:
            continue
        grouped = True
        ok = [p for p in pre if p.get("outcome") == Outcome.PASS]
        failed = [p for p in pre if p.get("outcome") != Outcome.PASS]
        names = ", ".join(str(p.get("name"))[len(PRECHECK_PREFIX):] for p in pre)
        rows.append({"name": f"prechecks ({len(pre)})", "axis": None,
                     "value": f"{len(ok)} of {len(pre)} passed", "unit": None, "low": None,
                     "high": None, "ci95": None,
                     "outcome": Outcome.FAIL if failed else Outcome.PASS,
                     "rule": "check", "decisive": True, "note": names, "group": True})
        rows.extend({**p, "group": False} for p in failed)
    return rows


def _decomposition(an: Mapping[str, Any]) -> list[tuple[str, Any, Any]]:
    """(component, variance deg², share of the mean-square error) rows."""
    c = an.get("components") or {}
    parts = [("linear (gain and phase error, coherent with the motion)", c.get("linear")),
             ("incoherent (noise, nonlinearity)", c.get("incoherent")),
             ("static (mean error²)", c.get("static"))]
    total = sum(float(v) for _, v in parts if isinstance(v, int | float))
    return [(name, v, (float(v) / total) if isinstance(v, int | float) and total > 0 else None)
            for name, v in parts]


def _trace(folder: Path, axes: Sequence[str], window: Sequence[float] | None,
           motion_start: float | None, title: str) -> dict[str, str]:
    """A ``TRACE_EXCERPT_S`` excerpt per axis: the middle of the analysis window, or the last
    seconds recorded (an aborted run)."""
    out: dict[str, str] = {}
    try:
        rec = load_recording(folder)
    except (DataError, OSError) as e:
        log.info("no time-trace excerpt for %s: %s", folder, e)
        return out
    for axis in axes:
        try:
            tr, xr, td, yd = rec.pair(axis, window=False)
        except (DataError, ValueError, KeyError) as e:
            log.info("no time-trace excerpt of %s: %s", axis, e)
            continue
        if tr.size < 2 or td.size < 2:
            continue
        if window is not None and len(window) == 2:
            mid = 0.5 * (float(window[0]) + float(window[1]))
            lo = max(float(window[0]), mid - TRACE_EXCERPT_S / 2)
        else:
            lo = float(min(tr[-1], td[-1])) - TRACE_EXCERPT_S
        hi = lo + TRACE_EXCERPT_S
        kr = (tr >= lo) & (tr <= hi)
        kd = (td >= lo) & (td <= hi)
        t0 = motion_start if motion_start is not None else float(tr[0])
        svg = trace_svg(np.asarray(tr[kr]), np.asarray(xr[kr]), np.asarray(td[kd]),
                        np.asarray(yd[kd]), t0, title=f"{axis} time trace — {title}")
        if svg is not None:
            out[axis] = svg
    return out


# A run draws its report twice (before its recording closes, and after, with the data files'
# SHA-256): the figures of the same content are drawn once. Keyed by their content (and the
# streams' size and time for the trace), the last few kept.
# (No lock: a report is drawn on one thread; two drawn at once would at worst draw twice.)
_FIGURES: OrderedDict[str, Any] = OrderedDict()
FIGURE_CACHE_SIZE = 8


def _key(*parts: Any) -> str:
    return hashlib.sha256(dumps(list(parts)).encode("utf-8")).hexdigest()


def _stamp(folder: Path) -> list[Any]:
    """The streams' sizes and modification times (a trace drawn of other data is not reused)."""
    out: list[Any] = []
    for name in ("stand.csv", "instrument.csv"):
        try:
            st = (folder / name).stat()
        except OSError:
            out.append(None)
            continue
        out.append([st.st_size, st.st_mtime_ns])
    return out


def _cached(key: str, make: Callable[[], T]) -> T:
    hit = _FIGURES.get(key)
    if hit is not None:
        value: T = hit
        return value
    value = make()
    _FIGURES[key] = value
    with contextlib.suppress(KeyError):
        while len(_FIGURES) > FIGURE_CACHE_SIZE:
            _FIGURES.popitem(last=False)
    return value


def _figures_of(name: str, an: Mapping[str, Any], lim: Any, exc: Any,
                title: str) -> dict[str, str | None]:
    """An axis's PSD, frequency response and excitation figures (SVG), drawn once per content."""

    limit = lim if isinstance(lim, int | float) else None

    def make() -> dict[str, str | None]:
        return {
            "psd_svg": psd_svg(an, limit, f"{name} error PSD — {title}"),
            "frf_svg": frf_svg(an, f"{name} frequency response — {title}"),
            "excitation_svg": None if not exc else excitation_svg(
                exc, f"{name} stand spectrum vs target — {title}"),
        }

    return dict(_cached(_key("axis", name, an, limit, exc, title), make))


def build_context(
    folder: Path,
    *,
    report: Mapping[str, Any] | None = None,
    record: Mapping[str, Any] | None = None,
    meta: Mapping[str, Any] | None = None,
    end: Mapping[str, Any] | None = None,
    trace: bool = True,
    figures: bool = True,
) -> dict[str, Any]:
    """The report's content for ``folder``: what is not given is read from the folder
    (``report.json``, ``record.json``, ``meta.json``, ``end.json``); missing files are no error
    (an aborted run has no report.json), but a folder without any of them is. ``figures``:
    False leaves the figures out (a run with ``run.figures: false``; the page says so)."""
    folder = Path(folder)
    report = report if report is not None else _read_json(folder / "report.json")
    record = record if record is not None else _read_json(folder / "record.json")
    meta = meta if meta is not None else _read_json(folder / "meta.json")
    end = end if end is not None else _read_json(folder / "end.json")
    if report is None and record is None and meta is None:
        raise DataError(f"{folder}: not a benchctl recording (no report.json, record.json or "
                        "meta.json)")
    rep: Mapping[str, Any] = report or {}
    rec: Mapping[str, Any] = record or {}
    m: Mapping[str, Any] = meta or {}
    cfg = m.get("config") if isinstance(m.get("config"), Mapping) else {}
    assert isinstance(cfg, Mapping)
    devices = m.get("devices") if isinstance(m.get("devices"), Mapping) else {}
    assert isinstance(devices, Mapping)
    unit = rec.get("unit") or {}
    stand = rec.get("stand") or {}
    prof = rec.get("profile") or {}
    verdict = _verdict(report, record, end)
    serial = str(unit.get("serial") or rep.get("serial") or m.get("serial") or "")
    start = rec.get("start_utc") or rep.get("start_utc") or m.get("start_utc")
    end_utc = rec.get("end_utc") or (end or {}).get("end_utc")
    due = stand.get("calibration_due") or (cfg.get("stand") or {}).get("calibration_due")
    instruments = rec.get("instruments") or [{"role": "dut",
                                              "identity": devices.get("instrument")}]
    dut = next((i.get("identity") for i in instruments if i.get("role") == "dut"), None)
    reported = unit.get("reported_serial")
    who = [
        ("serial", serial or "—"),
        ("serial the instrument reports", "—" if reported is None else
         f"{reported} ({'matches' if unit.get('serial_match') else 'DOES NOT MATCH'})"),
        ("part number", unit.get("part_number") or m.get("part_number") or "—"),
        ("operator", rec.get("operator") or rep.get("operator") or m.get("operator") or "—"),
        ("station", rec.get("station") or rep.get("station") or m.get("station") or "—"),
        ("stand", identity_text(stand.get("identity") or devices.get("stand"))),
        ("stand calibration due", str(due)[:10] if due else "—"),
        ("instrument", identity_text(dut)),
        ("profile", f"{prof.get('name') or rep.get('profile_name') or m.get('profile_name')}"
                    f" ({prof.get('kind') or '?'}), seed "
                    f"{_num(prof.get('seed', rep.get('seed', m.get('seed'))), 'd')}"),
        ("profile file", f"{prof.get('path') or m.get('profile_path') or '—'}"),
        ("profile SHA-256", prof.get("sha256") or m.get("profile_sha256") or "—"),
        ("config", f"{m.get('config_path') or '—'}"),
        ("config SHA-256", rec.get("config_sha256") or m.get("config_sha256") or "—"),
        ("software", f"benchctl {(rec.get('software') or {}).get('version') or m.get('software_version') or '?'}"),  # noqa: E501
        ("start (UTC)", start or "—"),
        ("end (UTC)", end_utc or "—"),
        ("run", rec.get("run_id") or folder.name),
    ]
    scale = prof.get("scale", rep.get("scale"))
    if isinstance(scale, int | float) and scale != 1.0:
        who.append(("profile scale", f"{scale:g} (scaled to fit the stand)"))
    stats = rep.get("stats") or (end or {}).get("stats") or {}
    limit = rep.get("limit_sigma_deg", m.get("limit_sigma_deg"))
    date_text = str(start or "")[:10]
    title = f"serial {serial or '?'}, {date_text}"
    axes = []
    warnings: list[str] = list(rec.get("warnings") or rep.get("warnings") or [])
    cal = _calibration_warning(due, start)
    if cal:
        warnings.append(cal)
    warnings.extend(_health_warnings(stats))
    for name, a in (rep.get("axes") or {}).items():
        an = a.get("analysis") or {}
        warnings.extend(_analysis_warnings(name, an))
        lim = a.get("limit", limit)
        exc = a.get("excitation") or an.get("excitation")
        axes.append({
            "name": name,
            "verdict": a.get("verdict"),
            "sigma_verdict": a.get("sigma_verdict"),
            "sigma": a.get("sigma"),
            "ci95": a.get("sigma_ci95") or [None, None],
            "dof": a.get("dof"),
            "limit": lim,
            "mean_error": a.get("mean_error"),
            "rms_error": a.get("rms_error"),
            "delay": a.get("delay"),
            "periods": [p for p in an.get("periods") or [] if isinstance(p, Mapping)],
            "frf_source": (an.get("frf") or {}).get("source"),
            "decomposition": _decomposition(an),
            "components_source": (an.get("components") or {}).get("source"),
            "steps": a.get("steps"),
            "linearity": a.get("linearity"),
            "excitation": exc,
            "departures": departure_text(an["departures"])
            if isinstance(an.get("departures"), Mapping) else None,
            "sigma_inconclusive": a.get("sigma_inconclusive"),
            "budget": a.get("budget") if isinstance(a.get("budget"), Mapping) else None,
            **(_figures_of(name, an, lim, exc, title) if figures else
               {"psd_svg": None, "frf_svg": None, "excitation_svg": None}),
        })
    window = rep.get("analysis_window") or (end or {}).get("analysis_window")
    motion_start = stats.get("motion_start") if isinstance(stats, Mapping) else None
    traces: dict[str, str] = {}
    if trace and figures:
        names = [a["name"] for a in axes] or list(m.get("axes") or [])
        traces = _cached(_key("trace", str(folder.resolve()), names, window, motion_start,
                              title, _stamp(folder)),
                         lambda: _trace(folder, names, window, motion_start, title))
    abort = rec.get("abort")
    if abort is None and verdict in (Outcome.ABORTED, Outcome.INCOMPLETE):
        reason = (end or {}).get("reason") if end else "the run ended without closing its " \
            "recording (no end.json: the process was killed)"
        abort = {"kind": None, "reason": reason}
    # an aborted run's cleanup, step by step: the record's, else end.json's (a record not
    # written); those at the motion's end first
    shutdown: list[Any] = []
    if verdict in (Outcome.ABORTED, Outcome.INCOMPLETE):
        shutdown = list((abort or {}).get("shutdown") or [
            *((end or {}).get("motion_end_shutdown") or []),
            *((end or {}).get("shutdown") or [])])
    # the reports by their names in the recording (its path is printed above them)
    files = [(k, _in_folder(v.get("path"), folder), v.get("sha256"))
             for k, v in (rec.get("files") or {}).items() if isinstance(v, Mapping)]
    data = rec.get("data") if isinstance(rec.get("data"), Mapping) else None
    if data is not None:
        who.append(("recording SHA-256", str(data.get("recording_sha256") or "—")))
    return {
        "verdict": verdict,
        "serial": serial,
        "title": title,
        "date": date_text,
        "rule": rec.get("decision_rule") or rep.get("decision_rule") or {},
        "abort": abort,
        "shutdown": [st for st in shutdown if isinstance(st, Mapping)],
        "deviations": list(rec.get("deviations") or rep.get("deviations") or []),
        "warnings": list(dict.fromkeys(warnings)),
        "who": who,
        "who_rows": who_rows(who),
        "axes": axes,
        "traces": traces,
        "measurements": measurement_rows(list(rec.get("measurements")
                                              or rep.get("measurements") or [])),
        "health": _health(stats),
        "ended": rep.get("ended"),
        "files": files,
        "data": data,
        "recording": str(folder),
        "operator": str(rec.get("operator") or rep.get("operator") or m.get("operator") or ""),
        "run_id": str(rec.get("run_id") or folder.name),
        "figures_off": not figures,
    }


def render_html(context: Mapping[str, Any]) -> str:
    """The report's HTML from a :func:`build_context` context."""
    text: str = _environment().get_template(TEMPLATE).render(**context)
    return text


def write_html(
    folder: Path,
    *,
    report: Mapping[str, Any] | None = None,
    record: Mapping[str, Any] | None = None,
    trace: bool = True,
    figures: bool = True,
) -> Path:
    """Render ``folder``'s report into ``<folder>/report.html`` (a temporary file renamed over
    it) and return its path; ``figures``: see ``build_context``."""
    folder = Path(folder)
    html = render_html(build_context(folder, report=report, record=record, trace=trace,
                                     figures=figures))
    dest = folder / REPORT_HTML
    atomic_write_text(dest, html)  # no .tmp left behind when it fails (a full disk)
    return dest


__all__ = ["REPORT_HTML", "build_context", "identity_text", "measurement_rows", "render_html",
           "who_rows", "write_html"]
