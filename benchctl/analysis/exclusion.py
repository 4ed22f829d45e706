"""Leaving the stand's departures out of the analysed record.

Departures (``departures``): the intervals where the stand's motion was not the profile's
(an underrun or a rejoin, :mod:`benchctl.analysis.departures`) are left out as gaps are: the
device samples there are masked, so σ, the error PSD and H come from the samples under the
profile's motion only. When the record holds whole periods of its line set (a profile's, from
``period_s``, or detected), the whole analysis — σ, the PSD, H and the line-wise estimate —
is made on the whole periods no departure touches (the periods one touches masked whole: a
periodic motion sampled over whole periods, so σ is that of the profile exactly; over parts
of periods a multisine of few lines is sampled unevenly, σ 9 % off in the tests). Without a
known line set, on the samples outside the departures (no line-wise estimate; the interval
from the lag window, the motion taken as random). σ is not to be judged — the result says so
(``departures.too_little``) and a verdict on it is INCONCLUSIVE (:mod:`benchctl.run.report`)
— when departures touch every whole period, when what is left holds less than
``MIN_KEPT_SHARE`` of the samples, or when it cannot be analysed.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis.align import Aligned
from benchctl.analysis.departures import MIN_KEPT_SHARE, REASON, Departures
from benchctl.analysis.lines import (
    LinesError,
    LineSet,
    LinesMode,
    detect_period,
    reference_lines,
    whole_periods,
)

FloatArray = NDArray[np.float64]


@dataclass
class Exclusion:
    """The departures that touch the analysed record, and what leaving them out left.

    ``slots``: grid slots inside a departure (with a sample or not); ``present``: samples
    before, ``removed``: samples left out; ``too_little``: why σ is not to be judged (None:
    it is); ``over``: what σ was computed over, ``kept`` (the samples outside the departures)
    or ``all`` (nothing usable was left: the whole record, shown for information only);
    ``periods``: the whole periods of the line set, ``{"used", "of", "period_s"}`` (used: the
    ones no departure touches, which the analysis is then made on); ``line_set``: that line
    set, when some are used; ``lines_note``: why the analysis is not on whole periods."""

    items: Departures
    slots: NDArray[np.bool_]
    span: tuple[float, float]
    present: int
    removed: int = 0
    too_little: str | None = None
    over: str = "kept"
    periods: dict[str, Any] | None = None
    line_set: LineSet | None = None
    lines_note: str | None = None

    @property
    def kept_share(self) -> float:
        return (self.present - self.removed) / self.present if self.present else 0.0

    @property
    def seconds(self) -> float:
        lo, hi = self.span
        return float(sum(max(0.0, min(d.end_s, hi) - max(d.start_s, lo))
                         for d in self.items.items))

    def to_dict(self) -> dict[str, Any]:
        lo, hi = self.span
        items = self.items.items
        return {
            "count": len(items),
            "underruns": sum(d.count("underrun") for d in items),
            "rejoins": sum(d.count("rejoin") for d in items),
            "excluded_s": self.seconds,
            "analysed_s": hi - lo,
            "excluded_samples": self.removed,
            "kept_share": self.kept_share,
            "kept_s": (self.present - self.removed) * (hi - lo) / max(len(self.slots), 1),
            "intervals": [[max(d.start_s, lo), min(d.end_s, hi)] for d in items],
            "settle_s": self.items.settle_s,
            "rule": self.items.rule,
            "reason": REASON,
            "line_periods": self.periods,
            "min_kept_share": MIN_KEPT_SHARE,
            "too_little": self.too_little is not None,
            "too_little_reason": self.too_little,
            "sigma_over": ("all" if self.over == "all" else
                           "whole_periods" if self.line_set is not None else "samples"),
            "not_whole_periods": None if self.line_set is not None else self.lines_note,
        }

    def summary(self) -> str:
        """One sentence for the warnings and the reports."""
        d = self.to_dict()
        what = ", ".join(f"{d[k]} {k[:-1]}(s)" for k in ("underruns", "rejoins") if d[k])
        text = (f"the stand's motion was not the profile's in {d['count']} interval(s) "
                f"({what}) lasting {d['excluded_s']:.3g} s of {d['analysed_s']:.4g} s, each "
                f"{self.items.rule}; ")
        if self.line_set is not None and self.periods is not None:
            text += (f"σ and the line-wise estimate on the {self.periods['used']} of "
                     f"{self.periods['of']} whole period(s) of {self.periods['period_s']:.4g} s "
                     "that no departure touches")
        else:
            text += ("σ on the samples outside them (not on whole periods: "
                     + (self.lines_note or "no line set") + ")")
        return (text + f": {d['excluded_samples']} samples left out, "
                f"{100 * d['kept_share']:.3g} % kept")


def _slot_times(al: Aligned) -> FloatArray:
    """The instant of every grid slot (an empty slot's interpolated between its neighbours)."""
    s = np.arange(len(al.mask))
    ok = al.mask & np.isfinite(al.t)
    return np.asarray(np.interp(s, s[ok], al.t[ok]), dtype=float)


def exclude(
    al: Aligned, departures: Departures | None, lines: LinesMode, period_s: float | None
) -> tuple[Aligned, Exclusion | None]:
    """``al`` with the departures left out (module notes): the slots inside one masked (the
    device instant there, or the reference's, ``t − shift``), then — when the record holds
    whole periods of its line set — the periods they touch; and what that left. ``(al,
    None)`` when no departure touches the record."""
    if not departures:
        return al, None
    ts = _slot_times(al)
    span = (float(ts[0]), float(ts[-1]) + al.dt)
    items = departures.within(min(span[0], span[0] - al.shift), max(span[1], span[1] - al.shift))
    if not items:
        return al, None
    slots = items.inside(ts) | items.inside(ts - al.shift)
    ex = Exclusion(items, slots, span, al.n_valid)
    out = al
    if slots.any():
        out = dataclasses.replace(al, mask=al.mask & ~slots)
        out = _whole_periods(out, ex, lines, period_s)
    ex.removed = al.n_valid - out.n_valid
    if ex.periods is not None and ex.line_set is None:  # periodic, and every period touched
        ex.too_little = f"{ex.lines_note}: σ is judged on whole periods of the profile only"
    elif ex.kept_share < MIN_KEPT_SHARE:
        where = "in the whole periods no departure touches " if ex.line_set is not None else ""
        ex.too_little = (f"{100 * ex.kept_share:.3g} % of the samples are left {where}"
                         f"(less than the {100 * MIN_KEPT_SHARE:g} % needed)")
    if out.n_valid == 0:
        ex.over = "all"
        return al, ex
    return out, ex


def _whole_periods(al: Aligned, ex: Exclusion, lines: LinesMode,
                   period_s: float | None) -> Aligned:
    """``al`` on the whole periods of its line set that no departure touches (the others
    masked; ``ex.line_set``, ``ex.periods`` set), or ``al`` itself with ``ex.lines_note``
    saying why not: not whole periods, every period touched, or no line there. Lines not
    given (``period_s``, "auto") are found in the reference on those periods only."""
    n = len(al.mask)
    try:
        if isinstance(lines, LineSet):
            period, count = lines.period_s, whole_periods(n, al.dt, lines)
        elif period_s is not None:
            period = float(period_s)
            count = whole_periods(n, al.dt, LineSet(period, np.array([1]), "period"))
        elif lines == "auto":
            found = detect_period(al.x, al.mask)
            if found is None:
                return al
            period, count = n * al.dt / found, found
        else:
            return al
    except LinesError as e:
        ex.lines_note = str(e)
        return al
    edges = np.rint(np.arange(count + 1) * (n / count)).astype(np.int64)
    mask = al.mask.copy()
    used = 0
    for a, b in itertools.pairwise(edges):
        if ex.slots[a:b].any():
            mask[a:b] = False
        else:
            used += 1
    ex.periods = {"used": used, "of": count, "period_s": period}
    if used == 0:
        ex.lines_note = (f"the stand's motion departed from the profile in every one of the "
                         f"{count} whole period(s) of {period:.6g} s")
        return al
    if isinstance(lines, LineSet):
        ex.line_set = lines
    else:
        harm = reference_lines(al.x, mask, count)
        if harm.size == 0:
            ex.lines_note = f"the reference is excited at no harmonic of {period:.6g} s"
            ex.periods = None
            return al
        ex.line_set = LineSet(period, harm, "period" if period_s is not None else "detected")
    return dataclasses.replace(al, mask=mask)


def exclusion_warnings(ex: Exclusion) -> list[str]:
    out = [ex.summary()]
    if ex.too_little is not None:
        over = ("the samples left" if ex.over == "kept" else
                "the whole record, departures included (for information only)")
        out.append(f"σ not to be judged (INCONCLUSIVE): {ex.too_little}; the σ shown is over "
                   f"{over}")
    return out
