"""Which lines a record's line-wise estimate is made at, and over which whole periods.

The lines: given (a recording's profile), the harmonics of a given period the reference is
excited at, or detected in the reference ("auto"); with departures, those of the whole periods
no departure touches (:mod:`benchctl.analysis.exclusion`). A record just short of (or past)
whole periods is completed with a gap at the end or trimmed to its first whole periods
(``PAD_SHARE``, ``PAD_CYCLES``). :func:`line_analysis` then makes the estimate
(:func:`benchctl.analysis.linewise.analyze_lines`), or says why not in a warning;
:func:`known_period` is the motion's period the skew is measured over.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numpy.typing import NDArray
from scipy.fft import rfft

from benchctl.analysis.align import Aligned
from benchctl.analysis.exclusion import Exclusion
from benchctl.analysis.lines import (
    WHOLE_PERIODS_TOL,
    LinesError,
    LineSet,
    LinesMode,
    detect_period,
    periodogram,
    reference_lines,
    whole_periods,
)
from benchctl.analysis.linewise import LineAnalysis, analyze_lines


def known_period(al: Aligned, lines: LinesMode, period_s: float | None) -> float | None:
    """The motion's period: given (a profile's lines, ``period_s``) or detected in the
    reference ("auto"); None when it is not periodic (or the detection finds no period)."""
    if isinstance(lines, LineSet):
        return lines.period_s
    if period_s is not None:
        return float(period_s)
    if lines != "auto":
        return None
    power = periodogram(al.x, al.mask)
    count = detect_period(al.x, al.mask, power)
    return None if count is None else len(al.mask) * al.dt / count


def _line_set(
    al: Aligned, lines: LinesMode, period_s: float | None
) -> tuple[LineSet | None, NDArray[np.complex128] | None]:
    """The lines to estimate at: given, the harmonics of ``period_s`` the reference is
    excited at, or detected ("auto"); ``(None, None)`` when none (``LinesError`` when given
    ones cannot be used). With the reference's rfft when it was made (a gap-free grid)."""
    n = len(al.mask)
    if isinstance(lines, LineSet):
        return lines, None
    if period_s is None and lines != "auto":
        return None, None
    x_spectrum = None
    if bool(al.mask.all()):  # one transform of x for the lines and the fit
        x_spectrum = rfft(al.x)
        power = x_spectrum.real**2 + x_spectrum.imag**2
        power[0] = 0.0
    else:
        power = periodogram(al.x, al.mask)
    if period_s is not None:
        count = whole_periods(n, al.dt, LineSet(float(period_s), np.array([1]), "period"))
        harm = reference_lines(al.x, al.mask, count, power)
        if harm.size == 0:
            raise LinesError(f"the reference is excited at no harmonic of {period_s:g} s")
        return LineSet(float(period_s), harm, "period"), x_spectrum
    count_or_none = detect_period(al.x, al.mask, power)
    if count_or_none is None:
        return None, None
    harm = reference_lines(al.x, al.mask, count_or_none, power)
    if harm.size == 0:
        return None, None
    return LineSet(n * al.dt / count_or_none, harm, "detected"), x_spectrum


def line_analysis(
    al: Aligned, lines: LinesMode, period_s: float | None, warnings: list[str],
    ex: Exclusion | None = None, band_hz: tuple[float, float] | None = None,
) -> LineAnalysis | None:
    """The line-wise estimate, or None (with a warning when lines were given but cannot be
    used, or were detected and fail). With departures (``ex``): on the whole periods they do
    not touch (``al`` is masked to them already), or none."""
    try:
        if ex is not None and ex.over == "kept" and ex.slots.any():
            if ex.line_set is None:  # not on whole periods: none (never on partial ones)
                if lines == "off" and period_s is None:
                    return None
                raise LinesError(ex.lines_note or "the departures leave no whole period of a "
                                 "known line set")
            lines, period_s = ex.line_set, None
        period = (lines.period_s if isinstance(lines, LineSet) else period_s)
        # completed with a gap only for known lines: found in the reference, a gap's edge
        # leaks into every harmonic and they would be found everywhere
        whole = (_whole_part(al, period, pad=isinstance(lines, LineSet))
                 if period is not None else None)
        ls, x_spectrum = _line_set(al if whole is None else whole[0], lines, period_s)
        if whole is not None and ls is not None and whole[2] * _line_span(ls) > PAD_CYCLES:
            # the gap at the end too long for the lines' band: their fit would amplify the
            # noise (a band B holds ≈ 2·B·gap functions that live mostly in the gap)
            assert period is not None
            whole = _whole_part(al, period, pad=False)
            if whole is None:
                raise LinesError(
                    f"the record ({len(al.mask) * al.dt:.6g} s) is short of whole periods of "
                    f"{period:.6g} s by more than a gap the lines' band "
                    f"({_line_span(ls):.4g} Hz) lets the fit bridge ({PAD_CYCLES:g}/band = "
                    f"{PAD_CYCLES / _line_span(ls):.3g} s), and holds no whole period")
            ls, x_spectrum = _line_set(whole[0], lines, period_s)
        if whole is not None:
            al = whole[0]
            warnings.append(whole[1])
        if ls is None:
            return None
        # the reference's spectrum handed over, not kept here: the line-wise estimate lets it
        # go after its first fit (a record's length of memory less at its peak)
        handed = [x_spectrum]
        del x_spectrum
        la = analyze_lines(al.x, al.y, al.mask, al.dt, ls, al.t, handed.pop(), band_hz)
        warnings.extend(la.warnings)
        return la
    except LinesError as e:
        warnings.append(f"no line-wise estimate: {e}")
        return None


PAD_SHARE = 0.02  # a record short of whole periods by at most this share of them: completed
PAD_CYCLES = 1.5  # … and by a gap of at most this / the lines' band (Hz), s
WHOLE_REL = 1e-4  # a record this close to whole periods is whole (a stand's clock ppm off)


def _line_span(ls: LineSet) -> float:
    """The band of a line set, Hz (its lowest to its highest line, one spacing at least)."""
    f = ls.freq
    return float(f.max() - f.min()) + 1.0 / ls.period_s


def _whole_part(al: Aligned, period: float,
                pad: bool = True) -> tuple[Aligned, str, float] | None:
    """A record just short of (or past) whole periods of ``period``: on whole periods, and the
    note that says so; None when it holds whole periods already, or not one and not nearly one.

    Short of whole periods by at most ``PAD_SHARE`` of them, with ``pad`` (known lines: a
    recording's profile; a run stopped half a second early, the usual one-period record of a
    sea state included): the grid is completed to the
    next whole period with empty slots, a gap at the end that the line fit handles as any
    other (every sample used), unless the lines' band makes that gap too long to bridge
    (``PAD_CYCLES``, judged by the caller, who then asks again with ``pad=False``). Otherwise its
    first whole periods (the rest left out). Returns the record, the note and the seconds
    missing at the end (0 when trimmed)."""
    n = len(al.mask)
    span = n * al.dt
    nf = span / period
    near = round(nf)
    m_near = round(near * period / al.dt)
    if near >= 1 and (abs(n - m_near) <= 1 or abs(nf - near) <= WHOLE_REL * near):
        return None  # whole periods: to a slot, or to a clock's ppm (the lines then refine it)
    if (pad and near >= 1 and n < m_near and near - nf <= PAD_SHARE * near
            and int(al.mask.sum()) >= 2):
        missing = m_near - n
        part = dataclasses.replace(
            al, t=np.concatenate((al.t, np.full(missing, np.nan))),
            x=np.concatenate((al.x, np.zeros(missing))),
            y=np.concatenate((al.y, np.zeros(missing))),
            mask=np.concatenate((al.mask, np.zeros(missing, dtype=bool))))
        return (part, (f"the record ({span:.6g} s) holds {nf:.6g} periods of {period:.6g} s: "
                      f"the line-wise estimate is made over {near} whole period"
                      f"{'s' if near > 1 else ''} ({m_near * al.dt:.6g} s), the last "
                      f"{missing * al.dt:.4g} s of which are missing (a gap at the end)"),
                missing * al.dt)
    whole = near if n > m_near else math.floor(nf)
    if whole < 1:
        return None
    m = round(whole * period / al.dt)
    if m < 2 or abs(m * al.dt / period - whole) > WHOLE_PERIODS_TOL / max(whole, 1):
        return None
    part = dataclasses.replace(al, t=al.t[:m], x=al.x[:m], y=al.y[:m], mask=al.mask[:m])
    if int(part.mask.sum()) < 2:
        return None
    return (part, (f"the record ({span:.6g} s) holds {nf:.4g} periods of {period:.6g} s: the "
                   f"line-wise estimate is made over its first {whole} whole period"
                   f"{'s' if whole > 1 else ''} ({m * al.dt:.6g} s), the last "
                   f"{span - m * al.dt:.4g} s left out of it"), 0.0)
