"""One-sided spectral densities from correlation functions (eq. 1), and a Welch cross-check.

Conventions: one-sided densities ``G(f)`` in deg²/Hz on ``0 ≤ f ≤ fs/2`` (scipy's
``scaling="density"``, ``return_onesided=True``), so that ``∫₀^{fs/2} G df`` is the variance.
Cross densities follow ``G_xy = 2·conj(X)·Y / (fs·N)`` in the limit, as ``scipy.signal.csd``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.fft import next_fast_len, rfft

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


def parzen_lag_window(max_lag: int) -> FloatArray:
    """Parzen lag window ``w(τ)``, τ = 0 … L, with ``w(0) = 1`` and ``w(L) = 0``.

    ``w = 1 − 6u² + 6u³`` for ``u = τ/L ≤ 1/2`` and ``2(1 − u)³`` beyond. Its spectral window
    is non-negative, so an auto-spectrum estimate from a positive semi-definite correlation
    sequence is never negative.
    """
    u = np.arange(max_lag + 1) / max_lag
    return np.where(u <= 0.5, 1.0 - 6.0 * u**2 + 6.0 * u**3, 2.0 * (1.0 - u) ** 3)


@dataclass(frozen=True)
class SpectralGrid:
    """The frequency grid of the Blackman–Tukey estimate and its statistics.

    ``freq`` in Hz (``0 … fs/2``, spacing ``fs/M``); ``window`` the lag window for τ = 0 … L;
    ``resolution_hz`` the equivalent bandwidth ``1/(Δt Σ_{−L}^{L} w²)``; ``nfft`` = M.
    """

    freq: FloatArray
    window: FloatArray
    dt: float
    nfft: int

    @property
    def resolution_hz(self) -> float:
        return 1.0 / (self.dt * window_power(self.window))

    def dof(self, n_samples: int) -> float:
        """Equivalent degrees of freedom of one auto-spectrum value: ``2N / Σ_{−L}^{L} w²``."""
        return 2.0 * n_samples / window_power(self.window)


def window_power(window: FloatArray) -> float:
    """``Σ_{τ=−L}^{L} w(τ)²`` for a symmetric lag window given for τ = 0 … L."""
    return float(window[0] ** 2 + 2.0 * np.sum(window[1:] ** 2))


def spectral_grid(max_lag: int, dt: float) -> SpectralGrid:
    """The grid for lags 0 … ``max_lag`` at sample interval ``dt`` s (M even, M ≥ 2L + 2)."""
    nfft = 2 * next_fast_len(max_lag + 1, real=True)
    freq = np.arange(nfft // 2 + 1) / (nfft * dt)
    return SpectralGrid(freq=freq, window=parzen_lag_window(max_lag), dt=dt, nfft=nfft)


def _two_sided_sequence(pos: FloatArray, neg: FloatArray, grid: SpectralGrid) -> FloatArray:
    """Windowed lags laid out for an FFT: ``c[τ] = w R(τ)``, ``c[M − τ] = w R(−τ)``."""
    lag = len(pos) - 1
    c = np.zeros(grid.nfft)
    c[: lag + 1] = grid.window * pos
    c[grid.nfft - lag :] = (grid.window[1:] * neg[1:])[::-1]
    return c


def auto_spectrum(r: FloatArray, grid: SpectralGrid) -> FloatArray:
    """One-sided density from an auto-correlation (eq. 1), deg²/Hz.

    Parameters
    ----------
    r : ndarray, shape (L + 1,)
        Correlation ``R(τ)`` for τ = 0 … L, deg² (even in τ).
    grid : SpectralGrid
        From :func:`spectral_grid` for the same L and sample interval.

    Returns
    -------
    ndarray
        ``G(f) = 2Δt [R(0) + 2 Σ_{τ=1}^{L} w(τ) R(τ) cos(2π f τ Δt)]`` on ``grid.freq``.

    Notes
    -----
    This is eq. 1, ``S(ω) = 2∫₀^∞ R(τ) e^{−jωτ} dτ``, discretised, with a lag window of
    ``w(0) = 1``. Integrated by the trapezoid rule over ``grid.freq`` the result equals
    ``R(0)`` to rounding (discrete Parseval, ``M`` even and ``M > 2L``).

    Examples
    --------
    >>> import numpy as np
    >>> g = spectral_grid(8, 0.1)
    >>> r = np.zeros(9); r[0] = 2.0          # white noise of variance 2 deg², fs = 10 Hz
    >>> bool(np.allclose(auto_spectrum(r, g), 2.0 * 2.0 * 0.1))
    True
    """
    c = _two_sided_sequence(r, r, grid)
    return np.asarray(2.0 * grid.dt * rfft(c).real, dtype=float)


def cross_spectrum(rxy: FloatArray, ryx: FloatArray, grid: SpectralGrid) -> ComplexArray:
    """One-sided cross density ``G_xy(f) = 2Δt Σ_{|τ|≤L} w(τ) R_xy(τ) e^{−j2πfτΔt}``, deg²/Hz.

    ``rxy[τ] = R_xy(τ)`` and ``ryx[τ] = R_xy(−τ)`` for τ = 0 … L; ``G_xy/G_xx`` is then the
    frequency response from x to y (H1), negative phase meaning y lags x.
    """
    c = _two_sided_sequence(rxy, ryx, grid)
    return np.asarray(2.0 * grid.dt * rfft(c), dtype=complex)


def trapezoid_area(freq: FloatArray, density: FloatArray) -> float:
    """``∫ density df`` by the trapezoid rule, deg²."""
    return float(np.trapezoid(density, freq))


def band_area(freq: FloatArray, density: FloatArray, lo: float, hi: float) -> float:
    """``∫_lo^hi density df`` by the trapezoid rule, the band edges linearly interpolated."""
    inside = (freq > lo) & (freq < hi)
    f = np.concatenate(([lo], freq[inside], [hi]))
    ends = np.interp([lo, hi], freq, density)
    g = np.concatenate(([ends[0]], density[inside], [ends[1]]))
    return float(np.trapezoid(g, f))


def welch_density(eps: FloatArray, dt: float, nperseg: int) -> tuple[FloatArray, FloatArray]:
    """Welch's one-sided density (deg²/Hz) of one gap-free series, no detrending.

    Hann window (periodic, as ``scipy.signal.get_window("hann", n)``), 50 % overlap,
    trailing samples that do not fill a segment dropped: the same numbers as
    ``scipy.signal.welch(eps, fs=1/dt, nperseg=nperseg, detrend=False)``, without importing
    scipy.signal (a third of a second at start-up).
    """
    step = nperseg - nperseg // 2
    n_seg = 1 + (len(eps) - nperseg) // step
    win = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(nperseg) / nperseg)
    scale = dt / float(np.sum(win**2))
    acc = np.zeros(nperseg // 2 + 1)
    for i in range(n_seg):
        spec = rfft(eps[i * step : i * step + nperseg] * win)
        acc += spec.real**2 + spec.imag**2
    psd = acc * (scale / n_seg)
    psd[1:] *= 2.0
    if nperseg % 2 == 0:
        psd[-1] /= 2.0
    freq = np.arange(nperseg // 2 + 1) / (nperseg * dt)
    return freq, psd


@dataclass(frozen=True)
class WelchEstimate:
    """Welch estimate of the error density from the contiguous runs of the record."""

    freq: FloatArray
    density: FloatArray
    nperseg: int
    n_windows: int
    n_used: int

    @property
    def area(self) -> float:
        return trapezoid_area(self.freq, self.density)


def welch_by_runs(
    eps: FloatArray, mask: NDArray[np.bool_], dt: float, nperseg: int
) -> WelchEstimate | None:
    """Welch density of ``eps`` (deg²/Hz), averaged over the gap-free runs of the grid.

    ``eps`` must already have its mean (over the valid samples) removed; segments are not
    detrended again, so power below the segment's resolution stays in the area. Hann window,
    50 % overlap; each run contributes in proportion to its number of segments. The segment
    length is ``nperseg``, halved until runs of at least that length hold half the valid
    samples (not below 64). Returns None when no run holds 64 samples.
    """
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.view(np.int8), [0]))))
    runs = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    lengths = np.array([b - a for a, b in runs])
    if len(lengths) == 0 or lengths.max() < 64:
        return None
    total = int(lengths.sum())
    nperseg = max(64, nperseg)
    while nperseg > 64 and lengths[lengths >= nperseg].sum() < total / 2:
        nperseg //= 2
    nperseg = min(max(nperseg, 64), int(lengths.max()))
    acc: FloatArray | None = None
    freq: FloatArray | None = None
    count = 0
    used = 0
    step = nperseg - nperseg // 2
    for a, b in runs:
        n = b - a
        if n < nperseg:
            continue
        k = 1 + (n - nperseg) // step
        freq, p = welch_density(eps[a:b], dt, nperseg)
        acc = p * k if acc is None else acc + p * k
        count += k
        used += nperseg + (k - 1) * step
    assert acc is not None and freq is not None
    return WelchEstimate(
        freq=freq, density=acc / count, nperseg=nperseg, n_windows=count, n_used=used
    )
