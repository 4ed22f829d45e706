"""Prediction: the dynamic error σ an instrument would show under another motion (another sea
state, another ship), from the response and the noise measured in one line-wise analysis.

The error of a linear instrument with additive noise under a stationary motion of one-sided
density ``G`` is ``σ² = ∫ |H(f) − 1|² G(f) df + ∫ G_n(f) df`` (about the mean). A benchctl
motion is a table of lines ``A_j`` at ``f_j``, so the exact discrete form is used::

    σ² = Σ_j |H(f_j) − 1|²·A_j²/2  +  N

- **H(f_j)** comes from the measured line-wise response ``Ĥ_k`` (:class:`LineAnalysis`):
  at a measured line it is that line's ``Ĥ_k``; between two measured lines it is their linear
  (complex) interpolation, when they are neighbours — consecutive harmonics, or two apart (an
  odd multisine), or each within ``INTERP_NEAR`` (20 %) of ``f_j``. Anywhere else (below the
  lowest line, above the highest, inside a wider hole of the tested lines) H was not measured
  and is **not guessed**: those lines' variance is reported as the share outside the tested
  band and left out of σ; ``sigma_outside_bound`` adds it back whole, which bounds the error
  when ``|1 − H| ≤ 1`` there (an instrument that follows the motion no worse than not at all).
- **The linear part** ``L = Σ_j P_j (|D̂_j|² − v_j)``, ``P_j = A_j²/2``, ``D̂_j = Ĥ(f_j) − 1``,
  has the noise's own share ``v_j = E|Ĥ(f_j) − H(f_j)|²`` removed (as the line-wise split
  does), so it is unbiased for a noisy measurement.
- **The noise part** ``N`` is the measurement's whole incoherent variance (the mean removal
  added back): noise taken as independent of the motion — instrument noise, quantisation —
  so it carries over unchanged to another motion. Drift carries over too; what does not is an
  incoherent error that grows with the motion (distortion, the time bases' error ``σ_ẋ²δ²``):
  the CLI states the measurement's timing contribution beside the prediction.
- **Interval** (``sigma_ci95``): the delta method for the linear part — Gaussian with variance
  ``2 Σ_k c_k |g_k|² + Σ_kl M_kl² c_k c_l + Σ_k M_kk² c_k²·2/ν_k``, ``|g_k|²`` estimated
  without its noise bias as ``max(|ĝ_k|² − Σ_l M_kl² c_l, 0)`` (``c_k = 2 s_k/|c^x_k|²`` the
  complex variance of ``Ĥ_k``, ``g_k = Σ_j P_j a_jk D̂_j`` and ``M_kl = Σ_j P_j a_jk a_jl``
  with ``a_jk`` the interpolation weights; the last term the estimation error of ``v_j`` from
  the noise estimates' ν_k); the noise part a scaled χ² whose ν reproduces the measurement's
  interval of its incoherent part; the two combined by the modified large-sample method
  (:func:`benchctl.analysis.uncertainty.mls_interval`), as the analysis combines its parts.
  The interpolation's own error is bounded by ``a(1−a)/2·w²·|H''|`` per line (w the gap in
  harmonics, ``|H''|`` the curvature of Ĥ per harmonic² over the neighbouring lines, its noise
  subtracted) and added to both ends of the intervals (``interpolation_bound``).

- **Weak lines.** A measured line whose SNR (``1/E|Ĥ_k − H_k|²``) is below ``SNR_FLOOR``
  (:mod:`benchctl.analysis.linewise`) is not used: its Ĥ_k is mostly noise (a profile's band-edge
  line a few 1e-8° high reads gains like 20 000), and multiplied by a heavier sea's real motion
  there it would make σ anything. The target's lines there count as not measured.
- **σ or a bound.** What the lines where H was not measured could add is bounded line by line,
  ``Σ P_j b_j²``. Below the tested band, with |1 − H| not growing toward low frequencies (a
  lag, a latency, a gain error) up to the band's lowest octave, ``b_j`` is the smallest upper
  end of ``|1 − Ĥ_k|`` over the M measured lines of that octave (``f_k ≤ 2 f_lowest``), each
  ``|1 − Ĥ_k| + √(c_k·F)`` with F the upper ``0.025/M`` point of an F(2, ν_k)
  (``|Ĥ_k − H_k|²/c_k`` is one): all M hold together with 97.5 % (Bonferroni), so their
  smallest does — the lowest reliable line alone, often barely above the SNR floor, gave a
  bound several times |1 − H|. In a hole between measured lines the larger of the two sides'
  upper 95 % ends; above the band 1 (an instrument that follows the motion no worse than not
  at all). ``sigma_bound`` = √(upper end of the
  variance's interval + that). When it exceeds σ by more than ``BOUND_SMALL`` (5 %), σ is not
  an estimate of the target's σ: the prediction is **bounded** (``bounded``; the JSON form
  gives ``sigma`` null and the bound), and says where the unmeasured motion lies. Otherwise σ
  is the measured lines' and its interval's upper end holds the bound.

Pure computation on arrays: :func:`predict`, with :func:`response_from_lines` and
:func:`noise_from_lines` to take both from a :class:`LineAnalysis`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq
from scipy.special import ndtri

from benchctl.analysis.linewise import SNR_FLOOR
from benchctl.analysis.result import _clean, _list
from benchctl.analysis.uncertainty import chi2_ppf, mls_interval
from benchctl.errors import DataError

if TYPE_CHECKING:
    from benchctl.analysis.linewise import LineAnalysis

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]

ON_LINE = 1e-9  # a target line "on" a measured line: relative distance in frequency
INTERP_MAX_STEP = 2  # neighbouring measured lines: harmonics at most this far apart …
INTERP_NEAR = 0.2  # … or each within this share of the frequency
CURVATURE_REACH = 7  # |H''| from the second differences of the lines within ± this many
OUTSIDE_WARN = 0.01  # warn when this share of the target's variance lies outside the band
BOUND_SMALL = 0.05  # σ is given as a bound when what was not measured could add more than this
Z95 = float(ndtri(0.975))
BELOW_OCTAVE = 2.0  # below the band: |1 − H| bounded by the lines up to this × the lowest
BELOW_ALPHA = 0.025  # … all of them holding together with 1 − this (one-sided)


@dataclass(frozen=True)
class MeasuredResponse:
    """H measured at lines: ``freq`` (Hz), ``harmonics`` (k of ``f = k/T_p``), ``h`` (complex),
    ``cvar`` (``E|Ĥ_k − H_k|²``) and ``dof`` (ν of each line's noise estimate)."""

    freq: FloatArray
    harmonics: IntArray
    h: ComplexArray
    cvar: FloatArray
    dof: FloatArray


@dataclass(frozen=True)
class NoisePart:
    """The incoherent variance (deg²) to carry over, its 95 % interval and equivalent ν."""

    variance: float
    ci95: tuple[float, float]
    dof: float


def response_from_lines(la: LineAnalysis) -> MeasuredResponse:
    """H at the lines of a line-wise analysis, with the complex variance ``2 s_k/|c^x_k|²``."""
    return MeasuredResponse(
        freq=np.asarray(la.freq, dtype=float),
        harmonics=np.asarray(la.lines.harmonics, dtype=np.int64),
        h=np.asarray(la.h, dtype=complex),
        cvar=np.asarray(2.0 * la.noise / la.ref_amplitude**2, dtype=float),
        dof=np.asarray(la.noise_dof, dtype=float),
    )


def dof_from_interval(value: float, lo: float, hi: float) -> float:
    """ν of a scaled χ² whose 95 % interval has the ratio ``hi/lo`` (its skew kept); from the
    width (``2θ²/var``, var = (width/3.92)²) when ``lo`` is 0; ``inf`` for a point."""
    if not (value > 0.0 and hi > lo):
        return math.inf
    if lo > 0.0:
        target = math.log(hi / lo)

        def gap(log_nu: float) -> float:
            nu = math.exp(log_nu)
            return math.log(float(chi2_ppf(0.975, nu)) / float(chi2_ppf(0.025, nu))) - target

        if gap(math.log(1e9)) > 0.0:
            return math.inf
        if gap(math.log(0.2)) < 0.0:
            return 0.2
        return math.exp(brentq(gap, math.log(0.2), math.log(1e9), xtol=1e-10))
    var = ((hi - lo) / (2.0 * Z95)) ** 2
    return max(2.0 * value * value / var, 0.2)


def noise_from_lines(la: LineAnalysis) -> NoisePart:
    """The incoherent part of a line-wise analysis (mean removal included) and its ν."""
    lo, hi = la.incoherent_ci95
    return NoisePart(float(la.incoherent), (float(lo), float(hi)),
                     dof_from_interval(float(la.incoherent), float(lo), float(hi)))


@dataclass
class Prediction:
    """σ expected under a target motion (deg, deg², Hz; intervals 95 %). See module notes."""

    sigma: float
    sigma_ci95: tuple[float, float]
    variance: float
    variance_ci95: tuple[float, float]
    linear: float
    linear_sd: float  # standard deviation of the linear part's estimate (delta method)
    linear_ci95: tuple[float, float]
    noise: float
    noise_ci95: tuple[float, float]
    noise_dof: float
    interpolation_bound: float  # deg²: the interpolation's error bound, in the intervals
    tested_band_hz: tuple[float, float]
    untested_gaps_hz: list[tuple[float, float]]  # holes between measured lines not bridged
    target_variance: float  # Σ A_j²/2 of the target's lines
    outside_variance: float  # of it, on lines where H was not measured
    outside_share: float
    sigma_outside_bound: float  # √(variance + outside_variance): |1 − H| ≤ 1 outside
    freq: FloatArray  # the target's lines …
    amplitude: FloatArray
    inside: NDArray[np.bool_]
    error_gain: FloatArray  # |Ĥ(f_j) − 1| (NaN outside)
    contribution: FloatArray  # P_j (|D̂_j|² − v_j), deg² (0 outside)
    warnings: list[str] = field(default_factory=list)
    sigma_bound: float = math.nan  # 95 % upper bound: what was not measured bounded (notes)
    bounded: bool = False  # the bound exceeds σ by more than BOUND_SMALL: σ is not predicted
    weak_lines_hz: list[float] = field(default_factory=list)  # measured, SNR < floor: not used
    outside_bands_hz: list[tuple[float, float, int]] = field(default_factory=list)

    @property
    def n_inside(self) -> int:
        return int(self.inside.sum())

    def to_dict(self) -> dict[str, Any]:
        return {
            # bounded: σ is not predicted (what was not measured could add more than 5 %);
            # the measured lines' part stays in sigma_measured_lines
            "sigma": None if self.bounded else self.sigma,
            "sigma_ci95": None if self.bounded else list(self.sigma_ci95),
            "bounded": self.bounded,
            "sigma_bound": self.sigma_bound,
            "sigma_measured_lines": self.sigma,
            "sigma_measured_lines_ci95": list(self.sigma_ci95),
            "snr_floor": SNR_FLOOR,
            "weak_lines_hz": list(self.weak_lines_hz),
            "outside_bands_hz": [list(b) for b in self.outside_bands_hz],
            "variance": self.variance,
            "variance_ci95": list(self.variance_ci95),
            "linear": self.linear,
            "linear_sd": self.linear_sd,
            "linear_ci95": list(self.linear_ci95),
            "noise": self.noise,
            "noise_ci95": list(self.noise_ci95),
            "noise_dof": self.noise_dof,
            "interpolation_bound": self.interpolation_bound,
            "tested_band_hz": list(self.tested_band_hz),
            "untested_gaps_hz": [list(g) for g in self.untested_gaps_hz],
            "target_variance": self.target_variance,
            "outside_band_variance": self.outside_variance,
            "outside_band_share": self.outside_share,
            "sigma_outside_bound": self.sigma_outside_bound,
            "n_lines": len(self.freq),
            "n_inside": self.n_inside,
            "lines": {
                "freq": _list(self.freq),
                "amplitude": _list(self.amplitude),
                "inside": [bool(v) for v in self.inside],
                "error_gain": _list(self.error_gain),
                "contribution": _list(self.contribution),
            },
            "warnings": list(_clean(self.warnings)),
        }


def _neighbours(resp: MeasuredResponse, i: int, f: float) -> bool:
    """May H be interpolated between measured lines i and i + 1 at f?"""
    if int(resp.harmonics[i + 1] - resp.harmonics[i]) <= INTERP_MAX_STEP:
        return True
    return bool(f - resp.freq[i] <= INTERP_NEAR * f and resp.freq[i + 1] - f <= INTERP_NEAR * f)


def _curvature(resp: MeasuredResponse) -> FloatArray:
    """``|H''|`` per harmonic² about each measured line: the mean over the lines within
    ± ``CURVATURE_REACH`` of ``|Δ²Ĥ|² − E|noise of Δ²Ĥ|²`` (divided differences over the
    harmonics; weighted by the inverse of that noise), clipped at 0, square root. With fewer
    than three lines: NaN."""
    kk = len(resp.freq)
    out = np.full(kk, np.nan)
    if kk < 3:
        return out
    k = resp.harmonics.astype(float)
    h, c = resp.h, resp.cvar
    d1 = k[1:-1] - k[:-2]
    d2 = k[2:] - k[1:-1]
    w = 2.0 / (d1 + d2)
    second = w * ((h[2:] - h[1:-1]) / d2 - (h[1:-1] - h[:-2]) / d1)
    noise = w**2 * (c[2:] / d2**2 + c[1:-1] * (1.0 / d1 + 1.0 / d2) ** 2 + c[:-2] / d1**2)
    excess = np.abs(second) ** 2 - noise  # at lines 1 … K−2
    # inverse-noise weights: a weakly excited line's noisy difference does not swamp the rest
    top = float(np.max(noise))
    wt = 1.0 / np.maximum(noise, 1e-12 * top) if top > 0.0 else np.ones_like(noise)
    for m in range(kk):
        a = max(0, m - 1 - CURVATURE_REACH)
        b = min(kk - 2, m - 1 + CURVATURE_REACH + 1)
        if b > a:
            mean = float(np.sum(wt[a:b] * excess[a:b]) / np.sum(wt[a:b]))
            out[m] = math.sqrt(max(mean, 0.0))
        else:
            out[m] = 0.0
    return out


def predict(
    response: MeasuredResponse,
    noise: NoisePart,
    target_freq: ArrayLike,
    target_amp: ArrayLike,
) -> Prediction:
    """σ expected under a motion of lines ``target_amp`` (deg) at ``target_freq`` (Hz).

    Parameters
    ----------
    response : MeasuredResponse
        H measured at lines (e.g. :func:`response_from_lines`), at least one line.
    noise : NoisePart
        The incoherent variance carried over (e.g. :func:`noise_from_lines`).
    target_freq, target_amp : array_like
        The target motion's lines: ``x(t) = Σ A_j cos(2πf_j t + φ_j)`` (phases do not matter:
        over whole periods the lines' variances add).

    Returns
    -------
    Prediction
        σ, its interval, the parts, the share of the target outside the tested band.

    Raises
    ------
    DataError
        No measured line, a target without lines, non-finite or negative values.

    Examples
    --------
    >>> import numpy as np
    >>> f = np.arange(1, 11) / 10.0
    >>> resp = MeasuredResponse(f, np.arange(1, 11), np.full(10, 0.9 + 0j), np.zeros(10),
    ...                         np.full(10, np.inf))
    >>> p = predict(resp, NoisePart(0.01, (0.01, 0.01), np.inf), [0.25, 2.0], [2.0, 1.0])
    >>> round(p.variance, 6), round(p.outside_share, 3)   # 0.1²·2²/2 + 0.01; 0.5/2.5
    (0.03, 0.2)
    """
    fq = np.asarray(target_freq, dtype=float).ravel()
    amp = np.asarray(target_amp, dtype=float).ravel()
    if fq.shape != amp.shape or fq.size == 0:
        raise DataError(
            f"target lines: expected frequencies and amplitudes of one length ≥ 1, got "
            f"{fq.size} and {amp.size}"
        )
    if not (np.all(np.isfinite(fq)) and np.all(np.isfinite(amp)) and np.all(fq > 0)):
        raise DataError("target lines: expected finite frequencies > 0 Hz and finite amplitudes")
    if len(response.freq) == 0:
        raise DataError("measured response: no line; a prediction needs H measured at lines")
    if not (math.isfinite(noise.variance) and noise.variance >= 0.0):
        raise DataError(f"noise variance {noise.variance!r}: expected a finite value ≥ 0")
    # weak lines (SNR = 1/cvar below the floor) are not used: their Ĥ is mostly noise
    strong = np.asarray(response.cvar, dtype=float) * SNR_FLOOR <= 1.0
    weak_hz = sorted(float(v) for v in np.asarray(response.freq)[~strong])
    if not strong.any():
        raise DataError(
            f"measured response: none of its {len(response.freq)} lines was measured reliably "
            f"(each line's SNR below {SNR_FLOOR:g}); a prediction needs H measured at lines"
        )
    response = MeasuredResponse(response.freq[strong], response.harmonics[strong],
                                response.h[strong], response.cvar[strong], response.dof[strong])
    kk = len(response.freq)
    order = np.argsort(response.freq)
    resp = MeasuredResponse(response.freq[order], response.harmonics[order], response.h[order],
                            np.maximum(response.cvar[order], 0.0), response.dof[order])
    fm = resp.freq
    power = amp**2 / 2.0
    curv = _curvature(resp)
    n_t = fq.size
    lo_idx = np.zeros(n_t, dtype=np.int64)
    weight = np.zeros(n_t)  # a: weight of the upper line (0 on a line)
    inside = np.zeros(n_t, dtype=bool)
    bound_h = np.zeros(n_t)  # bound on |Ĥ(f_j) − H(f_j)| from the interpolation
    # what |1 − H| could be where it was not measured (module notes): below the tested band
    # no more than at its lowest line, in a hole no more than at either side, above it 1
    d_up = np.abs(resp.h - 1.0) + Z95 * np.sqrt(resp.cvar)
    b_below = below_band_bound(resp)
    out_bound = np.zeros(n_t)
    basis = np.full(n_t, "", dtype=object)
    for j, f in enumerate(fq):
        tol = ON_LINE * f
        i = int(np.searchsorted(fm, f - tol))
        if i < kk and abs(fm[i] - f) <= tol:
            lo_idx[j], inside[j] = i, True
            continue
        if i == 0:
            out_bound[j], basis[j] = b_below, "below"
            continue
        if i >= kk:
            out_bound[j], basis[j] = 1.0, "above"
            continue
        i -= 1  # fm[i] < f < fm[i + 1]
        if not _neighbours(resp, i, float(f)):
            out_bound[j], basis[j] = float(max(d_up[i], d_up[i + 1])), "hole"
            continue
        a = (f - fm[i]) / (fm[i + 1] - fm[i])
        lo_idx[j], weight[j], inside[j] = i, a, True
        gap = float(resp.harmonics[i + 1] - resp.harmonics[i])
        kappa = np.nanmax(curv[i:i + 2]) if kk >= 3 else math.nan
        if math.isnan(kappa):  # two lines: the first difference, as for the periods
            bound_h[j] = a * (1 - a) / 2.0 * abs(complex(resp.h[i + 1] - resp.h[i]))
        else:
            bound_h[j] = a * (1 - a) / 2.0 * gap**2 * float(kappa)
    upper = np.minimum(lo_idx + 1, kk - 1)
    a = weight
    h_t = (1 - a) * resp.h[lo_idx] + a * resp.h[upper]
    d = h_t - 1.0
    v = (1 - a) ** 2 * resp.cvar[lo_idx] + np.where(a > 0, a**2 * resp.cvar[upper], 0.0)
    p_in = np.where(inside, power, 0.0)
    contribution = p_in * (np.abs(d) ** 2 - v)
    linear = float(contribution.sum())
    # delta method: first order (g), second order (M) and the noise estimates' own error
    g = np.zeros(kk, dtype=complex)
    m_diag = np.zeros(kk)
    m_off = np.zeros(kk)  # M[i, i+1]
    np.add.at(g, lo_idx, p_in * (1 - a) * d)
    np.add.at(g, upper, np.where(a > 0, p_in * a * d, 0.0))
    np.add.at(m_diag, lo_idx, p_in * (1 - a) ** 2)
    np.add.at(m_diag, upper, np.where(a > 0, p_in * a**2, 0.0))
    np.add.at(m_off, lo_idx, np.where(a > 0, p_in * a * (1 - a), 0.0))
    c = resp.cvar
    dof_inv = np.where(np.isfinite(resp.dof) & (resp.dof > 0), 2.0 / np.maximum(resp.dof, 1e-300),
                       0.0)
    # |ĝ_k|² holds the noise of the D̂ it is made of, E|ĝ_k|² = |g_k|² + Σ_l M_kl² c_l: taken
    # out (clipped at 0), or a line measured near the SNR floor under a heavy target motion
    # made the first-order term up to 3× too large (σ's interval twice as wide as its spread)
    g_noise = m_diag**2 * c
    g_noise[:-1] += m_off[:-1] ** 2 * c[1:]
    g_noise[1:] += m_off[:-1] ** 2 * c[:-1]
    lin_var = (
        max(2.0 * float(np.sum(c * (np.abs(g) ** 2 - g_noise))), 0.0)
        + float(np.sum(m_diag**2 * c**2))
        + 2.0 * float(np.sum(m_off[:-1] ** 2 * c[:-1] * c[1:]))
        + float(np.sum(m_diag**2 * c**2 * dof_inv))
    )
    interp = float(np.sum(p_in * (2.0 * np.abs(d) * bound_h + bound_h**2)))
    lin_sd = math.sqrt(max(lin_var, 0.0))
    lin_ci = (max(linear - Z95 * lin_sd - interp, 0.0), linear + Z95 * lin_sd + interp)
    variance = linear + noise.variance
    lo, hi = mls_interval(variance, [(noise.variance, noise.dof)], lin_var)
    var_ci = (max(lo - interp, 0.0), hi + interp)
    total = float(power.sum())
    outside = float(power[~inside].sum())
    share = outside / total if total > 0 else 0.0
    gaps = [
        (float(fm[i]), float(fm[i + 1]))
        for i in range(kk - 1)
        if not _neighbours(resp, i, 0.5 * float(fm[i] + fm[i + 1]))
    ]
    # what the lines where H was not measured could add: Σ P_j b_j² (b_j the bound above)
    extra = float(np.sum(np.where(inside, 0.0, power * out_bound**2)))
    sigma = math.sqrt(max(variance, 0.0))
    sigma_bound = math.sqrt(max(var_ci[1], 0.0) + extra)
    bounded = math.sqrt(max(variance, 0.0) + extra) > (1.0 + BOUND_SMALL) * sigma
    if not bounded:  # the interval holds what they could add
        var_ci = (var_ci[0], var_ci[1] + extra)
    bands = outside_bands(fq, ~inside, power)
    bases = sorted({str(b) for b in basis[~inside & (power > 0.0)]})
    assumed = "; ".join({
        "below": "below the tested band |1 − H| no larger than at any line of its lowest "
                 "octave (a lag, latency or gain error, not an error that grows toward low "
                 "frequencies)",
        "hole": "in a hole between measured lines |1 − H| no larger than at either side",
        "above": "above the tested band |1 − H| ≤ 1",
    }[b] for b in bases)
    where = ", ".join(f"{a:.4g} … {b:.4g} Hz ({m} line{'s' if m > 1 else ''})"
                      for a, b, m in bands)
    why = (f"not excited in the recording, or measured with SNR below {SNR_FLOOR:g}"
           if weak_hz else "not excited in the recording")
    warnings: list[str] = []
    if bounded:
        warnings.append(
            f"σ not predicted, only bounded: {100 * share:.3g} % of the target's variance "
            f"({outside:.4g} deg²) lies at {where}, where H was {why}; from the lines measured "
            f"σ = {sigma:.4g}°, and taking {assumed}: σ ≤ {sigma_bound:.4g}° (95 %). "
            "Record a profile that excites that band to predict σ"
        )
    elif share > OUTSIDE_WARN:
        warnings.append(
            f"{100 * share:.3g} % of the target's variance ({outside:.4g} deg²) lies on lines "
            f"where H was not measured (tested {fm[0]:.4g} … {fm[-1]:.4g} Hz): left out of σ "
            f"and bounded in its interval ({assumed})"
        )
    if linear < 0.0:
        warnings.append(
            f"the linear part is not resolved: its estimate is {linear:.3g} deg² (95 % CI up "
            f"to {lin_ci[1]:.3g} deg²), below zero by less than its uncertainty — the "
            "instrument's response error is too small for this recording to measure; σ is "
            "then mostly the noise carried over"
        )
    return Prediction(
        sigma=sigma,
        sigma_ci95=(math.sqrt(var_ci[0]), math.sqrt(max(var_ci[1], 0.0))),
        variance=variance,
        variance_ci95=var_ci,
        linear=linear,
        linear_sd=lin_sd,
        linear_ci95=lin_ci,
        noise=noise.variance,
        noise_ci95=noise.ci95,
        noise_dof=noise.dof,
        interpolation_bound=interp,
        tested_band_hz=(float(fm[0]), float(fm[-1])),
        untested_gaps_hz=gaps,
        target_variance=total,
        outside_variance=outside,
        outside_share=share,
        sigma_outside_bound=math.sqrt(max(variance, 0.0) + outside),
        freq=fq,
        amplitude=amp,
        inside=inside,
        error_gain=np.where(inside, np.abs(d), np.nan),
        contribution=contribution,
        warnings=warnings,
        sigma_bound=sigma_bound,
        bounded=bounded,
        weak_lines_hz=weak_hz,
        outside_bands_hz=bands,
    )


def f2_upper(p: float, dof: float) -> float:
    """The upper ``p`` point of an F(2, ν): ``(ν/2)(p^(−2/ν) − 1)`` (``−ln p`` for ν = ∞)."""
    if not math.isfinite(dof):
        return -math.log(p)
    return 0.5 * dof * (p ** (-2.0 / dof) - 1.0)


def below_band_bound(resp: MeasuredResponse) -> float:
    """A 97.5 % upper bound on ``|1 − H(f)|`` below the lowest measured line, with |1 − H| not
    decreasing from 0 Hz up to the band's lowest octave: the smallest of
    ``|1 − Ĥ_k| + √(c_k F_k)`` over the M lines ``f_k ≤ BELOW_OCTAVE·f_0``, F_k the upper
    ``BELOW_ALPHA/M`` point of F(2, ν_k) (``|Ĥ_k − H_k|²/c_k`` is an F(2, ν_k) when the noise
    at the line is estimated with ν_k degrees of freedom; the M bounds hold together with
    1 − BELOW_ALPHA, Bonferroni). ``resp`` sorted by frequency, reliable lines only."""
    near = np.flatnonzero(resp.freq <= BELOW_OCTAVE * resp.freq[0])
    m = near.size
    ends = [
        abs(complex(resp.h[k]) - 1.0)
        + math.sqrt(max(float(resp.cvar[k]), 0.0)
                    * f2_upper(BELOW_ALPHA / m, float(resp.dof[k])
                               if resp.dof[k] > 0 else math.inf))
        for k in near
    ]
    return float(min(ends))


def outside_bands(freq: FloatArray, outside: NDArray[np.bool_],
                  power: FloatArray) -> list[tuple[float, float, int]]:
    """The target's lines outside the measured band as runs of neighbouring lines
    ``(lo Hz, hi Hz, count)``, in frequency order; lines of no power are left out."""
    order = np.argsort(freq)
    out: list[tuple[float, float, int]] = []
    run: list[float] = []
    for i in order:
        if outside[i] and power[i] > 0.0:
            run.append(float(freq[i]))
        elif run:
            out.append((run[0], run[-1], len(run)))
            run = []
    if run:
        out.append((run[0], run[-1], len(run)))
    return out
