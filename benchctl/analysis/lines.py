"""The excited lines of a periodic multisine: what a line set is and where it comes from.

A :class:`LineSet` is the lines ``f_k = k/T_p`` a record is analysed at (the line-wise
estimate, :mod:`benchctl.analysis.linewise`): re-synthesised from a recording's profile
(:func:`line_set_from_recording`, :func:`line_set_from_tables`), or found in the reference
(:func:`detect_period` over its whole periods, :func:`reference_lines`); and whether a record
holds whole periods of it (:func:`whole_periods`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.fft import rfft

from benchctl.errors import BenchError

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]

WHOLE_PERIODS_TOL = 0.05  # cycles a line (and the period) may miss being whole over the record
DETECT_OFF_GRID = 0.01  # detection: at most this share of the reference's power off the grid …
DETECT_MIN_LINE = 1e-6  # … and a line holds at least this share of the strongest one …
DETECT_FLOOR = 100.0  # … and this many times the median power of the off-grid bins


class LinesError(ValueError):
    """The line-wise estimate cannot be made (the reason is the message)."""


@dataclass(frozen=True)
class LineSet:
    """Excited lines ``f_k = harmonics_k / period_s`` and where they come from.

    ``source``: ``"profile"`` (re-synthesised from a recording's profile), ``"period"`` (given
    period, lines found in the reference) or ``"detected"`` (period and lines found in the
    reference). ``odd``: an odd multisine (its unexcited odd and even harmonics show
    nonlinear distortion, :mod:`benchctl.analysis.distortion`): from the profile's
    ``multisine`` option, or for lines found in the reference when there are at least
    two and all are odd. ``others``: the harmonics (of the same period) excited on the
    profile's other axes, never counted as unexcited.
    """

    period_s: float
    harmonics: IntArray
    source: str
    odd: bool = False
    others: IntArray | None = None

    @property
    def all_excited(self) -> IntArray:
        """The harmonics excited on any axis."""
        if self.others is None or self.others.size == 0:
            return self.harmonics
        return np.asarray(np.union1d(self.harmonics, self.others), dtype=np.int64)

    @property
    def is_odd_multisine(self) -> bool:
        if self.odd:
            return True
        h = self.harmonics
        return self.source != "profile" and h.size >= 2 and bool(np.all(h % 2 == 1))

    @property
    def freq(self) -> FloatArray:
        return np.asarray(self.harmonics / self.period_s, dtype=float)


#: the line-wise estimate's option (``analyze(lines=...)``): given lines, found in the
#: reference ("auto") or none ("off")
LinesMode = LineSet | Literal["auto", "off"]


# ------------------------------------------------------------------------ finding the lines
def periodogram(values: FloatArray, mask: NDArray[np.bool_]) -> FloatArray:
    """``|X_j|²`` of the zero-filled, demeaned series, j = 0 … N/2 (DC set to 0)."""
    v = np.where(mask, values, 0.0)
    v = np.where(mask, v - v.sum() / max(1, int(mask.sum())), 0.0)
    spec = rfft(v)
    p = spec.real**2 + spec.imag**2
    p[0] = 0.0
    return np.asarray(p, dtype=float)


def detect_period(
    x: FloatArray, mask: NDArray[np.bool_], power: FloatArray | None = None
) -> int | None:
    """The number n ≥ 2 of whole periods of the reference in the record, or None.

    A reference periodic in ``T = N·Δt/n`` has its spectrum over the record (DFT bins
    ``j/(NΔt)``) on the bins ``j ≡ 0 (mod n)`` only. The candidates are the divisors of the
    strongest bin; the largest n whose off-grid bins hold at most ``DETECT_OFF_GRID`` of the
    power (plus twice the share the gaps' own spectrum puts off the grid) is the period.
    One period per record (n = 1) cannot be told from a non-periodic reference: state it
    with ``period_s``. ``power``: :func:`periodogram` of x, if already computed.
    """
    p = periodogram(x, mask) if power is None else power
    total = float(p[1:].sum())
    if not total > 0.0:
        return None
    j_max = int(np.argmax(p))
    mp = None
    if not bool(mask.all()):
        ms = rfft(mask.astype(float))
        mp = ms.real**2 + ms.imag**2
        mp_total = float(mp.sum())
    best = None
    for cand in range(2, j_max + 1):
        if j_max % cand:
            continue
        off = 1.0 - float(p[::cand].sum()) / total  # p[0] = 0: the DC bin holds nothing
        allowed = DETECT_OFF_GRID
        if mp is not None:
            allowed += 2.0 * (1.0 - float(mp[::cand].sum()) / mp_total)
        if off <= allowed:
            best = cand
    return best


def reference_lines(
    x: FloatArray, mask: NDArray[np.bool_], n_periods: int, power: FloatArray | None = None
) -> IntArray:
    """Harmonics k of ``T_p = N·Δt/n`` where the reference is excited: bin ``n·k`` holds at
    least ``DETECT_MIN_LINE`` of the strongest bin's power and ``DETECT_FLOOR`` times the
    median power of the off-grid bins (of the upper half of the spectrum when n = 1).
    ``power``: :func:`periodogram` of x, if already computed."""
    p = periodogram(x, mask) if power is None else power
    j = np.arange(len(p))
    on = (j % n_periods == 0) & (j > 0) & (2 * j < 2 * (len(p) - 1))
    floor_bins = p[(j % n_periods != 0)] if n_periods > 1 else p[len(p) // 2 :]
    floor = float(np.median(floor_bins)) if floor_bins.size else 0.0
    strongest = float(p[on].max()) if on.any() else 0.0
    keep = on & (p >= DETECT_MIN_LINE * strongest) & (p > DETECT_FLOOR * floor) & (p > 0)
    return np.asarray(j[keep] // n_periods, dtype=np.int64)


def _table_harmonics(table: Any, period: float) -> IntArray | None:
    freq = np.asarray(table.freq_hz, dtype=float)
    freq = freq[np.asarray(table.amp_deg, dtype=float) > 0]
    k = freq * period
    ki = np.rint(k).astype(np.int64)
    if freq.size == 0 or np.any(np.abs(k - ki) > WHOLE_PERIODS_TOL) or ki.min() < 1:
        return None
    return np.unique(ki)


def line_set_from_tables(
    table: Any, window_s: float | None, others: Sequence[Any] = ()
) -> tuple[LineSet | None, str | None]:
    """The line set of one axis's ``HarmonicTable`` (freq_hz, amp_deg, period_s), or
    ``(None, reason)``. Without a period, the analysis window is the period (its lines must
    make whole cycles in it). ``others``: the tables of the profile's other axes (their lines
    go into ``LineSet.others``); the table's ``meta["multisine"]`` (an odd multisine) sets
    ``LineSet.odd``."""
    amp = np.asarray(table.amp_deg, dtype=float)
    if not np.any(amp > 0):
        return None, "the profile's table has no line"
    period = table.period_s if table.period_s else window_s
    if not period:
        return None, "the profile's lines have no repetition period"
    ki = _table_harmonics(table, period)
    if ki is None:
        return None, f"the profile's lines are not whole harmonics of {period:g} s"
    rest = [h for h in (_table_harmonics(t, period) for t in others) if h is not None]
    other = np.unique(np.concatenate(rest)).astype(np.int64) if rest else None
    meta = getattr(table, "meta", None) or {}
    ms = meta.get("multisine") if isinstance(meta, dict) else None
    odd = isinstance(ms, dict) and bool(ms.get("odd"))
    return LineSet(float(period), ki, "profile", odd, other), None


def line_set_from_recording(
    meta: dict[str, Any], axis: str, window: tuple[float, float] | None
) -> tuple[LineSet | None, str | None]:
    """Re-synthesise the lines of ``axis`` from a recording's metadata (``profile``, ``seed``,
    ``duration_s``): ``(LineSet, None)``, or ``(None, reason)`` when it cannot be done."""
    # imported here: the profile schema (pydantic) costs `benchctl analyze` of a CSV, which
    # never needs it, about 0.6 s of its 2.4 s (python -X importtime)
    from benchctl.profiles import parse_profile, synthesize

    prof = meta.get("profile")
    if not isinstance(prof, dict) or not isinstance(prof.get("spec"), dict):
        return None, "the recording holds no profile"
    try:
        profile = parse_profile(prof["spec"], prof.get("source"))
        seed = meta.get("seed")
        duration = meta.get("duration_s")
        motion = synthesize(
            profile,
            duration_s=float(duration) if isinstance(duration, int | float) else None,
            seed=int(seed) if isinstance(seed, int) else None,
        )
    except (BenchError, OSError, ValueError, TypeError) as e:
        return None, f"its profile could not be re-synthesised ({e})"
    tables = motion.tables
    if not tables or axis not in tables:
        return None, f"the profile gives no harmonic table for {axis}"
    span = None if window is None else window[1] - window[0]
    others = [t for a, t in tables.items() if a != axis]
    return line_set_from_tables(tables[axis], span, others)


def whole_periods(n_slots: int, dt: float, lines: LineSet) -> int:
    """The number of whole periods ``T_p`` the record of ``n_slots·dt`` holds, or raise
    ``LinesError`` when it does not hold whole periods (within ``WHOLE_PERIODS_TOL`` of a
    cycle of the period and of every line)."""
    span = n_slots * dt
    nf = span / lines.period_s
    n = round(nf)
    cyc = lines.freq * span
    if n < 1 or abs(nf - n) > WHOLE_PERIODS_TOL or np.any(
        np.abs(cyc - np.rint(cyc)) > WHOLE_PERIODS_TOL
    ):
        raise LinesError(
            f"the record ({span:.6g} s) does not hold whole periods of {lines.period_s:.6g} s "
            f"({nf:.4g} periods)"
        )
    if 2 * int(np.rint(lines.freq.max() * span)) >= n_slots:
        raise LinesError("a line lies at or above the Nyquist frequency of the record")
    return n
