"""The delay between two streams from the excited lines (``benchctl.analysis.bench_timing``):
closed-form cases — a pure delay on any instants, a lag's phase, noise's scatter in the stated
uncertainty."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchctl.analysis.bench_timing import line_amplitudes, measure_delay

F = np.arange(12, 41) / 120.0  # the paper's band, lines of a 120 s period


def _motion(t: np.ndarray, delay: float = 0.0, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    amp = rng.uniform(0.2, 1.0, F.size)
    ph = rng.uniform(0, 2 * np.pi, F.size)
    return np.sum(amp[:, None] * np.cos(2 * np.pi * F[:, None] * (t - delay) + ph[:, None]),
                  axis=0)


def test_line_amplitudes_exact_on_uneven_instants() -> None:
    rng = np.random.default_rng(1)
    t = np.sort(rng.uniform(0, 240, 20_000))
    x = 0.3 + 1.5 * np.cos(2 * np.pi * F[3] * t + 0.7) + 0.2 * np.sin(2 * np.pi * F[9] * t)
    a = line_amplitudes(t, x, F)
    assert abs(a[3]) == pytest.approx(1.5, abs=1e-9)
    assert np.angle(a[3]) == pytest.approx(0.7, abs=1e-9)
    assert abs(a[9]) == pytest.approx(0.2, abs=1e-9)
    others = np.delete(np.abs(a), [3, 9])
    assert others.max() < 1e-9


@pytest.mark.parametrize("delay", [0.0, 0.00075, 0.0015625, -0.002, 0.05])
def test_a_pure_delay_on_other_instants(delay: float) -> None:
    """The reference at 100 Hz, the device at 100 Hz on instants 3.7 ms off the reference's
    and not a whole number of periods long: the delay exactly (1e-9 s)."""
    tr = np.arange(0, 250, 0.01)
    td = np.arange(0.0037, 247.3, 0.01)
    fit = measure_delay(tr, _motion(tr), td, _motion(td, delay), F)
    assert fit.delay_s == pytest.approx(delay, abs=1e-9)
    assert fit.gain == pytest.approx(1.0, abs=1e-9)
    assert fit.n_lines == F.size
    assert fit.uncertainty_s < 1e-9


def test_a_first_order_lag_reads_its_phase_delay() -> None:
    """A lag τ has phase −atan(2πfτ): its delay fit is the weighted mean of atan(2πfτ)/2πf."""
    tau = 0.08
    t = np.arange(0, 240, 0.01)
    rng = np.random.default_rng(3)
    amp = rng.uniform(0.2, 1.0, F.size)
    ph = rng.uniform(0, 2 * np.pi, F.size)
    x = np.sum(amp[:, None] * np.cos(2 * np.pi * F[:, None] * t + ph[:, None]), axis=0)
    phi = np.arctan(2 * np.pi * F * tau)
    g = 1 / np.sqrt(1 + (2 * np.pi * F * tau) ** 2)
    y = np.sum((g * amp)[:, None] * np.cos(2 * np.pi * F[:, None] * t + (ph - phi)[:, None]),
               axis=0)
    w = amp**2
    expect = np.sum(w * F * phi / (2 * np.pi)) / np.sum(w * F * F)
    fit = measure_delay(t, x, t, y, F)
    assert fit.delay_s == pytest.approx(expect, rel=1e-9)


def test_noise_is_in_the_stated_uncertainty() -> None:
    """White noise on the device: over 120 records the delay's spread matches its stated
    standard uncertainty within 30 %, and the mean is the true delay."""
    t = np.arange(0, 120, 0.01)
    x = _motion(t)
    clean = _motion(t, 0.0015)
    rng = np.random.default_rng(11)
    fits = [measure_delay(t, x, t, clean + rng.normal(0, 0.05, t.size), F) for _ in range(120)]
    d = np.array([f.delay_s for f in fits])
    u = np.array([f.uncertainty_s for f in fits])
    assert abs(d.mean() - 0.0015) < 3 * d.std() / math.sqrt(d.size)
    assert d.std() == pytest.approx(np.sqrt(np.mean(u**2)), rel=0.3)


def test_bad_lines_refused() -> None:
    t = np.arange(0, 10, 0.01)
    with pytest.raises(ValueError, match="freq_hz"):
        measure_delay(t, t, t, t, [])
    with pytest.raises(ValueError, match="cannot fit"):
        line_amplitudes(t[:5], t[:5], F)
