"""Exact synthetic records for the analysis tests and benchmarks: a multisine through a known
linear instrument.

The instrument's response is applied analytically, line by line: for
``x(t) = Σ A_k cos(2π f_k t + φ_k)`` the output is
``y(t) = Σ A_k |H(f_k)| cos(2π f_k t + φ_k + ∠H(f_k)) + n(t)``, so over whole periods
``σ² = Σ (A_k²/2) |1 − H(f_k)|² + σ_n²`` exactly (when the noise is uncorrelated with the
multisine error, which ``orthogonal_noise`` enforces exactly).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
Response = Callable[[FloatArray], NDArray[np.complex128]]


def gain(g: float) -> Response:
    return lambda f: np.full(np.shape(f), complex(g))


def first_order(tau_s: float) -> Response:
    return lambda f: 1.0 / (1.0 + 2j * np.pi * f * tau_s)


def second_order(fn_hz: float, zeta: float) -> Response:
    def h(f: FloatArray) -> NDArray[np.complex128]:
        r = f / fn_hz
        return 1.0 / (1.0 - r**2 + 2j * zeta * r)

    return h


def delay(d_s: float) -> Response:
    return lambda f: np.exp(-2j * np.pi * f * d_s)


@dataclass(frozen=True)
class Multisine:
    """Lines ``f_k = k/period_s`` for ``f_lo ≤ f_k ≤ f_hi``, equal amplitudes, random phases."""

    period_s: float
    f_lo: float
    f_hi: float
    rms_deg: float
    seed: int = 7

    @property
    def freqs(self) -> FloatArray:
        k = np.arange(int(np.ceil(self.f_lo * self.period_s)), int(self.f_hi * self.period_s) + 1)
        return k / self.period_s

    @property
    def amps(self) -> FloatArray:
        n = len(self.freqs)
        return np.full(n, self.rms_deg * np.sqrt(2.0 / n))

    @property
    def phases(self) -> FloatArray:
        return np.random.default_rng(self.seed).uniform(0, 2 * np.pi, len(self.freqs))

    def through(self, h: Response, t: FloatArray) -> FloatArray:
        """The response of H to the multisine at instants ``t`` (exact, line by line)."""
        hk = h(self.freqs)
        out = np.zeros_like(t)
        for a, f, p, hh in zip(self.amps, self.freqs, self.phases, hk, strict=True):
            out += a * abs(hh) * np.cos(2 * np.pi * f * t + p + np.angle(hh))
        return out

    def reference(self, t: FloatArray) -> FloatArray:
        return self.through(gain(1.0), t)

    def error_variance(self, h: Response) -> float:
        """``Σ (A_k²/2) |1 − H(f_k)|²``, deg²."""
        return float(np.sum(self.amps**2 / 2 * np.abs(1 - h(self.freqs)) ** 2))


def orthogonal_noise(rng: np.random.Generator, sigma: float, against: FloatArray) -> FloatArray:
    """White noise with sample mean 0, sample variance exactly ``sigma²`` and zero sample
    correlation with ``against`` (so the variances add exactly)."""
    n = rng.normal(0.0, sigma, against.size)
    a = against - against.mean()
    n -= n.mean()
    if np.dot(a, a) > 0:
        n -= a * np.dot(n, a) / np.dot(a, a)
    return n * sigma / np.sqrt(np.mean(n**2))
