"""Frequency response (H1), coherence, delay and the split of the error variance.

Conventions: ``H(f) = G_xy(f)/G_xx(f)`` from the reference x (stand) to the device y; gain is
``|H|``; ``phase_deg = angle(H)`` in degrees, negative when the device lags. Coherence
``γ² = |G_xy|²/(G_xx G_yy)``. All densities one-sided, deg²/Hz, from the same lag-windowed
correlations as the error density, so the identity
``G_εε = |1 − H|² G_xx + (1 − γ²) G_yy`` holds at every frequency.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.fft import irfft, next_fast_len, rfft

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

TRADITIONAL_PERIODS_S = (3.0, 5.0, 7.0, 10.0)
EXCITED_FRACTION = 1e-3  # a frequency is excited where G_xx ≥ this × max G_xx …
SKIRT_FRACTION = 0.05  # … and ≥ this × max G_xx within ± one resolution (not a line's skirt)
Z95 = 1.959963984540054


@dataclass(frozen=True)
class FrequencyResponse:
    """H1 on the frequencies where the reference is excited (and inside the band, if given)."""

    freq: FloatArray
    h: ComplexArray
    coherence: FloatArray
    gxx: FloatArray

    @property
    def gain(self) -> FloatArray:
        return np.abs(self.h)

    @property
    def phase_deg(self) -> FloatArray:
        return np.degrees(np.unwrap(np.angle(self.h)))


def excited(
    freq: FloatArray, gxx: FloatArray, fraction: float = EXCITED_FRACTION
) -> NDArray[np.bool_]:
    """Frequencies (f > 0) where the reference density is at least ``fraction`` of its peak."""
    pos = freq > 0
    peak = float(np.max(gxx[pos]))
    return pos & (gxx >= fraction * peak)


def frequency_response(
    freq: FloatArray,
    gxx: FloatArray,
    gyy: FloatArray,
    gxy: ComplexArray,
    band_hz: tuple[float, float] | None = None,
) -> FrequencyResponse:
    """H1 gain/phase and coherence on the excited frequencies (within ``band_hz`` if given).

    Parameters
    ----------
    freq : ndarray
        Frequencies, Hz.
    gxx, gyy : ndarray
        One-sided auto densities of reference and device, deg²/Hz.
    gxy : ndarray of complex
        One-sided cross density, deg²/Hz (``conj(X)·Y`` convention).
    band_hz : (lo, hi), optional
        Keep only ``lo ≤ f ≤ hi``.
    """
    keep = excited(freq, gxx)
    if band_hz is not None:
        keep &= (freq >= band_hz[0]) & (freq <= band_hz[1])
    h = gxy[keep] / gxx[keep]
    coh = np.abs(gxy[keep]) ** 2 / (gxx[keep] * gyy[keep])
    return FrequencyResponse(
        freq=freq[keep], h=h, coherence=np.clip(coh, 0.0, 1.0), gxx=gxx[keep]
    )


def h1_intervals(
    frf: FrequencyResponse, dof_per_freq: float
) -> tuple[FloatArray, FloatArray]:
    """95 % intervals of H1's gain and phase (deg) from the coherence, (n, 2) each.

    Bendat & Piersol (*Random Data*, 4th ed., §9.2.4): the normalised random error of
    ``|Ĥ|`` and the standard deviation of the phase (rad) are both
    ``√(1 − γ²) / (|γ| √ν_f)`` with ``ν_f = 2 n_d`` the degrees of freedom of one spectral
    value (here the lag window's); the interval is ± 1.96 of them. Bias (the lag window's
    smoothing of H) is not included.
    """
    coh = np.clip(frf.coherence, 1e-12, 1.0)
    err = np.sqrt((1.0 - coh) / coh / max(dof_per_freq, 1e-12))
    gain, phase = frf.gain, frf.phase_deg
    half_g = Z95 * err * gain
    half_p = np.degrees(np.minimum(Z95 * err, np.pi))
    return (
        np.column_stack((gain - half_g, gain + half_g)),
        np.column_stack((phase - half_p, phase + half_p)),
    )


def excited_at(
    f: float, freq: FloatArray, gxx: FloatArray, resolution_hz: float,
    fraction: float = EXCITED_FRACTION,
) -> bool:
    """Whether the reference is excited at ``f`` on the lag-window grid: its density there is
    at least ``fraction`` of its peak, and at least ``SKIRT_FRACTION`` of its largest value
    within ± one resolution bandwidth (so the spectral window's skirt of a neighbouring line
    does not count as excitation)."""
    pos = freq > 0
    if not pos.any():
        return False
    g = float(np.interp(f, freq, gxx))
    near = pos & (np.abs(freq - f) <= resolution_hz)
    local = float(np.max(gxx[near])) if near.any() else g
    return g >= fraction * float(np.max(gxx[pos])) and g >= SKIRT_FRACTION * local


def not_excited(period: float) -> dict[str, Any]:
    """A traditional period with no excitation near it: no gain, no phase."""
    return {
        "period_s": period,
        "freq": 1.0 / period,
        "excited": False,
        "gain": None,
        "gain_ci95": None,
        "phase_deg": None,
        "phase_ci95_deg": None,
        "coherence": None,
        "source": None,
    }


def at_periods(
    frf: FrequencyResponse,
    dof_per_freq: float,
    freq_all: FloatArray,
    gxx_all: FloatArray,
    resolution_hz: float,
    periods_s: tuple[float, ...] = TRADITIONAL_PERIODS_S,
) -> list[dict[str, Any]]:
    """Gain, phase (deg), coherence and their 95 % intervals from H1 at the given periods.

    Every period is listed. It is excited when it lies between two adjacent grid
    frequencies of the excited set and :func:`excited_at` holds there; ``H`` (complex), the
    coherence and the intervals' half-widths are interpolated linearly between the two.
    Otherwise ``excited`` is false and gain/phase are None.
    """
    out: list[dict[str, Any]] = []
    step = float(np.min(np.diff(frf.freq))) if len(frf.freq) >= 2 else 0.0
    gain_ci, phase_ci = h1_intervals(frf, dof_per_freq)
    for period in periods_s:
        f = 1.0 / period
        j = int(np.searchsorted(frf.freq, f))
        if (
            len(frf.freq) < 2
            or j == 0
            or j >= len(frf.freq)
            or frf.freq[j] - frf.freq[j - 1] > 1.5 * step
            or not excited_at(f, freq_all, gxx_all, resolution_hz)
        ):
            out.append(not_excited(period))
            continue
        f0, f1 = frf.freq[j - 1], frf.freq[j]
        a = (f - f0) / (f1 - f0)
        h = (1 - a) * frf.h[j - 1] + a * frf.h[j]
        coh = (1 - a) * frf.coherence[j - 1] + a * frf.coherence[j]
        hg = (1 - a) * np.diff(gain_ci[j - 1]) / 2 + a * np.diff(gain_ci[j]) / 2
        hp = (1 - a) * np.diff(phase_ci[j - 1]) / 2 + a * np.diff(phase_ci[j]) / 2
        g, ph = float(abs(h)), float(np.degrees(np.angle(h)))
        out.append(
            {
                "period_s": period,
                "freq": f,
                "excited": True,
                "gain": g,
                "gain_ci95": [g - float(hg[0]), g + float(hg[0])],
                "phase_deg": ph,
                "phase_ci95_deg": [ph - float(hp[0]), ph + float(hp[0])],
                "coherence": float(coh),
                "source": "h1",
            }
        )
    return out


def _pair_energies(
    x: FloatArray, y: FloatArray, mask: NDArray[np.bool_], lag: int
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """For τ = 0 … lag: Σ x_i² and Σ y_{i+τ}² over the pairs (i, i+τ) that exist, and the
    same for the pairs (i+τ, i): (ex_pos, ey_pos, ex_neg, ey_neg). By FFT when there are gaps,
    by cumulative sums when there are none."""
    n = len(x)
    t = np.arange(lag + 1)
    if bool(mask.all()):
        cx = np.concatenate(([0.0], np.cumsum(x * x)))  # cx[k] = Σ_{i<k} x_i²
        cy = np.concatenate(([0.0], np.cumsum(y * y)))
        return cx[n - t], cy[n] - cy[t], cx[n] - cx[t], cy[n - t]
    nfft = next_fast_len(n + lag, real=True)
    fm = rfft(mask.astype(float), nfft)
    p = irfft(np.conj(rfft(x * x, nfft)) * fm, nfft)  # Σ x_i² m_{i+τ}
    q = irfft(np.conj(fm) * rfft(y * y, nfft), nfft)  # Σ m_i y_{i+τ}²
    neg = np.concatenate(([0], nfft - t[1:]))
    return p[t], q[t], q[neg], p[neg]


def delay_from_correlation(
    rxy: FloatArray,
    ryx: FloatArray,
    x: FloatArray,
    y: FloatArray,
    mask: NDArray[np.bool_],
    dt: float,
    f_peak: float,
) -> float:
    """Delay of the device behind the reference, s (positive: the device lags).

    The lag of the maximum of the normalised cross-correlation
    ``ρ(τ) = Σ x_i y_{i+τ} / √(Σ x_i² · Σ y_{i+τ}²)``, each sum over the pairs the lag
    leaves and that exist (so neither gaps nor the ends of a record whose amplitude
    changes, a fade, pull the peak),
    refined below a sample by a parabola through the maximum and its neighbours. The search
    is limited to ``|τ| < 1/(2 f_peak)``, half the period where the reference has most power,
    so that a periodic motion cannot make a whole period look like a delay. For a pure delay
    this is the delay; otherwise the shift that makes the two records most alike.

    Parameters
    ----------
    rxy, ryx : ndarray
        ``Σ x_i y_{i+τ}`` and ``Σ y_i x_{i+τ}`` for τ = 0 … L (raw sums, deg²).
    x, y : ndarray
        The gridded series, means removed, zero in the gaps (deg).
    mask : ndarray of bool
        True where a slot holds a sample.
    dt : float
        Grid step, s.
    f_peak : float
        Frequency of the reference's PSD maximum, Hz.
    """
    lag = len(rxy) - 1
    w = lag if f_peak <= 0 else min(lag, max(1, int(0.5 / (f_peak * dt))))
    ex_pos, ey_pos, ex_neg, ey_neg = _pair_energies(x, y, mask, w)
    with np.errstate(invalid="ignore", divide="ignore"):
        pos = rxy[: w + 1] / np.sqrt(ex_pos * ey_pos)  # τ ≥ 0
        neg = ryx[: w + 1] / np.sqrt(ex_neg * ey_neg)  # τ ≤ 0, as −τ
    c = np.nan_to_num(np.concatenate((neg[1:][::-1], pos)), nan=-np.inf)
    tau = np.arange(-w, w + 1)
    i = int(np.argmax(c))
    frac = 0.0
    if 0 < i < len(c) - 1 and np.all(np.isfinite(c[i - 1 : i + 2])):
        a, b, d = c[i - 1], c[i], c[i + 1]
        den = a - 2.0 * b + d
        if den < 0:
            frac = 0.5 * (a - d) / den
    return float((tau[i] + frac) * dt)


@dataclass(frozen=True)
class Decomposition:
    """The error density split into its part coherent with the reference and the rest.

    ``linear`` = ``|1 − H|² G_xx`` = ``|G_xε|²/G_xx`` on the excited frequencies (0 elsewhere:
    without excitation no linear response can be seen, and the estimate's floors there are
    not to be read as coherence); ``incoherent`` = ``G_εε − linear``. The lag window's leakage
    of a linear error just outside the excited band counts as incoherent (conservative).
    Both deg²/Hz on the full grid.
    """

    linear: FloatArray
    incoherent: FloatArray


def decompose(
    freq: FloatArray, gxx: FloatArray, gxy: ComplexArray, gee: FloatArray, dof_per_freq: float
) -> Decomposition:
    """Split ``G_εε`` into the linear dynamic part and the incoherent part (see class).

    The residual ``G_εε − |G_xε|²/G_xx`` of a smoothed estimate with ν_f degrees of freedom
    per frequency is low by the factor ``1 − 2/ν_f`` (two degrees of freedom go to fitting H);
    the incoherent part is divided by it, within the limits ``0 ≤ linear ≤ G_εε``.
    """
    keep = excited(freq, gxx)
    lin = np.zeros_like(gee)
    gxe = gxy[keep] - gxx[keep]
    g = np.maximum(gee[keep], 0.0)
    resid = np.maximum(g - np.abs(gxe) ** 2 / gxx[keep], 0.0)
    factor = 1.0 - 2.0 / dof_per_freq if dof_per_freq > 4.0 else 0.5
    lin[keep] = np.clip(g - resid / factor, 0.0, g)
    return Decomposition(linear=lin, incoherent=gee - lin)
