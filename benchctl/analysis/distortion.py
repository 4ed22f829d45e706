"""Nonlinear distortion from one run of an odd random-phase multisine (pure computation).

An odd multisine excites only odd harmonics ``k`` of ``1/T_p``, and leaves some odd ones out
on purpose (detection lines, see ``benchctl.profiles.synthesis.select_lines``). A linear
instrument answers only at the excited lines; a static nonlinearity also puts power at the
unexcited ones: odd-order terms (a cubic, a saturation) on odd lines, even-order terms (a
square, an asymmetry) on even lines (Pintelon & Schoukens, *System Identification*, ch. 3).
Over a record of ``P ≥ 2`` whole periods the DFT bins between the harmonics (``j ≢ 0 mod P``)
hold noise only, so the noise level at each harmonic is measured beside it.

For each group G (the unexcited odd, then the unexcited even harmonics from 1 to
``3·k_max`` — the reach of a cubic —, ``k_max`` the highest line excited on any axis), on the
error ε = y − x (so that a stand's own distortion, which the instrument only follows, is not
counted):

- ``P_k = 2|E_{Pk}|²/N_v²``: the power (deg², a line's variance) at harmonic k;
- ``λ̂_k``: the mean of the same quantity over the ``P − 1`` non-harmonic bins nearest to it
  (``Pk + m``, ``−⌈P/2⌉ < m ≤ ⌊P/2⌋``, m ≠ 0: disjoint between harmonics);
- the statistic ``F = Σ_G P_k / Σ_G λ̂_k``. Without distortion and with the noise locally
  flat, ``F`` follows Fisher's F with ``ν₁ = 2(Σλ)²/Σλ²`` (``2|G|`` for a flat level;
  Satterthwaite, λ² estimated without bias) and ``ν₂ = (P − 1)·ν₁`` degrees of freedom;
- distortion is **detected** in a group when ``F`` exceeds its ``1 − α/2`` quantile, and in
  the record when either group's does (Bonferroni: a linear instrument is flagged in at most
  α = 1 % of records).

Levels are reported per line as rms (``√(mean P_k)``, deg) beside the noise's
(``√(mean λ̂_k)``), their ratio in dB, and the distortion variance at those lines
``max(Σ P_k − Σ λ̂_k, 0)`` (deg²). The output y and the reference x get the same levels
(without a verdict), to show where a distortion comes from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.special import fdtrc, fdtri  # the F distribution (scipy.stats costs 0.5 s to import)

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]

ALPHA = 0.01  # the record's false-alarm rate (Bonferroni over the odd and even groups)
REACH = 3  # harmonics examined up to REACH × the highest excited one


@dataclass(frozen=True)
class GroupLevel:
    """The levels of one group of unexcited harmonics in one signal."""

    harmonics: IntArray
    power: FloatArray  # P_k, deg²
    noise: FloatArray  # λ̂_k, deg²

    @property
    def level_deg(self) -> float | None:
        return math.sqrt(float(self.power.mean())) if self.power.size else None

    @property
    def noise_deg(self) -> float | None:
        return math.sqrt(float(self.noise.mean())) if self.noise.size else None

    @property
    def ratio(self) -> float:
        den = float(self.noise.sum())
        return float(self.power.sum()) / den if den > 0 else math.inf

    @property
    def excess_deg2(self) -> float:
        return max(float(self.power.sum() - self.noise.sum()), 0.0)


@dataclass(frozen=True)
class GroupTest:
    """The F test of one group (see the module notes)."""

    level: GroupLevel
    dof: tuple[float, float]
    p_value: float
    threshold: float  # the F quantile the ratio is held against
    detected: bool

    def to_dict(self, freq_of: float) -> dict[str, Any]:
        lv = self.level
        return {
            "n_lines": int(lv.harmonics.size),
            "harmonics": lv.harmonics.tolist(),
            "freq": (lv.harmonics * freq_of).tolist(),
            "power_deg2": lv.power.tolist(),
            "noise_deg2": lv.noise.tolist(),
            "level_deg": lv.level_deg,
            "noise_deg": lv.noise_deg,
            "ratio_db": _db(lv.ratio),
            "excess_deg2": lv.excess_deg2,
            "f": lv.ratio,
            "dof": list(self.dof),
            "p_value": self.p_value,
            "threshold_db": _db(self.threshold),
            "detected": self.detected,
        }


def _db(r: float) -> float | None:
    return 10.0 * math.log10(r) if r > 0 and math.isfinite(r) else None


@dataclass(frozen=True)
class Distortion:
    """What the unexcited lines of an odd multisine say (deg, deg²; see the module notes)."""

    n_periods: int
    period_s: float
    odd: GroupTest
    even: GroupTest
    output: tuple[GroupLevel, GroupLevel]  # y: odd, even
    reference: tuple[GroupLevel, GroupLevel]  # x: odd, even
    alpha: float = ALPHA

    @property
    def detected(self) -> bool:
        return self.odd.detected or self.even.detected

    def to_dict(self) -> dict[str, Any]:
        df = 1.0 / self.period_s
        noise = np.concatenate((self.odd.level.noise, self.even.level.noise))
        return {
            "signal": "error",
            "n_periods": self.n_periods,
            "odd_deg": self.odd.level.level_deg,
            "even_deg": self.even.level.level_deg,
            "noise_deg": math.sqrt(float(noise.mean())) if noise.size else None,
            "detected": self.detected,
            "alpha": self.alpha,
            "rule": (
                "F = Σ P_k / Σ λ̂_k over the unexcited odd (even) harmonics, against Fisher's F "
                f"quantile 1 − α/2 (α = {self.alpha:g}, Bonferroni over the two groups)"
            ),
            "odd": self.odd.to_dict(df),
            "even": self.even.to_dict(df),
            "output": _levels(self.output),
            "reference": _levels(self.reference),
        }


def _levels(pair: tuple[GroupLevel, GroupLevel]) -> dict[str, float | None]:
    odd, even = pair
    noise = np.concatenate((odd.noise, even.noise))
    return {
        "odd_deg": odd.level_deg,
        "even_deg": even.level_deg,
        "noise_deg": math.sqrt(float(noise.mean())) if noise.size else None,
        "odd_ratio_db": _db(odd.ratio),
        "even_ratio_db": _db(even.ratio),
    }


def distortion_harmonics(
    excited: IntArray, n_periods: int, n_bins: int
) -> tuple[IntArray, IntArray]:
    """The unexcited odd and even harmonics examined: 1 … ``REACH·max(excited)``, each with
    its ``P − 1`` noise bins below the Nyquist bin ``n_bins − 1``."""
    p = int(n_periods)
    top = REACH * int(np.max(excited))
    top = min(top, (n_bins - 2 - p // 2) // p)
    k = np.arange(1, top + 1, dtype=np.int64)
    k = k[~np.isin(k, excited)]
    return k[k % 2 == 1], k[k % 2 == 0]


def _offsets(p: int) -> IntArray:
    m = np.arange(-((p + 1) // 2) + 1, p // 2 + 1, dtype=np.int64)
    return m[m != 0]


def group_level(u: FloatArray, harmonics: IntArray, n_periods: int) -> GroupLevel:
    """``P_k`` and ``λ̂_k`` of ``harmonics`` from a periodogram ``u`` in line units."""
    p = int(n_periods)
    off = _offsets(p)
    j = harmonics * p
    power = u[j] if harmonics.size else np.zeros(0)
    noise = u[j[:, None] + off[None, :]].mean(axis=1) if harmonics.size else np.zeros(0)
    return GroupLevel(harmonics, np.asarray(power, dtype=float), np.asarray(noise, dtype=float))


def group_test(level: GroupLevel, n_periods: int, alpha: float = ALPHA) -> GroupTest:
    """The F test of one group (module notes); with no harmonic in it, never detected."""
    m = int(level.harmonics.size)
    p = int(n_periods)
    if m == 0 or not float(level.noise.sum()) > 0.0:
        return GroupTest(level, (0.0, 0.0), 1.0, math.inf, False)
    lam = level.noise
    # E λ̂² = λ²·(1 + 1/(P−1)) for a mean of P − 1 bins (χ² with 2(P−1) dof)
    lam2 = float(np.sum(lam**2)) / (1.0 + 1.0 / (p - 1))
    nu1 = min(2.0 * float(lam.sum()) ** 2 / lam2, 2.0 * m)
    nu2 = (p - 1) * nu1
    ratio = level.ratio
    threshold = float(fdtri(nu1, nu2, 1.0 - alpha / 2.0))
    p_value = float(fdtrc(nu1, nu2, ratio))
    return GroupTest(level, (nu1, nu2), p_value, threshold, bool(ratio > threshold))


def line_units(spectrum: ComplexArray, n_valid: int) -> FloatArray:
    """``2|X_j|²/N_v²``: a bin's power as a line's variance (deg²)."""
    return np.asarray(2.0 * (spectrum.real**2 + spectrum.imag**2) / float(n_valid) ** 2)


def analyze_distortion(
    x_spectrum: ComplexArray,
    y_spectrum: ComplexArray,
    n_valid: int,
    n_periods: int,
    period_s: float,
    excited: IntArray,
    alpha: float = ALPHA,
) -> Distortion:
    """The distortion levels and test of an odd multisine record (module notes).

    Parameters
    ----------
    x_spectrum, y_spectrum : ndarray of complex
        rfft of the reference's and the instrument's residuals after the fit of the mean and
        the excited lines (zero-filled in gaps), over ``n_periods`` whole periods.
    n_valid : int
        Samples present.
    n_periods : int
        Whole periods ``P`` in the record, at least 2 (the noise bins lie between harmonics).
    period_s : float
        ``T_p`` (only to give the harmonics' frequencies).
    excited : ndarray of int
        Every harmonic excited on any axis (they are not examined).

    Examples
    --------
    Three periods of an odd multisine through a cubic, plus white noise:

    >>> import numpy as np
    >>> n, p = 3000, 3
    >>> k = np.array([1, 3, 7, 9, 11])                   # 5 left out: a detection line
    >>> t = np.arange(n) / n
    >>> rng = np.random.default_rng(0)
    >>> x = sum(np.cos(2 * np.pi * p * kk * t + rng.uniform(0, 6.3)) for kk in k)
    >>> y = x + 0.01 * x**3 + rng.normal(0, 0.01, n)
    >>> def resid(v):
    ...     s = np.fft.rfft(v); s[0] = 0; s[k * p] = 0; return s
    >>> d = analyze_distortion(resid(x), resid(y), n, p, 1.0, k)
    >>> d.detected, d.odd.detected, d.even.detected
    (True, True, False)
    """
    if n_periods < 2:
        raise ValueError(f"n_periods: expected at least 2 whole periods, got {n_periods}")
    exc = np.unique(np.asarray(excited, dtype=np.int64))
    nb = len(y_spectrum)
    odd_k, even_k = distortion_harmonics(exc, n_periods, nb)
    ue = line_units(y_spectrum - x_spectrum, n_valid)
    uy = line_units(y_spectrum, n_valid)
    ux = line_units(x_spectrum, n_valid)
    odd = group_test(group_level(ue, odd_k, n_periods), n_periods, alpha)
    even = group_test(group_level(ue, even_k, n_periods), n_periods, alpha)
    out = (group_level(uy, odd_k, n_periods), group_level(uy, even_k, n_periods))
    ref = (group_level(ux, odd_k, n_periods), group_level(ux, even_k, n_periods))
    return Distortion(int(n_periods), float(period_s), odd, even, out, ref, alpha)
