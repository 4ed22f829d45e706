"""The geometry of the line view's control charts, for inline SVG (pure: numbers in, numbers
and plain texts out; the template draws and escapes them).

``individuals_chart``: σ per run (oldest left) with the centre line, the control limits and
the σ limit, each point's class saying which rule flagged it (``beyond``, ``run``);
``moving_range_chart``: the moving ranges with MR̄ and D₄·MR̄ under it, on the same x.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from benchctl.archive.history import run_labels, ticks
from benchctl.archive.rows import iso
from benchctl.web.linedata import PartChart
from benchctl.web.linestats import moving_ranges

W, H, H_MR = 720, 240, 120
ML, MR, MT, MB = 60, 70, 14, 36  # margins; the right one holds the lines' names


class _Frame:
    """Data to pixels for n points between ``lo`` and ``hi``."""

    def __init__(self, n: int, lo: float, hi: float, height: int) -> None:
        self.n, self.lo, self.hi, self.height = n, lo, hi, height
        self.pw, self.ph = W - ML - MR, height - MT - MB

    def x(self, i: int) -> float:
        return round(ML + self.pw * (i + 0.5) / max(self.n, 1), 1)

    def y(self, v: float) -> float:
        return round(MT + self.ph * (1 - (v - self.lo) / (self.hi - self.lo)), 1)

    def box(self) -> dict[str, Any]:
        return {"width": W, "height": self.height, "left": ML, "right": W - MR, "top": MT,
                "bottom": self.height - MB}


LABEL_GAP = 12.0  # px between the names of the lines at the chart's right


def _named(lines: Sequence[tuple[str, float]], f: _Frame) -> list[dict[str, Any]]:
    """The lines with their y and their name's y, names pushed apart (top down) so that no
    two overlap when the lines are close."""
    out: list[dict[str, Any]] = []
    last = -math.inf
    for k, v in sorted(lines, key=lambda kv: f.y(kv[1])):
        label_y = round(max(f.y(v) + 4, last + LABEL_GAP), 1)
        out.append({"kind": k, "value": v, "y": f.y(v), "label_y": label_y})
        last = label_y
    return out


def _range(values: Sequence[float]) -> tuple[float, float]:
    lo, hi = min(values), max(values)
    pad = 0.08 * (hi - lo) if hi > lo else 0.1 * max(abs(hi), 1e-3)
    return max(0.0, lo - pad), hi + pad


def individuals_chart(chart: PartChart) -> dict[str, Any]:
    """The individuals chart of ``chart`` (at least one point)."""
    values = [p.sigma for p in chart.points]
    st = chart.stats
    lines: list[tuple[str, float]] = []  # (kind, value): the template names and draws them
    if st.limits is not None:
        lines += [("centre", st.limits.centre), ("ucl", st.limits.ucl)]
        if st.limits.lcl > 0:  # σ is never negative: a limit below 0 is no limit
            lines.append(("lcl", st.limits.lcl))
    if chart.usl is not None:
        lines.append(("usl", chart.usl))
    lo, hi = _range([*values, *(v for _, v in lines)])
    f = _Frame(len(values), lo, hi, H)
    beyond, run = set(st.beyond), set(st.run)
    label_every = max(1, math.ceil(len(values) / 8))
    labels = run_labels([iso(p.start_utc) or p.run_id for p in chart.points])
    return {
        **f.box(),
        "points": [{
            "x": f.x(i), "y": f.y(p.sigma), "value": p.sigma, "run_id": p.run_id,
            "serial": p.serial, "station": p.station, "start_utc": iso(p.start_utc),
            "outcome": p.outcome, "beyond": i in beyond, "run": i in run,
        } for i, p in enumerate(chart.points)],
        "polyline": " ".join(f"{f.x(i)},{f.y(v)}" for i, v in enumerate(values)),
        "lines": _named(lines, f),
        "yticks": [{"y": f.y(v), "label": f"{v:.3g}"} for v in ticks(lo, hi)],
        "xlabels": [{"x": f.x(i), "label": labels[i]}
                    for i in range(0, len(values), label_every)],
    }


def moving_range_chart(chart: PartChart) -> dict[str, Any] | None:
    """The moving-range chart under it (None with fewer than two points)."""
    st = chart.stats
    if st.limits is None:
        return None
    mrs = moving_ranges([p.sigma for p in chart.points])
    lines = [("mr_bar", st.limits.mr_bar), ("mr_ucl", st.limits.mr_ucl)]
    lo, hi = 0.0, max([*mrs, st.limits.mr_ucl]) * 1.1 or 1.0
    f = _Frame(len(chart.points), lo, hi, H_MR)
    return {
        **f.box(),
        "points": [{"x": f.x(i + 1), "y": f.y(v), "value": v,
                    "beyond": v > st.limits.mr_ucl} for i, v in enumerate(mrs)],
        "polyline": " ".join(f"{f.x(i + 1)},{f.y(v)}" for i, v in enumerate(mrs)),
        "lines": _named(lines, f),
        "yticks": [{"y": f.y(v), "label": f"{v:.2g}"} for v in ticks(lo, hi, 3)],
    }


__all__ = ["individuals_chart", "moving_range_chart", "ticks"]
