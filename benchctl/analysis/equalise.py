"""Equalisation: the stand's own response on the profile's lines, and the drive corrected by it.

Pure computation on arrays, no I/O. The run (``benchctl.run.equalise``, ``run.equalise``) plays a
short low-level pre-test, hands its recorded stand angle here, and sends the corrected drive
through the same limit checks as any motion before the stand moves.

1. **Pre-test design** (:func:`pretest_design`). A multisine at ``level`` × the profile's
   amplitudes, on the profile's own lines when its period ``T_p`` is at most ``max_period_s``,
   played for ``periods`` whole periods after a fade-in and a settling lead. When ``T_p`` is
   longer, the pre-test uses the shorter period ``T_e = T_p / m`` (m the least whole number
   with ``T_e ≤ max_period_s``): its lines are the harmonics ``j/T_e`` nearest to the profile's
   lines (each carrying the power of the profile's lines it stands for, Schroeder phases), and
   the response is interpolated between them (below).
2. **Response** (:func:`estimate_response`). The measured stand angle over the pre-test's whole
   periods is fitted line by line at the known frequencies by least squares
   (:func:`benchctl.analysis.excitation.fidelity_of_table`), phases referred to the pre-test's
   start: ``H_s(f_j) = ĉ_j / (A_j e^{jφ_j})``, with the standard deviation of ``|ĉ_j|`` from
   the noise at the line, so ``sd|H_s| = sd_j / A_j`` and, in phase, ``sd_j / |ĉ_j|`` rad.
3. **At the profile's lines** (:func:`response_at`): the pre-test's own lines directly; a
   shorter pre-test period: ``log|H_s|`` and the unwrapped ``arg H_s`` interpolated linearly in
   frequency (held at the end values outside the pre-test's lines).
4. **Corrected drive** (:func:`corrected_table`): per line ``A'_k = A_k / |H_s(f_k)|``,
   ``φ'_k = φ_k − arg H_s(f_k)``, so that the stand's measured motion is the designed one,
   amplitudes and time history. A line is *not corrected* (gain 1, phase 0; reported) when
   ``|H_s|`` is below ``min_gain_db`` (the stand barely moves there) or the estimate's
   uncertainty is over ``max_uncertainty_db``. A boost is *capped* at ``max_boost_db``, at the
   line's own reach (its amplitude alone within the angle, rate and acceleration limits), and
   then — when the whole drive's peaks (fades included, on the setpoint grid) would exceed the
   stand's limits — every boost is shortened by the same fraction of its dB (bisection) until
   the drive fits; if the phase and cut corrections alone do not fit, the whole correction is
   shortened likewise. Capped lines are reported with the gain they got.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from benchctl.analysis.excitation import fidelity_of_table
from benchctl.analysis.fidelitylimits import StandReach
from benchctl.errors import DataError
from benchctl.harmonics import HarmonicTable
from benchctl.profiles.synthesis import evaluate_table, sample_times

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

LEVEL = 0.2  # the pre-test's amplitudes, × the profile's
MAX_PERIOD_S = 20.0  # a profile period longer than this: a pre-test on a shorter period
FADE_S = 2.0  # the pre-test's fades
SETTLE_S = 3.0  # after the fade-in, before the analysed periods (the stand's transient)
MIN_GAIN_DB = -20.0  # a line where the stand moves less than this is not corrected
MAX_BOOST_DB = 10.0  # no line is driven up by more than this
MAX_UNCERTAINTY_DB = 0.5  # a response whose 1-σ amplitude uncertainty exceeds this: no correction
BISECT_STEPS = 12
DB = 20.0 / math.log(10.0)  # dB per neper (amplitude)


@dataclass(frozen=True)
class PretestDesign:
    """The pre-test of one axis: its table and where its whole periods lie (from its start)."""

    table: HarmonicTable
    period_s: float
    periods: int
    analysis_start_s: float  # the analysed whole periods: [start, start + periods·period_s]
    own_lines: bool  # True: the profile's own lines; False: a shorter period, interpolated
    note: str

    @property
    def analysis_end_s(self) -> float:
        return self.analysis_start_s + self.periods * self.period_s

    def to_dict(self) -> dict[str, Any]:
        return {
            "period_s": self.period_s,
            "periods": self.periods,
            "duration_s": self.table.duration_s,
            "n_lines": self.table.n_lines,
            "analysis_s": [self.analysis_start_s, self.analysis_end_s],
            "own_lines": self.own_lines,
            "note": self.note,
        }


def _schroeder(n: int) -> FloatArray:
    i = np.arange(1, n + 1, dtype=float)
    return np.asarray(-np.pi * i * (i - 1) / max(n, 1), dtype=float)


def pretest_design(
    table: HarmonicTable,
    *,
    level: float = LEVEL,
    periods: int = 1,
    max_period_s: float = MAX_PERIOD_S,
    fade_s: float = FADE_S,
    settle_s: float = SETTLE_S,
) -> PretestDesign:
    """The low-level pre-test for ``table`` (module notes, 1). Raises ``DataError`` when the
    table has no period or no line."""
    if not 0 < level <= 1:
        raise DataError(f"equalise: level = {level!r}; expected 0 < level ≤ 1")
    if periods < 1:
        raise DataError(f"equalise: periods = {periods!r}; expected at least 1")
    tp = table.period_s
    use = np.asarray(table.amp_deg) > 0
    if tp is None or not tp > 0:
        raise DataError("equalise: the profile's lines have no repetition period T_p")
    if not np.any(use):
        raise DataError("equalise: the profile's table has no line (every amplitude is 0)")
    f, a, p = table.freq_hz[use], table.amp_deg[use], table.phase_rad[use]
    if tp <= max_period_s * (1 + 1e-9):
        period, own = float(tp), True
        freq, amp, phase = f, level * a, p
        note = f"the profile's own {f.size} lines at {level:g} × their amplitudes, T_p {tp:g} s"
    else:
        m = math.ceil(tp / max_period_s - 1e-9)
        period, own = float(tp) / m, False
        j = np.maximum(1, np.rint(f * period)).astype(np.int64)
        uj = np.unique(j)
        power = np.array([np.sum(a[j == v] ** 2) for v in uj])
        freq = uj / period
        amp = level * np.sqrt(power)
        phase = _schroeder(uj.size)
        note = (f"T_p {tp:g} s is over {max_period_s:g} s: {uj.size} lines on the shorter period "
                f"{period:g} s (T_p/{m}) nearest to the profile's {f.size}, at {level:g} × their "
                "power; the response interpolated between them")
    start = fade_s + settle_s
    duration = start + periods * period + fade_s
    pre = HarmonicTable(np.asarray(freq, dtype=float), np.asarray(amp, dtype=float),
                        np.asarray(phase, dtype=float), duration, fade_s, fade_s, period,
                        {"pretest": True})
    return PretestDesign(pre, period, periods, start, own, note)


@dataclass
class Response:
    """The stand's measured response on the pre-test's lines (angle / commanded)."""

    freq_hz: FloatArray
    h: ComplexArray  # H_s(f): |H_s| the gain, arg H_s the phase (rad, negative = lag)
    gain_sd: FloatArray  # 1-σ of |H_s|
    n_periods: int

    @property
    def gain_db(self) -> FloatArray:
        return np.asarray(DB * np.log(np.maximum(np.abs(self.h), 1e-300)), dtype=float)

    @property
    def gain_sd_db(self) -> FloatArray:
        mag = np.maximum(np.abs(self.h), 1e-300)
        return np.asarray(DB * self.gain_sd / mag, dtype=float)

    def to_dict(self) -> dict[str, Any]:
        return {
            "freq_hz": [float(v) for v in self.freq_hz],
            "gain_db": [float(v) for v in self.gain_db],
            "gain_sd_db": [float(v) for v in self.gain_sd_db],
            "phase_deg": [float(v) for v in np.degrees(np.angle(self.h))],
            "n_periods": self.n_periods,
        }


def estimate_response(
    t: ArrayLike, x: ArrayLike, design: PretestDesign, t_start: float,
    drive: tuple[ArrayLike, ArrayLike] | None = None,
) -> Response:
    """H_s on the pre-test's lines from the stand's measured angle ``x`` at instants ``t`` (the
    pre-test started at ``t_start`` on the same clock), against the pre-test's design — or,
    given ``drive`` (instants, setpoints: what the stand was actually sent), against that: a
    streaming host that held or rejoined on a busy machine changed the stand's input, and the
    stand's response is its output over its input. Raises ``DataError`` when the record does
    not hold the analysed periods."""
    tab = design.table
    window = (t_start + design.analysis_start_s, t_start + design.analysis_end_s)
    # fidelity's lines are sorted by frequency; the pre-test's table is too (by construction or
    # as the profile's): map them by frequency all the same
    order = np.argsort(tab.freq_hz)
    f = tab.freq_hz[order]

    def lines(tt: ArrayLike, v: ArrayLike) -> tuple[ComplexArray, FloatArray, int]:
        fid = fidelity_of_table(tt, v, tab, window, t_start)
        if fid.freq.size != f.size or not np.allclose(fid.freq, f):
            raise DataError("equalise: the pre-test's fit did not return its lines")
        c = fid.achieved_amp * np.exp(1j * np.radians(fid.phase_deg))
        return np.asarray(c, dtype=np.complex128), np.asarray(fid.amp_sd, dtype=float), \
            fid.n_periods

    cx, sx, n_per = lines(t, x)
    if drive is None:
        a = tab.amp_deg[order]
        return Response(f, cx / a, sx / a, n_per)
    cu, su = lines(*drive)[:2]
    h = cx / cu
    rel = np.hypot(sx / np.abs(cx), su / np.abs(cu))
    return Response(f, np.asarray(h, dtype=np.complex128), np.abs(h) * rel, n_per)


def response_at(resp: Response, freq_hz: ArrayLike) -> tuple[ComplexArray, FloatArray]:
    """H_s and the 1-σ of |H_s| at ``freq_hz``: the measured lines where they coincide, else
    log-gain and unwrapped phase interpolated linearly (held at the ends)."""
    f = np.asarray(freq_hz, dtype=float)
    fr = resp.freq_hz
    logg = np.log(np.maximum(np.abs(resp.h), 1e-300))
    ph = np.unwrap(np.angle(resp.h))
    rel = resp.gain_sd / np.maximum(np.abs(resp.h), 1e-300)
    lg = np.interp(f, fr, logg)
    pp = np.interp(f, fr, ph)
    rr = np.interp(f, fr, rel)
    h = np.exp(lg + 1j * pp)
    return np.asarray(h, dtype=np.complex128), np.asarray(rr * np.abs(h), dtype=float)


@dataclass
class Correction:
    """The corrected drive of one axis and what was done on each line."""

    drive: HarmonicTable
    freq_hz: FloatArray
    h: ComplexArray  # H_s at the profile's lines
    gain_sd: FloatArray
    wanted_db: FloatArray  # −20 log10 |H_s|: the drive's change the line needs
    applied_db: FloatArray  # the drive's change applied (dB)
    phase_applied_deg: FloatArray  # −arg H_s where corrected, else 0
    status: list[str]  # corrected, capped, weak_response, uncertain, zero
    boost_fraction: float  # the share of each boost (in dB) the limits allowed (1: all)
    notes: list[str] = field(default_factory=list)

    @property
    def not_corrected(self) -> list[dict[str, Any]]:
        return [
            {"freq_hz": float(self.freq_hz[i]), "status": s,
             "wanted_db": float(self.wanted_db[i]), "applied_db": float(self.applied_db[i])}
            for i, s in enumerate(self.status) if s not in ("corrected", "zero")
        ]

    @property
    def predicted_error_db(self) -> FloatArray:
        """The measured line's error re the target the corrected drive should give (dB)."""
        return np.asarray(self.applied_db - self.wanted_db, dtype=float)

    def to_dict(self) -> dict[str, Any]:
        hd = DB * np.log(np.maximum(np.abs(self.h), 1e-300))
        return {
            "freq_hz": [float(v) for v in self.freq_hz],
            "gain_db": [float(v) for v in hd],
            "gain_sd_db": [float(v) for v in DB * self.gain_sd / np.maximum(np.abs(self.h),
                                                                             1e-300)],
            "phase_deg": [float(v) for v in np.degrees(np.angle(self.h))],
            "correction_db": [float(v) for v in self.applied_db],
            "correction_phase_deg": [float(v) for v in self.phase_applied_deg],
            "status": list(self.status),
            "boost_fraction": self.boost_fraction,
            "not_corrected": self.not_corrected,
            "notes": list(self.notes),
        }


def _peaks(table: HarmonicTable, rate_hz: float) -> tuple[float, float, float]:
    t = sample_times(table.duration_s, rate_hz)
    return tuple(float(np.max(np.abs(evaluate_table(table, t, d)))) for d in range(3))  # type: ignore[return-value]


def _fits(table: HarmonicTable, reach: StandReach, rate_hz: float) -> bool:
    pa, pr, pacc = _peaks(table, rate_hz)
    return (pa <= reach.angle_deg * (1 - 1e-6) and pr <= reach.rate_deg_s * (1 - 1e-6)
            and pacc <= reach.accel_deg_s2 * (1 - 1e-6))


def corrected_table(
    table: HarmonicTable,
    h: ArrayLike,
    gain_sd: ArrayLike,
    reach: StandReach,
    rate_hz: float,
    *,
    min_gain_db: float = MIN_GAIN_DB,
    max_boost_db: float = MAX_BOOST_DB,
    max_uncertainty_db: float = MAX_UNCERTAINTY_DB,
) -> Correction:
    """The drive that makes the stand play ``table`` (module notes, 4). ``h``, ``gain_sd``: the
    stand's response and its 1-σ at ``table``'s lines (same order). The drive keeps the
    table's frequencies, fades, duration and period."""
    hh = np.asarray(h, dtype=np.complex128)
    sd = np.asarray(gain_sd, dtype=float)
    f, a, p = table.freq_hz, table.amp_deg, table.phase_rad
    if hh.shape != f.shape or sd.shape != f.shape:
        raise DataError(f"equalise: {hh.size} responses for {f.size} lines")
    mag = np.abs(hh)
    with np.errstate(divide="ignore", invalid="ignore"):
        gain_db = np.where(mag > 0, DB * np.log(np.where(mag > 0, mag, 1.0)), -np.inf)
        sd_db = np.where(mag > 0, DB * sd / np.where(mag > 0, mag, 1.0), np.inf)
    wanted = -gain_db
    status: list[str] = []
    want_db = np.zeros_like(f)  # the change to apply before the limits
    phase = np.zeros_like(f)
    w = 2 * np.pi * f
    for i in range(f.size):
        if not a[i] > 0:
            status.append("zero")
            continue
        if not np.isfinite(gain_db[i]) or gain_db[i] < min_gain_db:
            status.append("weak_response")
            continue
        if not np.isfinite(sd_db[i]) or sd_db[i] > max_uncertainty_db:
            status.append("uncertain")
            continue
        phase[i] = -float(np.angle(hh[i]))
        d = float(wanted[i])
        if d > max_boost_db:
            d = max_boost_db
            status.append("capped")
        else:
            status.append("corrected")
        # the line alone within the stand's reach
        own = min(reach.angle_deg, reach.rate_deg_s / w[i], reach.accel_deg_s2 / w[i] ** 2)
        cap = DB * math.log(own / a[i]) if own > a[i] else 0.0
        if d > 0 and d > cap:
            d = max(cap, 0.0)
            status[-1] = "capped"
        want_db[i] = d
    boost = want_db > 0

    def drive(frac_boost: float, frac_all: float = 1.0) -> HarmonicTable:
        d = np.where(boost, want_db * frac_boost, want_db) * frac_all
        amp = a * np.exp(d / DB)
        return HarmonicTable(f.copy(), amp, p + phase * frac_all, table.duration_s,
                             table.fade_in_s, table.fade_out_s, table.period_s,
                             dict(table.meta, equalised=True))

    notes: list[str] = []
    frac_b, frac_a = 1.0, 1.0
    if not _fits(drive(1.0), reach, rate_hz):
        if np.any(boost) and _fits(drive(0.0), reach, rate_hz):
            lo, hi = 0.0, 1.0
            for _ in range(BISECT_STEPS):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if _fits(drive(mid), reach, rate_hz) else (lo, mid)
            frac_b = lo
            notes.append(f"the boosts shortened to {100 * frac_b:.1f} % of their dB to keep the "
                         "drive within the stand's limits")
        else:
            lo, hi = 0.0, 1.0
            for _ in range(BISECT_STEPS):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if _fits(drive(0.0, mid), reach, rate_hz) else (lo, mid)
            frac_b, frac_a = 0.0, lo
            notes.append(f"the whole correction shortened to {100 * frac_a:.1f} % to keep the "
                         "drive within the stand's limits")
        for i in range(f.size):
            if status[i] in ("corrected", "capped") and (frac_a < 1 or boost[i]):
                status[i] = "capped"
    final = drive(frac_b, frac_a)
    applied = np.where(boost, want_db * frac_b, want_db) * frac_a
    return Correction(final, f.copy(), hh, sd, wanted, applied, np.degrees(phase * frac_a),
                      status, frac_b * frac_a if np.any(boost) else frac_a, notes)


__all__ = [
    "Correction",
    "PretestDesign",
    "Response",
    "corrected_table",
    "estimate_response",
    "pretest_design",
    "response_at",
]
