"""The history of a bench or a unit from the archive: a text table, CSV, JSON and a
self-contained HTML page (Jinja2 with autoescaping; inline SVG plots of a unit's σ over its
runs with the limit and of each station's yield per day; no JavaScript, no external
resource).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from datetime import UTC, datetime
from typing import Any

from jinja2 import Environment, StrictUndefined

from benchctl.outcomes import RUN_OUTCOMES, Outcome
from benchctl.text import csv_cell, terminal_lines, visible

HISTORY_COLUMNS = ("run_id", "start_utc", "serial", "part_number", "station", "operator",
                   "outcome", "sigma", "sigma_limit", "profile", "seed", "abort_reason")
PAGE_COLUMNS = ("start_utc", "serial", "station", "operator", "outcome", "sigma", "sigma_limit",
                "abort_reason", "run_id")  # the page's table (A4)


def _sigma_text(d: dict[str, Any]) -> str:
    if not d:
        return ""
    return " ".join(f"{axis}={v:.4g}" if isinstance(v, int | float) else f"{axis}=?"
                    for axis, v in sorted(d.items()))


def flat(row: dict[str, Any]) -> dict[str, Any]:
    """One history row as flat fields (CSV, the text table)."""
    abort = row.get("abort") or {}
    return {
        "run_id": row["run_id"], "start_utc": row.get("start_utc") or "",
        "serial": row.get("serial") or "", "part_number": row.get("part_number") or "",
        "station": row.get("station") or "", "operator": row.get("operator") or "",
        "outcome": row.get("outcome") or "", "sigma": _sigma_text(row.get("sigma") or {}),
        "sigma_limit": _sigma_text(row.get("sigma_limit") or {}),
        "profile": (row.get("profile") or {}).get("name") or "",
        "seed": "" if (row.get("profile") or {}).get("seed") is None
        else str(row["profile"]["seed"]),
        "abort_reason": abort.get("reason") or "",
    }


def to_csv(rows: Sequence[dict[str, Any]]) -> str:
    """The runs as CSV, every cell through ``benchctl.text.csv_cell``: control characters
    shown as escapes, a cell a spreadsheet would take for a formula (``=HYPERLINK(…)``, ``+``,
    ``-``, ``@``) prefixed with ``'``."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(HISTORY_COLUMNS), lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: csv_cell(v) for k, v in flat(r).items()})
    return buf.getvalue()


def to_text(rows: Sequence[dict[str, Any]]) -> str:
    """The runs as a text table for the terminal (each cell made safe:
    ``benchctl.text.visible``)."""
    if not rows:
        return "no runs"
    cols = ("start_utc", "serial", "station", "operator", "outcome", "sigma", "run_id")
    table = [[visible(flat(r)[c]) for c in cols] for r in rows]
    for t in table:
        t[0] = t[0][:19].replace("T", " ")
    widths = [max(len(c), *(len(t[i]) for t in table)) for i, c in enumerate(cols)]
    lines = ["  ".join(c.ljust(w) for c, w in zip(cols, widths, strict=True)).rstrip()]
    lines += ["  ".join(v.ljust(w) for v, w in zip(t, widths, strict=True)).rstrip()
              for t in table]
    return "\n".join(lines)


NONE = "—"  # a field the run has no value for (an aborted run's report, a killed run's end)


def _v(value: object) -> str:
    """A field's value for the terminal: ``—`` for none (never ``None``)."""
    return NONE if value is None or value == "" else str(value)


def _file_lines(label: str, f: dict[str, Any] | None, missing: str) -> list[str]:
    """A file's path and SHA-256 (two lines), or one line saying why there is none."""
    f = f or {}
    if not f.get("path"):
        return [f"{label:<10} {NONE} ({missing})"]
    return [f"{label:<10} {f['path']}", f"{'':<10} sha256 {_v(f.get('sha256'))}"]


def show_text(run: dict[str, Any]) -> str:
    """One run, for the terminal (every line made safe: ``benchctl.text.visible``). A field the
    run has no value for is ``—`` (an aborted run has no report: the line says so)."""
    p = run.get("profile") or {}
    abort = run.get("abort") or {}
    aborted = run.get("outcome") == Outcome.ABORTED
    why = "no report: the run was aborted" if aborted else "no report recorded"
    lines = [
        f"run        {run['run_id']}",
        f"outcome    {_v(run.get('outcome'))}"
        + (f" ({_v(abort.get('kind'))}: {_v(abort.get('reason'))})" if abort else "")
        + (f", rule {run['decision_rule']}" if run.get("decision_rule") else ""),
        f"unit       {_v(run.get('serial'))}"
        + (f" (part {run['part_number']})" if run.get("part_number") else ""),
        f"station    {_v(run.get('station'))}   operator {_v(run.get('operator'))}",
        f"start/end  {_v(run.get('start_utc'))} → "
        + (_v(run.get("end_utc")) if run.get("end_utc") else f"{NONE} (no end recorded)"),
        f"profile    {_v(p.get('name'))} ({p.get('kind') or '?'}), seed {_v(p.get('seed'))}",
        f"software   {_v(run.get('software_version'))}   "
        f"config sha256 {_v(run.get('config_sha256'))}",
        *_file_lines("recording", run.get("recording"), "no recording folder recorded"),
        *_file_lines("report", run.get("report_json"), why),
        f"archived   {_v(run.get('archived_utc'))} (from {_v(run.get('source'))})",
    ]
    ms = run.get("measurements") or []
    if ms:
        lines.append("measurements")
        names = [m["name"] + (f" {m['axis']}" if m.get("axis") else "") for m in ms]
        width = max(len(n) for n in names)
        for name, m in zip(names, ms, strict=True):
            lo, hi = m.get("low"), m.get("high")
            if lo is not None and hi is not None:
                lim = f"   limit {lo:.4g} … {hi:.4g}"
            elif hi is not None:
                lim = f"   limit ≤ {hi:.4g}"
            elif lo is not None:
                lim = f"   limit ≥ {lo:.4g}"
            else:
                lim = ""
            ci = m.get("ci95")
            ci_text = f" [{ci[0]:.4g}, {ci[1]:.4g}]" if ci else ""
            v = m.get("value")
            val = (NONE if v is None else ("yes" if v else "no") if isinstance(v, bool)
                   else f"{v:.4g}" if isinstance(v, int | float) else str(v))
            unit = f" {m['unit']}" if m.get("unit") else ""
            lines.append(f"  {name:<{width}}  {val}{ci_text}{unit}{lim}   "
                         f"{m.get('outcome') or NONE}")
    return terminal_lines(lines)


# --- the HTML page ----------------------------------------------------------------------------

W, H = 720, 260
ML, MR, MT, MB = 60, 20, 20, 50  # margins


def ticks(lo: float, hi: float, n: int = 5) -> list[float]:
    """Round values between ``lo`` and ``hi`` for an axis (about ``n``)."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo]
    step = 10 ** math.floor(math.log10((hi - lo) / n))
    for m in (1, 2, 5, 10):
        if (hi - lo) / (step * m) <= n:
            step *= m
            break
    out, v = [], math.ceil(lo / step) * step
    while v <= hi + 1e-12 * max(1.0, abs(hi)):  # (a top of 0 reached from below: kept)
        out.append(round(v, 12))
        v += step
    return out


def sigma_plot(series: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """SVG geometry of a unit's σ over its runs (one polyline per axis, the 95 % interval as
    bars, the limit as a dashed line); x: the run's index (oldest left)."""
    pts = [s for s in series if isinstance(s.get("sigma"), int | float)]
    if not pts:
        return None
    runs = list(dict.fromkeys(s["run_id"] for s in pts))
    values = [float(s["sigma"]) for s in pts]
    for s in pts:
        if s.get("ci95"):
            values += [float(v) for v in s["ci95"]]
        if isinstance(s.get("limit"), int | float):
            values.append(float(s["limit"]))
    lo, hi = 0.0, max(values) * 1.1 or 1.0
    pw, ph = W - ML - MR, H - MT - MB

    def x(i: int) -> float:
        return ML + (pw * (i + 0.5) / len(runs))

    def y(v: float) -> float:
        return MT + ph * (1 - (v - lo) / (hi - lo))

    colours = {"roll": "#1f77b4", "pitch": "#d62728"}
    axes: dict[str, dict[str, Any]] = {}
    for s in pts:
        a = axes.setdefault(str(s["axis"]), {"axis": str(s["axis"]), "points": [],
                                             "colour": colours.get(str(s["axis"]), "#2ca02c")})
        i = runs.index(s["run_id"])
        ci = s.get("ci95")
        a["points"].append({
            "x": round(x(i), 1), "y": round(y(float(s["sigma"])), 1),
            "ci": None if not ci else (round(y(float(ci[1])), 1), round(y(float(ci[0])), 1)),
            "fail": s.get("outcome") not in (Outcome.PASS, None),
            "title": f"{s['run_id']} {s['axis']}: σ = {float(s['sigma']):.4g}"
                     + (f" [{float(ci[0]):.4g}, {float(ci[1]):.4g}]" if ci else "")
                     + f" ({s.get('outcome')})",
        })
    for a in axes.values():
        a["polyline"] = " ".join(f"{p['x']},{p['y']}" for p in a["points"])
    limits = sorted({float(s["limit"]) for s in pts if isinstance(s.get("limit"), int | float)})
    label_every = max(1, math.ceil(len(runs) / 8))
    return {
        "width": W, "height": H, "left": ML, "right": W - MR, "top": MT, "bottom": H - MB,
        "axes": list(axes.values()),
        "limits": [{"y": round(y(v), 1), "value": v} for v in limits],
        "yticks": [{"y": round(y(v), 1), "label": f"{v:.3g}"} for v in ticks(lo, hi)],
        "xlabels": [{"x": round(x(i), 1), "label": label}
                    for i, label in zip(range(0, len(runs), label_every),
                                        run_labels([pts_start(series, r) or r
                                                    for r in runs[::label_every]]),
                                        strict=True)],
    }


def run_labels(starts: Sequence[str]) -> list[str]:
    """Distinct x labels for runs started at ``starts`` (ISO UTC times, oldest first): the
    date when the runs are on different days (``2026-11-20``), else the day and time to the
    minute (``11-20 08:02``), to the second, and as a last resort numbered (``#3``)."""
    def fmt(s: str, form: int) -> str:
        if len(s) < 16 or s[10] != "T":  # not a time (a run id): as it is
            return s[:16]
        return (s[:10], f"{s[5:10]} {s[11:16]}", f"{s[5:10]} {s[11:19]}")[form]

    for form in range(3):
        labels = [fmt(s, form) for s in starts]
        if len(set(labels)) == len(labels):
            return labels
    return [f"{fmt(s, 1)} #{i + 1}" for i, s in enumerate(starts)]


def pts_start(series: Sequence[dict[str, Any]], run_id: str) -> str | None:
    for s in series:
        if s["run_id"] == run_id:
            return s.get("start_utc")
    return None


def _counted(key: dict[str, Any], outcomes: Sequence[str | None]) -> dict[str, Any]:
    c = {v: sum(o == v for o in outcomes) for v in RUN_OUTCOMES}
    judged = c[Outcome.PASS] + c[Outcome.FAIL] + c[Outcome.INCONCLUSIVE]
    return {**key, "runs": len(outcomes), "pass": c[Outcome.PASS], "fail": c[Outcome.FAIL],
            "inconclusive": c[Outcome.INCONCLUSIVE], "aborted": c[Outcome.ABORTED],
            "yield": None if judged == 0 else c[Outcome.PASS] / judged}


def unit_yield(serial: str, rows: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """A unit's yield over ``rows`` (its runs): runs, pass, fail, inconclusive, aborted and
    the yield = PASS / (PASS + FAIL + INCONCLUSIVE) (None when none reached a verdict)."""
    return _counted({"serial": serial}, [r.get("outcome") for r in rows])


def unit_yield_per_day(serial: str, rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """A unit's yield per UTC day of its runs ``rows`` (as :func:`unit_yield`, a ``day``
    each), oldest first."""
    days: dict[str, list[str | None]] = {}
    for r in rows:
        day = str(r.get("start_utc") or "")[:10] or "unknown"
        days.setdefault(day, []).append(r.get("outcome"))
    return [_counted({"serial": serial, "day": d}, o) for d, o in sorted(days.items())]


def yield_plot(days: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """SVG geometry per station (or per unit: entries with a ``serial`` and no ``station``):
    a bar per UTC day, its height the yield (0…100 %), with the day's counts in its title."""
    out = []

    def group(d: dict[str, Any]) -> str:
        return f"station {d['station']}" if d.get("station") is not None else \
            f"unit {d.get('serial')}"

    stations = list(dict.fromkeys(group(d) for d in days))  # as given: a unit's first
    pw, ph = W - ML - MR, H - MT - MB
    for st in stations:
        ds = [d for d in days if group(d) == st]
        bw = pw / max(len(ds), 1)
        bars = []
        for i, d in enumerate(ds):
            yv = d["yield"]
            h = 0.0 if yv is None else ph * float(yv)
            # the day's aborted runs beside its yield bar: their share of the day's runs
            share = d["aborted"] / d["runs"] if d["runs"] else 0.0
            ha = ph * share
            title = (f"{d['day']}: {d['runs']} run(s): {d['pass']} pass, {d['fail']} fail, "
                     f"{d['inconclusive']} inconclusive, {d['aborted']} aborted")
            bars.append({
                "x": round(ML + i * bw + bw * 0.1, 1), "width": round(bw * 0.5, 1),
                "y": round(MT + ph - h, 1), "height": round(h, 1),
                "label": d["day"], "label_x": round(ML + (i + 0.35) * bw, 1),
                "text": "—" if yv is None else f"{100 * float(yv):.0f} %",
                "title": title,
                "aborted": None if not d["aborted"] else {
                    "x": round(ML + i * bw + bw * 0.62, 1), "width": round(bw * 0.28, 1),
                    "y": round(MT + ph - ha, 1), "height": round(max(ha, 1.0), 1),
                    "text_x": round(ML + i * bw + bw * 0.76, 1),
                    "text": f"{d['aborted']} ab.", "title": title},
            })
        out.append({
            "station": st, "width": W, "height": H, "left": ML, "right": W - MR, "top": MT,
            "bottom": H - MB, "bars": bars,
            "yticks": [{"y": round(MT + ph * (1 - f), 1), "label": f"{int(f * 100)} %"}
                       for f in (0.0, 0.25, 0.5, 0.75, 1.0)],
            "label_every": max(1, math.ceil(len(ds) / 10)),
        })
    return out


TEMPLATE = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>benchctl history{% if serial %} — {{ serial }}{% endif %}</title>
<style>
body { font-family: sans-serif; margin: 1.5em; color: #222; }
table { border-collapse: collapse; font-size: 0.8em; max-width: 100%; }
td { white-space: nowrap; }
td.col-abort_reason, td.col-run_id { white-space: normal; overflow-wrap: anywhere; }
td.col-abort_reason { min-width: 12em; }
th, td { border: 1px solid #bbb; padding: 0.2em 0.5em; text-align: left; }
th { background: #eee; }
td.PASS { color: #176117; font-weight: bold; } td.FAIL { color: #a11; font-weight: bold; }
td.INCONCLUSIVE { color: #a60; font-weight: bold; } td.ABORTED { color: #555; }
svg { border: 1px solid #ddd; margin: 0.5em 0; }
svg text { font-size: 11px; font-family: sans-serif; }
@media print { @page { size: A4; margin: 12mm; } body { margin: 0; } }
</style></head><body>
<h1>benchctl history{% if serial %}: unit {{ serial }}{% endif %}</h1>
<p>Archive {{ archive }}; {{ rows|length }} run(s){% if station %}, station {{ station }}{% endif
%}{% if since %}, since {{ since }}{% endif %}; made {{ made }}.</p>
{% if sigma %}
<h2>σ of unit {{ serial }} over its runs</h2>
<svg xmlns="http://www.w3.org/2000/svg" width="{{ sigma.width }}" height="{{ sigma.height }}"
 role="img" aria-label="sigma over runs">
<line x1="{{ sigma.left }}" y1="{{ sigma.bottom }}" x2="{{ sigma.right }}" y2="{{ sigma.bottom
}}" stroke="#000"/>
<line x1="{{ sigma.left }}" y1="{{ sigma.top }}" x2="{{ sigma.left }}" y2="{{ sigma.bottom
}}" stroke="#000"/>
{% for t in sigma.yticks %}<line x1="{{ sigma.left - 4 }}" y1="{{ t.y }}" x2="{{ sigma.right
}}" y2="{{ t.y }}" stroke="#eee"/><text x="{{ sigma.left - 6 }}" y="{{ t.y + 4 }}"
 text-anchor="end">{{ t.label }}</text>
{% endfor %}
{% for t in sigma.xlabels %}<text x="{{ t.x }}" y="{{ sigma.bottom + 16 }}"
 text-anchor="middle">{{ t.label }}</text>{% endfor %}
<text x="14" y="{{ (sigma.top + sigma.bottom) / 2 }}" transform="rotate(-90 14 {{ (sigma.top
 + sigma.bottom) / 2 }})" text-anchor="middle">σ (deg)</text>
<text x="{{ (sigma.left + sigma.right) / 2 }}" y="{{ sigma.height - 8 }}"
 text-anchor="middle">run (oldest left)</text>
{% for l in sigma.limits %}<line class="limit" x1="{{ sigma.left }}" y1="{{ l.y }}" x2="{{
 sigma.right }}" y2="{{ l.y }}" stroke="#a11" stroke-dasharray="6 4"/><text x="{{ sigma.right
 }}" y="{{ l.y - 4 }}" text-anchor="end" fill="#a11">limit {{ '%.3g'|format(l.value) }}</text>
{% endfor %}
{% for a in sigma.axes %}<polyline class="sigma" fill="none" stroke="{{ a.colour }}"
 points="{{ a.polyline }}"/>
{% for p in a.points %}{% if p.ci %}<line x1="{{ p.x }}" y1="{{ p.ci[0] }}" x2="{{ p.x }}"
 y2="{{ p.ci[1] }}" stroke="{{ a.colour }}"/>{% endif %}<circle cx="{{ p.x }}" cy="{{ p.y
 }}" r="3.5" fill="{{ '#fff' if p.fail else a.colour }}" stroke="{{ a.colour }}"><title>{{
 p.title }}</title></circle>
{% endfor %}{% endfor %}
{% for a in sigma.axes %}<text x="{{ sigma.left + 10 + loop.index0 * 70 }}" y="{{ sigma.top
 + 12 }}" fill="{{ a.colour }}">● {{ a.axis }}</text>{% endfor %}
</svg>
<p>Filled: PASS; open: not PASS. Bars: σ's 95 % interval.</p>
{% endif %}
{% for st in yields %}
<h2>Yield per day: {{ st.station }}</h2>
<svg xmlns="http://www.w3.org/2000/svg" width="{{ st.width }}" height="{{ st.height }}"
 role="img" aria-label="yield per day">
{% for t in st.yticks %}<line x1="{{ st.left }}" y1="{{ t.y }}" x2="{{ st.right }}" y2="{{ t.y
}}" stroke="#eee"/><text x="{{ st.left - 6 }}" y="{{ t.y + 4 }}" text-anchor="end">{{ t.label
}}</text>{% endfor %}
<line x1="{{ st.left }}" y1="{{ st.bottom }}" x2="{{ st.right }}" y2="{{ st.bottom }}"
 stroke="#000"/>
{% for b in st.bars %}<rect class="yield" x="{{ b.x }}" y="{{ b.y }}" width="{{ b.width }}"
 height="{{ b.height }}" fill="#4a8"><title>{{ b.title }}</title></rect><text x="{{ b.label_x
 }}" y="{{ b.y - 3 }}" text-anchor="middle">{{ b.text }}</text>
{% if b.aborted %}<rect class="aborted" x="{{ b.aborted.x }}" y="{{ b.aborted.y }}"
 width="{{ b.aborted.width }}" height="{{ b.aborted.height }}" fill="#999"><title>{{
 b.aborted.title }}</title></rect><text class="aborted" x="{{ b.aborted.text_x }}" y="{{
 b.aborted.y - 3 }}" text-anchor="middle" fill="#555">{{ b.aborted.text }}</text>{% endif %}
{% if loop.index0 % st.label_every == 0 %}<text x="{{ b.label_x }}" y="{{ st.bottom + 16 }}"
 text-anchor="middle">{{ b.label }}</text>{% endif %}
{% endfor %}
<text x="{{ (st.left + st.right) / 2 }}" y="{{ st.height - 8 }}" text-anchor="middle">day
 (UTC); green: yield = PASS / (PASS + FAIL + INCONCLUSIVE); grey: aborted runs (share of the
 day's runs)</text>
</svg>
{% endfor %}
<h2>Runs</h2>
<table>
<tr>{% for c in columns %}<th>{{ c }}</th>{% endfor %}</tr>
{% for r in rows %}<tr>{% for c in columns %}<td class="col-{{ c }}{% if c == 'outcome' %} {{ r[c]
}}{% endif %}">{{ r[c] }}</td>{% endfor %}</tr>
{% endfor %}
</table>
</body></html>
"""


def html_page(rows: Sequence[dict[str, Any]], *, archive: str, serial: str | None = None,
              sigma_series: Sequence[dict[str, Any]] = (),
              yields: Sequence[dict[str, Any]] = (), station: str | None = None,
              since: str | None = None) -> str:
    """The history page: self-contained HTML (inline SVG, no script)."""
    env = Environment(autoescape=True, undefined=StrictUndefined)
    t = env.from_string(TEMPLATE)
    table = []
    for r in rows:
        f = flat(r)
        f["start_utc"] = f["start_utc"][:16].replace("T", " ")
        table.append(f)
    return t.render(
        rows=table, columns=PAGE_COLUMNS, archive=archive,
        serial=serial, station=station, since=since,
        made=datetime.now(UTC).isoformat(timespec="seconds"),
        sigma=sigma_plot(sigma_series) if serial else None,
        yields=yield_plot(yields),
    )


__all__ = ["HISTORY_COLUMNS", "flat", "html_page", "show_text", "sigma_plot", "to_csv",
           "to_text", "unit_yield", "unit_yield_per_day", "yield_plot"]
