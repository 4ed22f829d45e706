"""Line-wise estimation: the spectra of reference and instrument at the excited lines of a
periodic multisine, H(f_k) with intervals, and the unbiased linear/incoherent split.

The stand plays lines ``f_k = k/T_p`` over whole periods, the best excitation there is for
frequency-domain measurement (Pintelon & Schoukens, *System Identification*, ch. 2–3). When the
record holds ``n`` whole periods of a known line set (from a benchctl recording's profile,
from ``period_s``, or detected in the reference, see :func:`benchctl.analysis.lines.detect_period`):

1. **Fit** (:mod:`benchctl.analysis.linefit`). The excited lines (and a mean) are fitted by
   least squares to the samples actually present on the analysis grid (slot instants
   ``s·Δt``; gaps are masked slots): ``v_s ≈ c₀ + Re Σ_k c_k e^{j2π f_k s Δt}``, separately
   for the reference x and the instrument y. Over whole periods of a gap-free uniform grid
   this is the DFT over the record (``c_k = 2 X_k / N``) and is computed so; otherwise by
   conjugate gradients on the normal equations, the sums ``Σ v_s e^{−j2π f_k s Δt}`` by
   chirp-z transforms (exact, O(N log N)).
2. **Noise at each line** (:mod:`benchctl.analysis.linenoise`; the power ``s_k = E|N_k|²/2``
   a line's coefficient picks up from the incoherent error): from the record's unexcited DFT
   bins nearby (the residual's periodogram, at least ``NOISE_BINS`` of them within
   ``±NOISE_REACH`` bins), else — every bin excited, as with one period per record — from the
   local polynomial method: the deviation of ``E_j = c^y_j − c^x_j`` from ``P(f_j)·c^x_j``
   (P of degree 2) over the ``LPM_LINES`` nearest other lines (the line itself left out, so
   that its noise estimate is independent of its own noise).
3. **H and its interval.** ``H_k = c^y_k / c^x_k``; gain and phase each with the standard
   deviation ``√s_k/|c^x_k|`` (gain) and ``√s_k/|c^y_k|`` (phase, rad) and a Student-t quantile
   for the noise estimate's degrees of freedom. The reference is taken as noise-free.
4. **Split.** Linear part ``Σ_k (|E_k|²/2 − s_k)`` (= Σ |1 − H_k|²·A_k²/2 with the noise's
   own contribution removed, so a noise-free record has no incoherent part and a noisy one is
   not biased); incoherent part the rest: the residual's variance, the noise at the lines
   ``Σ s_k`` and the variance the mean removal took out (``≈ G_ε(0)/(2T)``, half the noise
   level at the lowest bin). Their sum is σ̂² plus the mean removal's loss over whole periods
   without gaps (with gaps the lines' variance is taken over whole periods, not over the
   samples present). Only *reliable* lines (SNR ``|c^x_k|²/(2 s_k)`` ≥ ``SNR_FLOOR``) count in
   the linear part; a weaker line's power stays in the incoherent part (its Ĥ_k is mostly
   noise; the sum is unchanged). Weak lines are reported with their SNR and kept out of the
   gain table (:func:`benchctl.analysis.lineperiods.periods_from_lines`) and of prediction.
5. **Interval of σ** (:func:`benchctl.analysis.uncertainty.mls_interval`): the linear part
   varies only through its cross term with the noise, ``Σ 2 P_k s_k`` (Gaussian); the noise
   in two parts, the lowest ``LOW_BINS`` DFT bins (with the mean-removal term: a slow drift
   lives there, with few degrees of freedom) and the rest, each a scaled χ² with
   Satterthwaite's ν from its own bins (``var ≈ level²``), corrected for ν's bias
   (:func:`unbiased_dof`); combined by the modified large-sample method so that each keeps
   its own skew. With no line among the lowest ``2·DRIFT_BINS`` bins, those bins' term is a
   drift's, from the residual's cosine transform with its exact quantiles; and a power that
   changes from segment to segment widens the interval
   (:mod:`benchctl.analysis.stationarity`).

Pure computation on arrays; see :func:`analyze_lines`.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.fft import irfft
from scipy.special import stdtrit

from benchctl.analysis.distortion import Distortion, analyze_distortion
from benchctl.analysis.linefit import fit_lines, grid_offsets, refine_period
from benchctl.analysis.linenoise import line_noise
from benchctl.analysis.lines import (
    LinesError,
    LineSet,
    whole_periods,
)
from benchctl.analysis.stationarity import (
    MIN_SEGMENTS,
    ONE_PERIOD_SEGMENTS,
    Drift,
    Stationarity,
    assess,
    fit_drift,
    low_part,
)
from benchctl.analysis.sums import dot
from benchctl.analysis.uncertainty import mls_interval, unbiased_dof

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]

LOW_BINS = 5  # the lowest DFT bins: their own term of the σ interval (drift) …
#: … or, with no line among the lowest 2·DRIFT_BINS bins, these bins' frequencies as the
#: residual's lowest 2·DRIFT_BINS cosine coefficients (stationarity.low_part: a drift)
DRIFT_BINS = 10
GROUP_RATIO = 3  # … then groups of bins each this many times longer
REFERENCE_FIT_MIN = 0.99  # the fitted lines must hold this share of the reference's variance
#: a line is *reliable* when its signal-to-noise ratio ``|c^x_k|²/(2 s_k)`` (= 1/E|Ĥ_k − H_k|²)
#: is at least this: Ĥ_k within ±0.32 (one standard deviation, complex) of H_k. Weaker lines
#: (a profile's band edges, lines a few 1e-8° high) are reported with their SNR, but kept out
#: of the gain table, the linear part and prediction: their Ĥ_k is mostly noise
SNR_FLOOR = 10.0


@dataclass
class LineAnalysis:
    """Everything the line-wise estimate says (deg, deg², Hz; intervals 95 %)."""

    lines: LineSet  # the period refined to the reference (see refine_period)
    period_nominal: float
    n_periods: int
    freq: FloatArray
    ref_amplitude: FloatArray
    h: ComplexArray
    gain_ci95: FloatArray  # (K, 2)
    phase_ci95_deg: FloatArray  # (K, 2)
    coherence: FloatArray
    noise: FloatArray  # s_k
    noise_dof: FloatArray
    noise_lpm: NDArray[np.bool_]
    linear: float
    linear_ci95: tuple[float, float]
    incoherent: float
    incoherent_ci95: tuple[float, float]
    mean_removal: float
    variance: float  # linear + incoherent: the error's variance, mean removal corrected
    variance_ci95: tuple[float, float]
    dof: float  # equivalent ν of ``variance`` (2θ²/var)
    dof_parts: dict[str, float]
    reference_fit: float  # share of the reference's variance the lines hold
    exact: bool
    iterations: int
    warnings: list[str] = field(default_factory=list)
    distortion: Distortion | None = None  # an odd multisine over ≥ 2 periods
    snr: FloatArray = field(default_factory=lambda: np.zeros(0))  # |c^x_k|²/(2 s_k)
    reliable: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, dtype=bool))
    snr_floor: float = SNR_FLOOR
    band: dict[str, Any] | None = None  # the band-limited variance (analyze_lines' band_hz)
    stationarity: Stationarity | None = None  # the segment-to-segment test (stationarity.py)
    drift: Drift | None = None  # the residual's lowest cosine coefficients (stationarity.py)

    @property
    def gain(self) -> FloatArray:
        return np.asarray(np.abs(self.h), dtype=float)

    @property
    def phase_deg(self) -> FloatArray:
        return np.asarray(np.degrees(np.unwrap(np.angle(self.h))), dtype=float)

    @property
    def sigma(self) -> float:
        return math.sqrt(max(self.variance, 0.0))

    @property
    def sigma_ci95(self) -> tuple[float, float]:
        lo, hi = self.variance_ci95
        return math.sqrt(max(lo, 0.0)), math.sqrt(max(hi, 0.0))

    def to_dict(self) -> dict[str, Any]:
        return {
            "source": self.lines.source,
            "period_s": self.lines.period_s,
            "period_nominal_s": self.period_nominal,
            "n_periods": self.n_periods,
            "n_lines": len(self.freq),
            "freq": self.freq.tolist(),
            "reference_amplitude": self.ref_amplitude.tolist(),
            "gain": self.gain.tolist(),
            "gain_ci95": self.gain_ci95.tolist(),
            "phase_deg": self.phase_deg.tolist(),
            "phase_ci95_deg": self.phase_ci95_deg.tolist(),
            "coherence": self.coherence.tolist(),
            "snr": self.snr.tolist(),
            "reliable": [bool(v) for v in self.reliable],
            "snr_floor": self.snr_floor,
            "n_reliable": int(np.sum(self.reliable)),
            "noise": self.noise.tolist(),
            "noise_dof": self.noise_dof.tolist(),
            "noise_method": "lpm" if self.noise_lpm.all() else (
                "unexcited" if not self.noise_lpm.any() else "mixed"),
            "linear": self.linear,
            "linear_ci95": list(self.linear_ci95),
            "incoherent": self.incoherent,
            "incoherent_ci95": list(self.incoherent_ci95),
            "mean_removal": self.mean_removal,
            "variance": self.variance,
            "variance_ci95": list(self.variance_ci95),
            "sigma": self.sigma,
            "sigma_ci95": list(self.sigma_ci95),
            "dof": self.dof,
            "dof_parts": dict(self.dof_parts),
            "reference_fit": self.reference_fit,
            "stationarity": None if self.stationarity is None else self.stationarity.to_dict(),
        }


def t975(dof: FloatArray) -> FloatArray:
    return np.asarray(stdtrit(np.asarray(dof, dtype=float), 0.975), dtype=float)


def _bin_groups(nb: int, low: int = LOW_BINS) -> list[tuple[int, int]]:
    """The DFT bins 1 … nb−1 in groups [a, b): the lowest ``low``, then groups
    ``GROUP_RATIO`` times longer each."""
    edges = [1, low + 1]
    while edges[-1] < nb:
        edges.append(min(nb, edges[-1] + GROUP_RATIO * (edges[-1] - edges[-2])))
    return list(itertools.pairwise(edges))


def _parts(
    level: FloatArray, var: FloatArray, groups: list[tuple[int, int]], coef: FloatArray
) -> list[tuple[float, float]]:
    """(value, ν) of each group of bins: Σ level, and Satterthwaite's ν from Σ var, at most
    the ν of the group's bins all at one level, ``2(Σc)²/Σc²`` (each bin holds 2 degrees of
    freedom; c its weight in the estimate)."""
    out = []
    for a, b in groups:
        val = float(level[a:b].sum())
        c = coef[a:b]
        bound = 2.0 * float(c.sum()) ** 2 / float(np.sum(c * c))
        out.append((val, min(unbiased_dof(val, float(var[a:b].sum())), bound)))
    return out


def noise_spectrum(spec: ComplexArray, deviation: ComplexArray, bins: IntArray,
                   n_valid: int) -> ComplexArray:
    """The rfft of the error less its linear part on a one-period record (its lines' noise
    from the local polynomial method): the lines' residual (``spec``, its rfft) with, at each
    such line, the coefficient's deviation from the smooth response (``c = 2X/N_v``; 0 at a
    band-edge line whose noise came from unexcited bins). Without the deviations the residual
    of a noise inside the band is little but its leakage, which sits at the record's ends."""
    full = spec.copy()
    full[bins] = deviation * (n_valid / 2.0)
    return full


def _centred_power(x: FloatArray, mask: NDArray[np.bool_]) -> float:
    """``Σ (x − x̄)²`` over the slots ``mask`` holds."""
    xd = np.where(mask, x - x[mask].mean(), 0.0)
    return dot(xd, xd)


def _power(spectrum: ComplexArray, n: int) -> float:
    """``Σ_s r_s²`` of a real series of length n from its rfft (Parseval)."""
    a = spectrum.real**2 + spectrum.imag**2
    total = 2.0 * float(a.sum()) - float(a[0]) - (float(a[-1]) if n % 2 == 0 else 0.0)
    return total / n


def analyze_lines(
    x: FloatArray,
    y: FloatArray,
    mask: NDArray[np.bool_],
    dt: float,
    lines: LineSet,
    t: FloatArray | None = None,
    x_spectrum: ComplexArray | None = None,
    band_hz: tuple[float, float] | None = None,
) -> LineAnalysis:
    """The line-wise estimate on the analysis grid (see module notes).

    Parameters
    ----------
    x, y : ndarray
        Reference and instrument on the grid (deg), meaningful where ``mask``.
    mask : ndarray of bool
        Slots that hold a sample.
    dt : float
        Grid step, s.
    lines : LineSet
        The excited lines.
    t : ndarray, optional
        The samples' instants (s, per slot; NaN in gaps). When they stray from the uniform
        grid the lines are fitted at the instants themselves; default: the grid.
    x_spectrum : ndarray of complex, optional
        ``rfft(x)`` of a gap-free grid, if already made (saves a transform of a long record).
    band_hz : (lo, hi), optional
        A band for the band-limited variance (``LineAnalysis.band``, :func:`_band`).

    Raises
    ------
    LinesError
        Not whole periods, the reference not periodic in the lines, or the fit impossible.
    """
    n = len(mask)
    n_valid = int(mask.sum())
    whole_periods(n, dt, lines)
    offsets = None if t is None else grid_offsets(t, mask, dt)
    nominal = lines.period_s
    fit = fit_lines(np.vstack((x, y)), mask, dt, lines.period_s, lines.harmonics, offsets,
                    x_spectrum)
    del x_spectrum  # used once (the caller keeps none: memory at the peak below)
    ref_var = _centred_power(x, mask)
    lines, changed = refine_period(x, mask, dt, lines, offsets, fit, ref_var)
    n_periods = whole_periods(n, dt, lines)
    if changed:
        fit = fit_lines(np.vstack((x, y)), mask, dt, lines.period_s, lines.harmonics, offsets)
    cx, cy = fit.coef[0], fit.coef[1]
    rpow = fit.residual_power()
    ref_fit = 1.0 - float(rpow[0]) / ref_var
    if ref_fit < REFERENCE_FIT_MIN or np.any(cx == 0):
        raise LinesError(
            f"the reference is not periodic in {lines.period_s:.6g} s: its {len(cx)} line(s) "
            f"hold {100 * ref_fit:.3g} % of its variance (at least "
            f"{100 * REFERENCE_FIT_MIN:g} % expected)"
        )
    e = cy - cx
    spec = fit.spectrum[1] - fit.spectrum[0]  # the residual of ε = y − x
    # of the fit, only what is used below: its two residual spectra (two records' length of
    # memory) are kept for the distortion estimate alone
    exact, iterations = fit.exact, fit.iterations
    both = fit.spectrum if lines.is_odd_multisine and n_periods >= 2 else None
    del fit
    u = 2.0 * (spec.real**2 + spec.imag**2) / float(n_valid) ** 2  # line units
    nb = len(u)
    bins = np.rint(lines.freq * n * dt).astype(np.int64)
    probe = np.ones(nb, dtype=bool)
    probe[0] = False
    if n % 2 == 0:
        probe[-1] = False
    probe[bins] = False
    noise = line_noise(e, cx, lines.freq, bins, u, probe)
    s = noise.power
    h = cy / cx
    t = t975(noise.dof)
    sd_gain = np.sqrt(s) / np.abs(cx)
    sd_phase = np.sqrt(s) / np.maximum(np.abs(cy), 1e-300)
    gain = np.abs(h)
    phase = np.degrees(np.unwrap(np.angle(h)))
    gain_ci = np.column_stack((gain - t * sd_gain, gain + t * sd_gain))
    half = np.degrees(np.minimum(t * sd_phase, np.pi))
    phase_ci = np.column_stack((phase - half, phase + half))
    coherence = np.clip(1.0 - s / np.maximum(np.abs(cy) ** 2 / 2.0, 1e-300), 0.0, 1.0)
    ref_power = np.abs(cx) ** 2 / 2.0
    snr = np.where(s > 0.0, ref_power / np.maximum(s, 1e-300), np.inf)
    reliable = snr >= SNR_FLOOR
    weak = ~reliable
    p_line = np.abs(e) ** 2 / 2.0
    lin_k = p_line - s
    # the linear part from the reliable lines; a weak line's excess over its noise cannot be
    # told from noise: it stays in the incoherent part (σ̂² is the same either way)
    linear = float(lin_k[reliable].sum())
    q = u * (n_valid / n)  # the residual's periodogram in variance units
    q[0] = 0.0
    # no line among the lowest bins: a drift's term from the residual's cosine transform
    drift_term = not np.any(bins <= 2 * DRIFT_BINS)
    groups = _bin_groups(nb, DRIFT_BINS if drift_term else LOW_BINS)
    drift = None
    if drift_term:
        g1 = groups[1] if len(groups) > 1 else groups[0]
        above = probe[g1[0]:g1[1]]
        floor = 0.5 * float(np.mean(q[g1[0]:g1[1]][above])) if above.any() else 0.0
        drift = fit_drift(irfft(spec, n), mask, DRIFT_BINS, floor)  # the residual of ε
    # the mean removal took out var(ε̄) ≈ the noise level at 1/T (line units) / 2; a drift
    # whose level rises without bound towards zero frequency has no such level: its record
    # mean is the drift's own, and only the noise floor's var(ε̄) is added back
    level1 = float(s[bins == 1][0]) if np.any(bins == 1) else float(u[1])
    mean_removal = drift.floor if drift is not None and drift.steep else 0.5 * level1
    incoherent = (float(_power(spec, n)) / n_valid + float(s.sum()) + mean_removal
                  + float(lin_k[weak].sum()))
    theta = linear + incoherent  # = σ̂² + mean_removal over whole periods without gaps
    # --- intervals: noise per bin (variance units) and its variance
    level = np.where(probe, q, 0.0)
    var_bin = level**2 / 2.0
    level[bins] += s
    var_bin[bins] += s**2 / (1.0 + 2.0 / noise.dof)
    coef = np.ones(nb)
    coef[1] += mean_removal / max(level[1], 1e-300) if level[1] > 0 else 0.0
    parts: list[tuple[float, ...]] = list(_parts(coef * level, coef**2 * var_bin, groups, coef))
    group0 = float(np.sum((coef**2 * var_bin)[groups[0][0]:groups[0][1]]))
    low_var = group0  # the lowest group's variance: its bins', or the drift term's
    if drift is not None:
        value, low_var, nu, g_low, h_low = low_part(drift, mean_removal)
        parts[0] = (value, nu, g_low, h_low)
    if n_periods >= MIN_SEGMENTS:
        stat = assess(np.where(mask, y - x, 0.0), spec, mask, dt, n_periods,
                      float(np.sum(np.maximum(lin_k, 0.0) * s)),
                      lowest_line_bin=int(bins.min()))
    elif n_periods == 1 and noise.lpm.any() and noise.deviation is not None:
        smooth = np.zeros(nb, dtype=complex)
        smooth[bins] = np.where(noise.lpm, e - noise.deviation, e) * (n_valid / 2.0)
        baseline = irfft(smooth, n)
        del smooth  # a record's length less at the analysis's peak (in assess)
        stat = assess(np.where(mask, y - x, 0.0), noise_spectrum(spec, noise.deviation, bins,
                                                                 n_valid),
                      mask, dt, ONE_PERIOD_SEGMENTS, float(np.sum(np.maximum(lin_k, 0.0) * s)),
                      baseline=baseline, lowest_line_bin=int(bins.min()))
        del baseline
    else:
        stat = None
    widen = 0.0 if stat is None else stat.widening()
    cross = max(0.0, float(np.sum(2.0 * lin_k * s)))  # unbiased: P̂_k not clipped
    var_ci = mls_interval(theta, parts, cross + widen)
    total_var = (float(np.sum(coef**2 * var_bin)) - group0 + low_var + cross
                 + (0.0 if stat is None else stat.extra_variance))
    dof = 2.0 * theta**2 / total_var if total_var > 0 else float("inf")
    # linear part: Gaussian; incoherent part: the noise components with the estimation
    # error of the noise at the lines in place of its realisation
    s2 = float(np.sum(s**2))
    s2_rel = float(np.sum(s[reliable] ** 2))
    lin_var = (max(0.0, float(np.sum(2.0 * lin_k[reliable] * s[reliable]))) + s2_rel
               + noise.var_sum * (s2_rel / s2 if s2 > 0.0 else 1.0))
    z = 1.959963984540054
    lin_half = z * math.sqrt(max(lin_var, 0.0))
    lin_ci = (max(linear - lin_half, 0.0), max(linear + lin_half, 0.0))
    var_inc = coef**2 * var_bin
    var_inc[bins] += noise.var_sum * s**2 / max(s2, 1e-300) - (
        s**2 / (1.0 + 2.0 / noise.dof))
    level_inc = level.copy()
    if weak.any():  # a weak line's whole power: a χ² with 2 degrees of freedom
        wb = bins[weak]
        level_inc[wb] += lin_k[weak]
        var_inc[wb] += np.maximum(p_line[weak], s[weak]) ** 2
    inc_parts: list[tuple[float, ...]] = list(_parts(coef * level_inc, var_inc, groups, coef))
    inc_parts[0] = parts[0] if drift is not None else inc_parts[0]
    inc_ci = mls_interval(incoherent, inc_parts, widen)
    inc_ci = (max(inc_ci[0], 0.0), max(inc_ci[1], 0.0))
    dof_parts = {f"{a}-{b - 1}": p[1] for (a, b), p in zip(groups, parts, strict=True)}
    band = None
    if band_hz is not None:
        band = _band(band_hz, n * dt, bins, lin_k, s, level, var_bin, groups)
    distortion, notes = None, []
    if lines.is_odd_multisine:
        if both is not None:
            distortion = analyze_distortion(both[0], both[1], n_valid, n_periods,
                                            lines.period_s, lines.all_excited)
        elif lines.odd:
            notes.append("no distortion estimate: an odd multisine, but the record holds one "
                         "period (the noise lies between the harmonics only over two or more: "
                         "give the profile a repeat_period_s)")
    if drift is not None and drift.flagged:
        notes.append(
            f"the error drifts: its power rises towards the record's lowest frequencies (the "
            f"residual's lowest {len(drift.values)} cosine coefficients fall as "
            f"k^−{drift.exponent:g} and hold {drift.excess + 1.0:.3g} times the noise floor's "
            "power), as a wandering bias or a random walk does; σ is this test's and depends on "
            "the test's length, and its interval is for tests of this length")
    if stat is not None and not stat.stationary:
        notes.append(
            f"the error is not stationary: its power differs from segment to segment "
            f"({stat.segments} of {stat.segment_s:.4g} s; χ² {stat.statistic:.4g} on "
            f"{stat.segments - 1} degrees of freedom, p = {stat.p_value:.2g}); σ is this "
            "test's, and its interval is widened for the process's")
    return LineAnalysis(
        lines=lines,
        period_nominal=nominal,
        n_periods=n_periods,
        freq=lines.freq,
        ref_amplitude=np.abs(cx),
        h=h,
        gain_ci95=gain_ci,
        phase_ci95_deg=phase_ci,
        coherence=coherence,
        noise=s,
        noise_dof=noise.dof,
        noise_lpm=noise.lpm,
        linear=linear,
        linear_ci95=lin_ci,
        incoherent=incoherent,
        incoherent_ci95=inc_ci,
        mean_removal=mean_removal,
        variance=theta,
        variance_ci95=(max(var_ci[0], 0.0), var_ci[1]),
        dof=dof,
        dof_parts=dof_parts,
        reference_fit=ref_fit,
        exact=exact,
        iterations=iterations,
        warnings=notes,
        distortion=distortion,
        snr=snr,
        reliable=reliable,
        band=band,
        stationarity=stat,
        drift=drift,
    )


def _band(band_hz: tuple[float, float], span: float, bins: IntArray, lin_k: FloatArray,
          s: FloatArray, level: FloatArray, var_bin: FloatArray,
          groups: list[tuple[int, int]]) -> dict[str, Any]:
    """The error's variance in ``band_hz`` from the record's DFT bins there: over whole periods
    the bins split the variance exactly (Parseval), so the band's share is the lines' power in
    the band (``Σ (P̂_k − s_k)``, a line in or out whole) plus the noise's: the residual's bins
    and the noise at the lines ``s_k``, each bin weighted by the share of its width
    ``f_j ± 1/(2T)`` inside the band (an edge on a bin takes half of it: counting it whole read
    a noise-only band ``1/(T·width)`` high) — no smoothing, so no leakage in or out of the band
    (the lag-window PSD's area reads a band of a few tenths of a Hz 1–8 % low). The truth it
    estimates: the lines' power in ``[lo, hi]`` plus ``∫_lo^hi G_noise df``. Interval as σ²'s:
    the lines' cross term Gaussian, the noise bins by groups, scaled χ², combined by the
    modified large-sample method."""
    lo, hi = band_hz
    nb = len(level)
    df = 1.0 / span
    f = np.arange(nb) * df
    tol = 1e-9 * max(hi, df)
    # the noise's density counts over [lo, hi] only: bin j stands for f_j ± Δf/2, weighted by
    # its overlap with the band (an edge on a bin: half of it); a line is in or out whole
    w = np.clip((np.minimum(hi, f + 0.5 * df) - np.maximum(lo, f - 0.5 * df)) / df, 0.0, 1.0)
    w[0] = 0.0
    on = (f[bins] >= lo - tol) & (f[bins] <= hi + tol)
    lev = w * level  # the residual's bins and the noise at the lines
    var = w**2 * var_bin
    theta = float(lin_k[on].sum()) + float(lev.sum())
    cross = max(0.0, float(np.sum(2.0 * lin_k[on] * s[on])))
    parts = [p for p in _parts(lev, var, groups, np.ones(nb)) if p[0] > 0.0]
    lo_v, hi_v = mls_interval(theta, parts, cross) if theta > 0.0 else (0.0, 0.0)
    lo_v = max(lo_v, 0.0)
    inb = w > 0.0
    return {
        "lo": float(lo), "hi": float(hi), "method": "lines",
        "variance": theta, "variance_ci95": [lo_v, hi_v],
        "sigma": math.sqrt(max(theta, 0.0)),
        "sigma_ci95": [math.sqrt(lo_v), math.sqrt(max(hi_v, 0.0))],
        "n_lines": int(on.sum()), "n_bins": int(inb.sum()),
    }
