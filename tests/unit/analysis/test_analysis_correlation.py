"""Eq. 2 and eq. 1 against direct computation: the four-term R_ε equals the autocovariance of
ε computed directly, each term equals its biased definition, and the PSD's area is R(0)."""

from __future__ import annotations

import numpy as np
import pytest

from benchctl.analysis.correlation import correlations
from benchctl.analysis.psd import (
    auto_spectrum,
    band_area,
    cross_spectrum,
    parzen_lag_window,
    spectral_grid,
    trapezoid_area,
)
from benchctl.errors import DataError


def _pair(n: int = 1500, seed: int = 0):
    rng = np.random.default_rng(seed)
    x = np.cumsum(rng.normal(size=n)) * 0.1 + 3.0  # non-zero mean, red
    y = 0.9 * np.roll(x, 2) + rng.normal(0, 0.2, n) - 1.0
    return x, y


def direct(a: np.ndarray, b: np.ndarray, lag: int, mask: np.ndarray | None = None) -> np.ndarray:
    """Σ_i a_i b_{i+τ} over existing pairs, /pairs·(N−τ)/N; the biased estimator without gaps."""
    n = len(a)
    m = np.ones(n, dtype=bool) if mask is None else mask
    a = np.where(m, a - a[m].mean(), 0.0)
    b = np.where(m, b - b[m].mean(), 0.0)
    out = np.empty(lag + 1)
    for t in range(lag + 1):
        pairs = np.sum(m[: n - t] & m[t:])
        out[t] = np.dot(a[: n - t], b[t:]) / pairs * (n - t) / n
    return out


def test_each_term_is_the_biased_estimator() -> None:
    x, y = _pair()
    c = correlations(x, y, None, 150)
    n = len(x)
    xd, yd = x - x.mean(), y - y.mean()
    for t in (0, 1, 7, 150):
        assert c.rx[t] == pytest.approx(np.dot(xd[: n - t], xd[t:]) / n, rel=1e-10)
        assert c.rxy[t] == pytest.approx(np.dot(xd[: n - t], yd[t:]) / n, rel=1e-10)
        assert c.ryx[t] == pytest.approx(np.dot(yd[: n - t], xd[t:]) / n, rel=1e-10)
    assert np.allclose(c.ry, direct(y, y, 150), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("gappy", [False, True])
def test_eq2_equals_direct_autocovariance_of_error(gappy: bool) -> None:
    x, y = _pair()
    mask = None
    if gappy:
        mask = np.random.default_rng(3).random(len(x)) > 0.05
        mask[500:540] = False
    c = correlations(x, y, mask, 200)
    r_eps = direct(y - x, y - x, 200, mask)
    assert np.allclose(c.error(), r_eps, rtol=1e-9, atol=1e-12 * r_eps[0])
    assert np.allclose(c.rxy, direct(x, y, 200, mask), rtol=1e-9, atol=1e-12)


def test_lag_out_of_range() -> None:
    x, y = _pair(100)
    with pytest.raises(DataError, match="max_lag"):
        correlations(x, y, None, 100)


def test_parzen_window() -> None:
    w = parzen_lag_window(100)
    assert w[0] == 1.0 and w[100] == 0.0 and w[50] == pytest.approx(0.25)
    assert np.all(np.diff(w) <= 0)


def test_white_noise_density_and_parseval() -> None:
    g = spectral_grid(64, 0.01)  # fs = 100 Hz
    r = np.zeros(65)
    r[0] = 4.0
    assert np.allclose(auto_spectrum(r, g), 2 * 4.0 * 0.01)  # one-sided 2σ²Δt
    assert trapezoid_area(g.freq, auto_spectrum(r, g)) == pytest.approx(4.0, rel=1e-12)
    assert g.freq[-1] == pytest.approx(50.0)


def test_area_is_r0_for_any_correlation() -> None:
    x, y = _pair()
    c = correlations(x, y, None, 300)
    g = spectral_grid(300, 0.05)
    for r in (c.rx, c.ry, c.error()):
        assert trapezoid_area(g.freq, auto_spectrum(r, g)) == pytest.approx(r[0], rel=1e-12)


def test_sine_density_peaks_at_its_frequency() -> None:
    dt, n = 0.1, 4000
    t = np.arange(n) * dt
    x = 2.0 * np.sin(2 * np.pi * 0.5 * t)  # 200 whole periods, variance 2
    c = correlations(x, x, None, 400)
    g = spectral_grid(400, dt)
    s = auto_spectrum(c.rx, g)
    assert g.freq[np.argmax(s)] == pytest.approx(0.5, abs=g.freq[1])
    assert trapezoid_area(g.freq, s) == pytest.approx(2.0, rel=1e-9)
    # nearly all of it within ±0.1 Hz (Parzen resolution 1.86/(LΔt) = 0.047 Hz)
    assert band_area(g.freq, s, 0.4, 0.6) == pytest.approx(2.0, rel=0.01)


def test_cross_spectrum_of_a_delay() -> None:
    rng = np.random.default_rng(2)
    dt, k = 0.01, 5  # y is x delayed by 50 ms
    x = rng.normal(size=20000)
    y = np.concatenate((np.zeros(k), x[:-k]))
    c = correlations(x, y, None, 500)
    g = spectral_grid(500, dt)
    h = cross_spectrum(c.rxy, c.ryx, g) / auto_spectrum(c.rx, g)
    f = g.freq
    sel = (f > 1) & (f < 5)
    assert np.allclose(np.abs(h[sel]), 1.0, atol=0.05)
    expected = np.degrees(-2 * np.pi * f[sel] * k * dt)
    assert np.max(np.abs(np.degrees(np.angle(h[sel])) - expected)) < 3.0


@pytest.mark.parametrize("nperseg", [256, 255])
def test_welch_density_is_scipys(nperseg: int) -> None:
    from scipy.signal import welch

    from benchctl.analysis.psd import welch_density

    e = np.random.default_rng(5).normal(size=5000)
    f, p = welch_density(e, 0.02, nperseg)
    fs, ps = welch(e, fs=50.0, nperseg=nperseg, detrend=False)
    assert np.allclose(f, fs) and np.allclose(p, ps, rtol=1e-12)
