"""Roll spectra: a one-degree-of-freedom ship roll response, the exponential-cosine correlation
model, and breakpoint tables.

Pure computation, no I/O. Frequencies in Hz, roll spectra one-sided in deg²/Hz, wave spectra
one-sided in m²/Hz (see :mod:`benchctl.profiles.spectra`).

The ship's roll is modelled as a linear oscillator driven by the effective wave slope:

    φ'' + 2ζω_n φ' + ω_n² φ = ω_n² κ α(t)

with ``ω_n = 2π/T_n`` (natural roll period ``T_n``), damping ratio ``ζ``, effective wave-slope
coefficient ``κ`` (≈ 1 for a small ship that follows the wave surface, less for a larger one),
and deep-water wave slope ``α`` whose spectrum is ``S_α(ω) = ω⁴/g² · S_ζ(ω)`` (``k = ω²/g``).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from benchctl.profiles.spectra import G_STANDARD

FloatArray = NDArray[np.float64]

RAD2DEG = 180.0 / math.pi


def roll_rao(
    f_hz: ArrayLike, natural_period_s: float, damping_ratio: float, slope_coefficient: float = 1.0
) -> FloatArray:
    """Amplitude response |H(f)| of roll to wave slope (rad/rad).

    ``|H| = κ / √((1 − r²)² + (2ζr)²)`` with ``r = f·T_n``. At ``r = 1`` it is ``κ/(2ζ)``;
    its maximum ``κ / (2ζ√(1 − ζ²))`` lies at ``r = √(1 − 2ζ²)`` (for ζ < 1/√2).
    """
    if not natural_period_s > 0:
        raise ValueError(f"natural_period_s must be > 0, got {natural_period_s!r}")
    if not 0 < damping_ratio < 1:
        raise ValueError(f"damping_ratio must be in (0, 1), got {damping_ratio!r}")
    r = np.atleast_1d(np.asarray(f_hz, dtype=float)) * natural_period_s
    return np.asarray(
        slope_coefficient / np.sqrt((1.0 - r**2) ** 2 + (2.0 * damping_ratio * r) ** 2)
    )


def wave_slope_spectrum(
    f_hz: ArrayLike, wave_psd_m2_hz: ArrayLike, g: float = G_STANDARD
) -> FloatArray:
    """Deep-water wave-slope spectrum ``S_α(f) = (2πf)⁴/g² · S_ζ(f)``, rad²/Hz."""
    f = np.atleast_1d(np.asarray(f_hz, dtype=float))
    return np.asarray((2.0 * math.pi * f) ** 4 / g**2 * np.asarray(wave_psd_m2_hz, dtype=float))


def roll_response_psd(
    f_hz: ArrayLike,
    wave_psd_m2_hz: ArrayLike,
    natural_period_s: float,
    damping_ratio: float,
    slope_coefficient: float = 1.0,
    g: float = G_STANDARD,
) -> FloatArray:
    """Roll spectrum of the 1-DOF model driven by a wave spectrum, deg²/Hz.

    ``G_φ(f) = (180/π)² · |H(f)|² · (2πf)⁴/g² · S_ζ(f)``.
    """
    rao = roll_rao(f_hz, natural_period_s, damping_ratio, slope_coefficient)
    return np.asarray(RAD2DEG**2 * rao**2 * wave_slope_spectrum(f_hz, wave_psd_m2_hz, g))


def exp_cos_correlation(
    tau_s: ArrayLike, sigma_deg: float, alpha_1_s: float, beta_rad_s: float
) -> FloatArray:
    """Exponential-cosine roll correlation ``R(τ) = σ² e^(−α|τ|) cos βτ``, deg²."""
    tau = np.asarray(tau_s, dtype=float)
    return np.asarray(sigma_deg**2 * np.exp(-alpha_1_s * np.abs(tau)) * np.cos(beta_rad_s * tau))


def exp_cos_psd(
    f_hz: ArrayLike, sigma_deg: float, alpha_1_s: float, beta_rad_s: float
) -> FloatArray:
    """One-sided spectral density of the exponential-cosine model, deg²/Hz.

    The two-sided transform of ``R(τ) = D e^(−α|τ|) cos βτ`` (``D = σ²``) is
    ``S(ω) = 2Dα(ω² + α² + β²) / ((ω² − α² − β²)² + 4α²ω²)``; the one-sided density in Hz is
    ``G(f) = 2·S(2πf)``, so that ``∫₀^∞ G df = D``.

    Parameters
    ----------
    f_hz : array_like
        Frequencies, Hz (≥ 0).
    sigma_deg : float
        Standard deviation σ of the roll, deg.
    alpha_1_s : float
        Decay rate α of the correlation, 1/s (> 0).
    beta_rad_s : float
        Angular frequency β of the correlation's oscillation, rad/s (≥ 0); ``2π/β`` is the
        apparent roll period.
    """
    if not alpha_1_s > 0:
        raise ValueError(f"alpha_1_s must be > 0, got {alpha_1_s!r}")
    w = 2.0 * math.pi * np.atleast_1d(np.asarray(f_hz, dtype=float))
    a2b2 = alpha_1_s**2 + beta_rad_s**2
    s = (
        2.0
        * sigma_deg**2
        * alpha_1_s
        * (w**2 + a2b2)
        / ((w**2 - a2b2) ** 2 + 4.0 * alpha_1_s**2 * w**2)
    )
    return np.asarray(2.0 * s)


def exp_cos_parameters(period_s: float, damping: float) -> tuple[float, float]:
    """(α, β) of the exponential-cosine model from the apparent period and ``damping = α/β``."""
    beta = 2.0 * math.pi / period_s
    return damping * beta, beta


def breakpoint_psd(f_hz: ArrayLike, freq_hz: ArrayLike, density_deg2_hz: ArrayLike) -> FloatArray:
    """A spectrum given as breakpoints, linear between them and zero outside, deg²/Hz."""
    f = np.atleast_1d(np.asarray(f_hz, dtype=float))
    xp = np.asarray(freq_hz, dtype=float)
    fp = np.asarray(density_deg2_hz, dtype=float)
    return np.asarray(np.interp(f, xp, fp, left=0.0, right=0.0))
