"""A harmonic table judged against the stand's limits over its whole duration, in continuous time.

The stand plays a table (``benchctl.harmonics.HarmonicTable``) on its own clock, so what it needs
is the table's peak angle, rate and acceleration between the grid points a host could sample:
:func:`table_peak` finds them (a grid, then a bounded search around each candidate) and
:func:`check_table` raises ``LimitError`` (needed vs allowed) before a table is uploaded.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from benchctl.devices.base import StandLimitsView
from benchctl.errors import LimitError
from benchctl.harmonics import HarmonicTable


def check_table(tab: HarmonicTable, limits: StandLimitsView, *, axis: str, max_lines: int) -> None:
    """Raise ``LimitError`` if a table exceeds the limits anywhere in its duration.

    The stand plays a table in continuous time, so the peaks of angle, rate and acceleration
    (fades included) are found in continuous time: a grid of at least 40 points per period of
    the highest line (and 20 per fade) locates them, and each candidate (every local maximum
    of the grid within 1 % of the grid's peak, and the 16 largest) is refined by a bounded
    scalar search on the table itself (:func:`table_peak`). The message gives needed vs allowed.
    """
    if tab.n_lines > max_lines:
        raise LimitError(f"table {axis}: {tab.n_lines} lines, the stand takes at most {max_lines}")
    if tab.n_lines == 0:
        raise LimitError(f"table {axis}: no lines")
    for name in ("freq_hz", "amp_deg", "phase_rad"):
        if not np.all(np.isfinite(getattr(tab, name))):
            raise LimitError(f"table {axis}: {name} holds a non-finite value")
    if np.any(tab.freq_hz < 0):
        raise LimitError(f"table {axis}: negative frequency {float(tab.freq_hz.min())} Hz")
    if not 0 < tab.duration_s < 1e6:
        raise LimitError(
            f"table {axis}: duration_s {tab.duration_s} s: expected 0 < duration < 1e6 s"
        )
    for deriv, allowed, unit, what in (
        (0, limits.angle_deg, "°", "angle"),
        (1, limits.rate_deg_s, "°/s", "rate"),
        (2, limits.accel_deg_s2, "°/s²", "acceleration"),
    ):
        peak = table_peak(tab, deriv)
        if peak > allowed:
            raise LimitError(
                f"table {axis}: needs {what} {peak:.4f}{unit}, allowed {allowed}{unit}"
            )


def table_peak(tab: HarmonicTable, derivative: int) -> float:
    """The largest |x^(derivative)(t)| of a table over [0, duration] in continuous time."""
    fmax = float(tab.freq_hz.max())
    step = 1.0 / (40.0 * fmax) if fmax > 0 else tab.duration_s
    fades = [f for f in (tab.fade_in_s, tab.fade_out_s) if f > 0]
    if fades:
        step = min(step, min(fades) / 20.0)
    n = min(math.ceil(tab.duration_s / step) + 1, 5_000_000)
    t = np.linspace(0.0, tab.duration_s, n)
    h = t[1] - t[0] if n > 1 else tab.duration_s
    y = np.abs(tab.evaluate(t, derivative))
    peak = float(y.max())
    if n < 3:
        return peak
    inner = (y[1:-1] >= y[:-2]) & (y[1:-1] >= y[2:])
    cand = np.flatnonzero(inner) + 1
    cand = np.concatenate([cand, [0, n - 1]])
    top = cand[np.argsort(y[cand])[::-1][:16]]
    near = cand[y[cand] >= 0.99 * peak][:200]
    for i in np.unique(np.concatenate([top, near])):
        lo, hi = max(0.0, t[i] - h), min(tab.duration_s, t[i] + h)

        def neg(x: float) -> float:
            return -float(np.abs(tab.evaluate(np.array([x]), derivative))[0])

        r = minimize_scalar(neg, bounds=(lo, hi), method="bounded", options={"xatol": 1e-10})
        peak = max(peak, -float(r.fun))
    return peak


__all__ = ["check_table", "table_peak"]
