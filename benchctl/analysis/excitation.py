"""Excitation fidelity: how well the stand reproduced the profile's spectrum, measured.

The profile's lines ``A_k cos(2π f_k t + φ_k)`` (a :class:`benchctl.harmonics.HarmonicTable`,
``t`` from the motion's start) are what the stand is commanded to play; its servo (and any
resonance of the stand and its load) makes the *measured* angle differ. Given the stand's
recorded angle (instants and values, gaps allowed) over a window of whole periods ``T_p``:

1. **Fit.** The mean and the lines at their known frequencies are fitted by least squares to
   the samples present (:func:`benchctl.analysis.linefit.fit_lines`: the instants are placed on a
   uniform grid of ``N`` slots over ``n·T_p`` with their offsets from it, gaps masked), giving
   the achieved complex amplitude ``ĉ_k`` (phase referred to the motion's start, so that
   ``ĉ_k / (A_k e^{jφ_k})`` is the stand's response at ``f_k``).
2. **Noise at each line** ``s_k`` (the variance a line's coefficient picks up, per
   component) from the residual's unexcited DFT bins near the line, else — every nearby bin
   a line — from the local polynomial method on ``ĉ_k − c_k`` against the target ``c_k``
   (:mod:`benchctl.analysis.lines`, step 2). The achieved amplitude's standard deviation is
   ``√s_k``; its 95 % interval uses the Student t of the noise estimate's degrees of freedom.
3. **Per line**: target and achieved amplitude, error ``20·log10(|ĉ_k|/A_k)`` dB with its
   interval, phase of the response. A line is *weak* (reported, not judged) below
   ``weak_line_db`` (default −30 dB) of the strongest; *unreachable* (reported, not judged,
   left out of the bands) when its amplitude alone needs more than the stand's limits
   (angle ``A``, rate ``A·2πf``, acceleration ``A·(2πf)²``).
4. **Per band** (third-octave bands, base 10: centres ``10^(m/10)`` Hz, edges
   ``10^((m ∓ ½)/10)``, or given edges): target power ``Σ A_k²/2`` and achieved power
   ``Σ (|ĉ_k|²/2 − s_k)`` (the noise's own share removed) over the reachable lines in the
   band, the error ``10·log10(achieved/target)`` dB and its 95 % interval
   (``var = Σ |ĉ_k|² s_k``).
5. **Overall**: the rms of the lines' dB errors weighted by their target power (judged lines),
   the variance ratio achieved/target over the lines, and the measured motion's whole
   variance: the lines' ``Σ |ĉ_k|²/2`` plus the residual's mean square on the samples present
   (off-line content — distortion, noise, transients — is that residual).
6. **Judgement** per band: ``ok`` within ±``alarm_db``, ``alarm`` beyond it, ``abort`` beyond
   ±``abort_db`` (defaults 1.5 and 3 dB, in the spirit of random-vibration control); not
   judged when the band's target power is below ``weak_band_db`` (default −20 dB) of the
   strongest band's (``weak``), when it holds no reachable line (``unreachable``), or when the
   estimate is not yet meaningful: less than one whole period, or a 95 % half-width over
   ``max_ci_db`` (default 0.5 dB) (``uncertain``). The overall judgement is the worst band's.

7. **During the run**, before whole periods are in: the bands' running estimate
   (:class:`benchctl.analysis.runningfidelity.RunningFidelity`).

Pure computation on arrays; see :func:`excitation_fidelity`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import stdtrit

from benchctl.analysis.fidelitylimits import (
    FidelityLimits,
    StandReach,
    bands_of,
)
from benchctl.analysis.linefit import fit_lines
from benchctl.analysis.linenoise import line_noise
from benchctl.analysis.lines import LinesError
from benchctl.errors import DataError

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

WHOLE_TOL = 0.05  # a window may miss whole periods by this share of a period
JUDGEMENTS = ("ok", "alarm", "abort")  # judged; otherwise weak, unreachable, uncertain


@dataclass
class Fidelity:
    """The measured excitation of one axis (deg, Hz, dB; intervals 95 %)."""

    window: tuple[float, float]  # the whole periods analysed (the stand's clock, s)
    period_s: float
    n_periods: int
    freq: FloatArray
    target_amp: FloatArray
    achieved_amp: FloatArray
    amp_sd: FloatArray  # standard deviation of the achieved amplitude, deg
    error_db: FloatArray
    error_ci95_db: FloatArray  # (K, 2)
    phase_deg: FloatArray  # arg(ĉ_k / c_k): the stand's phase at the line
    line_status: list[str]  # judged, weak, unreachable
    bands: list[dict[str, Any]]
    rms_error_db: float | None  # power-weighted rms of the judged lines' errors
    variance_target: float  # Σ A_k²/2, deg²
    variance_lines: float  # Σ |ĉ_k|²/2 − s_k, deg²
    variance_measured: float  # the measured motion's: Σ |ĉ_k|²/2 + the residual's, deg²
    variance_residual: float  # the residual's (off the lines: distortion, noise), deg²
    limits: FidelityLimits
    judgement: str  # ok, alarm, abort, or "not judged"
    worst_band: dict[str, Any] | None
    noise_method: str
    warnings: list[str] = field(default_factory=list)

    @property
    def variance_ratio(self) -> float:
        return self.variance_lines / self.variance_target if self.variance_target > 0 else math.nan

    def to_dict(self) -> dict[str, Any]:
        def num(v: float | None) -> float | None:
            return None if v is None or not math.isfinite(v) else float(v)

        lines = [
            {
                "freq": float(self.freq[i]),
                "target_amp": float(self.target_amp[i]),
                "achieved_amp": float(self.achieved_amp[i]),
                "amp_sd": num(float(self.amp_sd[i])),
                "error_db": num(float(self.error_db[i])),
                "error_ci95_db": [num(float(v)) for v in self.error_ci95_db[i]],
                "phase_deg": float(self.phase_deg[i]),
                "status": self.line_status[i],
            }
            for i in range(len(self.freq))
        ]
        ratio = self.variance_ratio
        return {
            "judgement": self.judgement,
            "alarm_db": self.limits.alarm_db,
            "abort_db": self.limits.abort_db,
            "rms_error_db": num(self.rms_error_db),
            "variance_target": self.variance_target,
            "variance_lines": self.variance_lines,
            "variance_measured": self.variance_measured,
            "variance_residual": self.variance_residual,
            "variance_ratio": num(ratio),
            "variance_ratio_db": num(10.0 * math.log10(ratio)) if ratio > 0 else None,
            "worst_band": self.worst_band,
            "window": list(self.window),
            "period_s": self.period_s,
            "n_periods": self.n_periods,
            "noise_method": self.noise_method,
            "bands": self.bands,
            "lines": lines,
            "warnings": list(self.warnings),
        }


def _grid(
    t: FloatArray, x: FloatArray, lo: float, span: float
) -> tuple[FloatArray, NDArray[np.bool_], FloatArray, float]:
    """The samples on a uniform grid of N slots over ``[lo, lo + span)`` (N·dt = span): values,
    mask, offsets of the instants from their slots, dt. Two samples in one slot: the nearer."""
    sel = (t >= lo - 1e-9) & (t < lo + span)
    ts, xs = t[sel], x[sel]
    if ts.size < 4:
        raise DataError(f"excitation: {ts.size} stand sample(s) in the window; at least 4 needed")
    step = float(np.median(np.diff(ts)))
    if not step > 0:
        raise DataError("excitation: the stand's instants do not increase")
    n = max(4, round(span / step))
    dt = span / n
    slot = np.clip(np.rint((ts - lo) / dt).astype(np.int64), 0, n - 1)
    off = ts - lo - slot * dt
    order = np.lexsort((np.abs(off), slot))  # per slot the nearest sample first
    first = np.ones(order.size, dtype=bool)
    first[1:] = slot[order][1:] != slot[order][:-1]
    keep = order[first]
    values = np.zeros(n)
    mask = np.zeros(n, dtype=bool)
    offsets = np.zeros(n)
    values[slot[keep]] = xs[keep]
    mask[slot[keep]] = True
    offsets[slot[keep]] = off[keep]
    return values, mask, offsets, dt


def excitation_fidelity(
    t: ArrayLike,
    x: ArrayLike,
    freq_hz: ArrayLike,
    amp_deg: ArrayLike,
    phase_rad: ArrayLike,
    period_s: float,
    window: tuple[float, float],
    t_start: float,
    *,
    limits: FidelityLimits | None = None,
    reach: StandReach | None = None,
) -> Fidelity:
    """The achieved spectrum of the measured stand angle against the target lines.

    Parameters
    ----------
    t, x : array_like
        The stand's measured angle (deg) at its instants (s, increasing; gaps allowed).
    freq_hz, amp_deg, phase_rad : array_like
        The target lines ``A_k cos(2π f_k (t − t_start) + φ_k)``; lines of zero amplitude are
        ignored. Their frequencies must be whole harmonics of ``period_s``.
    period_s : float
        The lines' repetition period ``T_p``.
    window : (float, float)
        The steady part (no fades) on the clock of ``t``; its first whole periods are used.
    t_start : float
        The motion's start on the clock of ``t`` (the phases' origin).
    limits, reach :
        The judgement's settings; the stand's limits (None: every line reachable).

    Raises
    ------
    DataError
        No line, not one whole period in the window, too few samples, or the fit impossible.
    """
    lim = limits or FidelityLimits()
    f_all = np.asarray(freq_hz, dtype=float)
    a_all = np.asarray(amp_deg, dtype=float)
    p_all = np.asarray(phase_rad, dtype=float)
    use = a_all > 0
    if not np.any(use):
        raise DataError("excitation: the profile's table has no line (every amplitude is 0)")
    order = np.argsort(f_all[use])
    freq, amp, phase = f_all[use][order], a_all[use][order], p_all[use][order]
    if not (period_s > 0 and math.isfinite(period_s)):
        raise DataError(f"excitation: period_s = {period_s!r}; expected a positive period")
    kf = freq * period_s
    harm = np.rint(kf).astype(np.int64)
    if np.any(np.abs(kf - harm) > WHOLE_TOL) or harm.min() < 1:
        raise DataError(
            f"excitation: the lines are not whole harmonics of period_s = {period_s:g} s"
        )
    lo, hi = float(window[0]), float(window[1])
    n_per = math.floor((hi - lo) / period_s + WHOLE_TOL)
    if n_per < 1:
        raise DataError(
            f"excitation: the window ({hi - lo:.4g} s) holds no whole period of {period_s:g} s"
        )
    span = n_per * period_s
    tt = np.asarray(t, dtype=float)
    xx = np.asarray(x, dtype=float)
    ok = np.isfinite(tt) & np.isfinite(xx)
    values, mask, offsets, dt = _grid(tt[ok], xx[ok], lo, span)
    n = len(mask)
    bins = harm * n_per
    if 2 * int(bins.max()) >= n:
        raise DataError(
            f"excitation: a line ({freq.max():g} Hz) lies at or above the Nyquist frequency "
            f"of the stand's sampling ({0.5 / dt:g} Hz)"
        )
    try:
        fit = fit_lines(values, mask, dt, period_s, harm,
                        offsets if np.any(offsets[mask]) else None)
    except LinesError as e:
        raise DataError(f"excitation: {e}") from None
    c_hat = fit.coef[0]
    # the target's complex amplitudes on the grid's origin lo
    c_tgt = amp * np.exp(1j * (phase + 2.0 * np.pi * freq * (lo - t_start)))
    n_valid = int(mask.sum())
    spec = fit.spectrum[0]
    u = 2.0 * (spec.real**2 + spec.imag**2) / float(n_valid) ** 2
    nb = len(u)
    probe = np.ones(nb, dtype=bool)
    probe[0] = False
    if n % 2 == 0:
        probe[-1] = False
    probe[bins] = False
    warnings: list[str] = []
    try:
        noise = line_noise(c_hat - c_tgt, c_tgt, freq, bins, u, probe)
        s, dof = noise.power, noise.dof
        method = "lpm" if noise.lpm.all() else ("unexcited" if not noise.lpm.any() else "mixed")
    except LinesError:  # few lines, all bins excited: the residual taken as white
        free = max(1, n_valid - 1 - 2 * len(freq))
        s = np.full(len(freq), 2.0 * float(fit.residual_power()[0]) / free / n_valid)
        dof = np.full(len(freq), float(free))
        method = "white"
        warnings.append("excitation: the noise at the lines from the whole residual (white)")
    t95 = np.asarray(stdtrit(dof, 0.975), dtype=float)
    ach = np.abs(c_hat)
    sd = np.sqrt(np.maximum(s, 0.0))
    with np.errstate(divide="ignore"):
        err = 20.0 * np.log10(ach / amp)
        ci = np.column_stack((
            20.0 * np.log10(np.maximum(ach - t95 * sd, 0.0) / amp),
            20.0 * np.log10((ach + t95 * sd) / amp),
        ))
    resp = c_hat / c_tgt
    ph = np.degrees(np.unwrap(np.angle(resp)))
    # which lines count
    status = ["judged"] * len(freq)
    weak = amp < amp.max() * 10.0 ** (lim.weak_line_db / 20.0)
    unreach = np.zeros(len(freq), dtype=bool)
    if reach is not None:
        unreach = reach.unreachable(freq, amp)
    for i in range(len(freq)):
        if unreach[i]:
            status[i] = "unreachable"
        elif weak[i]:
            status[i] = "weak"
    judged = np.array([st == "judged" for st in status])
    # bands
    p_tgt = amp**2 / 2.0
    p_ach = ach**2 / 2.0 - s
    bands: list[dict[str, Any]] = []
    specs = bands_of(lim, freq)
    powers = []
    for blo, _c, bhi in specs:
        inb = (freq >= blo) & (freq < bhi) & ~unreach
        powers.append(float(p_tgt[inb].sum()))
    strongest = max(powers) if powers else 0.0
    meaningful_time = n_per >= 1
    for (blo, centre, bhi), pt in zip(specs, powers, strict=True):
        inb_all = (freq >= blo) & (freq < bhi)
        if not inb_all.any():
            continue
        inb = inb_all & ~unreach
        entry: dict[str, Any] = {
            "lo_hz": blo, "centre_hz": centre, "hi_hz": bhi,
            "n_lines": int(inb_all.sum()), "n_unreachable": int((inb_all & unreach).sum()),
            "target_power": pt, "achieved_power": None, "error_db": None,
            "error_ci95_db": None, "judgement": "unreachable",
        }
        if inb.any():
            pa = float(p_ach[inb].sum())
            var = float(np.sum(ach[inb] ** 2 * s[inb]))
            tq = float(np.max(t95[inb]))
            half = tq * math.sqrt(max(var, 0.0))
            entry["achieved_power"] = pa
            e_db = 10.0 * math.log10(pa / pt) if pa > 0 else -math.inf
            lo_db = 10.0 * math.log10((pa - half) / pt) if pa - half > 0 else -math.inf
            hi_db = 10.0 * math.log10((pa + half) / pt) if pa + half > 0 else -math.inf
            entry["error_db"] = e_db if math.isfinite(e_db) else None
            entry["error_ci95_db"] = [v if math.isfinite(v) else None for v in (lo_db, hi_db)]
            width = max(e_db - lo_db, hi_db - e_db)
            if pt < strongest * 10.0 ** (lim.weak_band_db / 10.0):
                entry["judgement"] = "weak"
            elif not meaningful_time or not width <= lim.max_ci_db:
                entry["judgement"] = "uncertain"
            else:
                entry["judgement"] = ("abort" if abs(e_db) > lim.abort_db else
                                      "alarm" if abs(e_db) > lim.alarm_db else "ok")
        bands.append(entry)
    jb = [b for b in bands if b["judgement"] in JUDGEMENTS]
    worst = max(jb, key=lambda b: abs(b["error_db"])) if jb else None
    if any(b["judgement"] == "abort" for b in jb):
        verdict = "abort"
    elif any(b["judgement"] == "alarm" for b in jb):
        verdict = "alarm"
    else:
        verdict = "ok" if jb else "not judged"
    w = p_tgt[judged & np.isfinite(err)]
    rms = (float(np.sqrt(np.sum(w * err[judged & np.isfinite(err)] ** 2) / w.sum()))
           if w.size and w.sum() > 0 else None)
    var_resid = float(fit.residual_power()[0]) / n_valid
    return Fidelity(
        window=(lo, lo + span),
        period_s=float(period_s),
        n_periods=n_per,
        freq=freq,
        target_amp=amp,
        achieved_amp=ach,
        amp_sd=sd,
        error_db=err,
        error_ci95_db=ci,
        phase_deg=ph,
        line_status=status,
        bands=bands,
        rms_error_db=rms,
        variance_target=float(p_tgt.sum()),
        variance_lines=float(p_ach.sum()),
        variance_measured=float(np.sum(ach**2) / 2.0) + var_resid,
        variance_residual=var_resid,
        limits=lim,
        judgement=verdict,
        worst_band=None if worst is None else {
            k: worst[k] for k in ("lo_hz", "centre_hz", "hi_hz", "error_db", "judgement")},
        noise_method=method,
        warnings=warnings,
    )


def fidelity_of_table(
    t: ArrayLike,
    x: ArrayLike,
    table: Any,
    window: tuple[float, float],
    t_start: float,
    *,
    scale: float = 1.0,
    limits: FidelityLimits | None = None,
    reach: StandReach | None = None,
) -> Fidelity:
    """:func:`excitation_fidelity` for one axis's ``HarmonicTable`` (its amplitudes × ``scale``,
    a profile scaled to fit; without a period, the window's span is the period)."""
    period = table.period_s or (window[1] - window[0])
    return excitation_fidelity(
        t, x, table.freq_hz, np.asarray(table.amp_deg, dtype=float) * scale, table.phase_rad,
        float(period), window, t_start, limits=limits, reach=reach,
    )


def format_fidelity(fid: Fidelity | dict[str, Any]) -> str:
    """One line for a summary: overall error, variance ratio, worst band, the judgement."""
    d = fid.to_dict() if isinstance(fid, Fidelity) else fid
    rms = d.get("rms_error_db")
    vr, vdb = d.get("variance_ratio"), d.get("variance_ratio_db")
    wb = d.get("worst_band")
    worst = ("—" if not wb or wb.get("error_db") is None else
             f"{wb['error_db']:+.2f} dB at {wb['centre_hz']:.3g} Hz")
    j = str(d.get("judgement", "?"))
    tag = {"abort": "ABORT LEVEL"}.get(j, j.upper())
    var = "—" if vr is None or vdb is None else f"×{vr:.3f} ({vdb:+.2f} dB)"
    return (f"excitation: rms {'—' if rms is None else f'{rms:.2f}'} dB over the lines, "
            f"variance {var}, worst band {worst} "
            f"(alarm ±{d.get('alarm_db'):g} dB, abort ±{d.get('abort_db'):g} dB) → {tag}")


def breached(fid: Fidelity) -> list[dict[str, Any]]:
    """The judged bands beyond the alarm level."""
    return [b for b in fid.bands if b["judgement"] in ("alarm", "abort")]
