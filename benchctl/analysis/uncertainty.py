"""Confidence interval of σ from the equivalent degrees of freedom of the variance estimate.

The variance estimate is ``σ̂² = (1/N) Σ (ε_i − ε̄)²`` (= the area under the error density).
For a Gaussian stationary error of one-sided density ``G`` over a record of ``T`` seconds,
``var(σ̂²) ≈ (1/T) ∫ G² df``, so ``σ̂²·ν/σ²`` is close to χ² with

    ν = 2 σ⁴ / var(σ̂²) = 2 T (∫G df)² / ∫G² df = 2 B_e T,   B_e = (∫G)²/∫G².

Better, for a bench test: the stand's motion is known and is not a random sample, so the part
of ε coherent with it (``G_lin``, see ``frf.decompose``) is a fixed function of the motion.
Only the incoherent part ``G_inc`` is random; then
``var(σ̂²) ≈ (1/T) [∫ G_inc² df + 2 ∫ G_lin G_inc df]`` (the ∫G_lin² term of the Gaussian
formula is absent). This is the ``dof`` reported; the fully random ν (the motion itself a
sample of the sea) is reported too as ``dof_motion_random``.

``∫ Ĝ²`` of an estimate with ν_f degrees of freedom per frequency overestimates ``∫ G²`` by
the factor ``1 + 2/ν_f``; the random parts are corrected for it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray
from scipy.special import gammaincinv, ndtri

FloatArray = NDArray[np.float64]


def chi2_ppf(q: float, dof: float | FloatArray) -> FloatArray:
    """Quantile ``q`` of χ² with ``dof`` degrees of freedom (= scipy.stats.chi2.ppf)."""
    return np.asarray(2.0 * gammaincinv(np.asarray(dof) / 2.0, q), dtype=float)


def dof_of_variance(
    freq: FloatArray,
    linear: FloatArray,
    incoherent: FloatArray,
    duration_s: float,
    dof_per_freq: float,
    motion_random: bool = False,
) -> float:
    """Equivalent degrees of freedom ν of the variance estimate (see module notes).

    Parameters
    ----------
    freq : ndarray
        Frequencies, Hz.
    linear, incoherent : ndarray
        One-sided densities of the coherent and incoherent parts of ε, deg²/Hz.
    duration_s : float
        Effective record length ``N·Δt``, s.
    dof_per_freq : float
        ν_f of one spectral value of the estimate.
    motion_random : bool
        True: treat all of ε as a Gaussian random process (ν = 2 B_e T).

    Returns
    -------
    float
        ν, or ``inf`` when the estimate has no random part at all.
    """
    lin = np.maximum(linear, 0.0)
    inc = np.maximum(incoherent, 0.0)
    total = float(np.trapezoid(lin + inc, freq))
    bias = 1.0 + 2.0 / dof_per_freq
    if motion_random:
        denom = float(np.trapezoid((lin + inc) ** 2, freq)) / bias
    else:
        cross = float(np.trapezoid(lin * inc, freq))
        denom = float(np.trapezoid(inc**2, freq)) / bias + 2.0 * cross
    if denom <= 0.0 or total <= 0.0:
        return float("inf")
    return 2.0 * duration_s * total**2 / denom


def sigma_interval(sigma: float, dof: float, level: float = 0.95) -> tuple[float, float]:
    """Two-sided ``level`` interval for σ: ``σ̂ √(ν/χ²_{1−α/2,ν}) … σ̂ √(ν/χ²_{α/2,ν})``.

    Examples
    --------
    >>> lo, hi = sigma_interval(1.0, 100.0)
    >>> round(lo, 3), round(hi, 3)
    (0.879, 1.161)
    """
    if not np.isfinite(dof):
        return (sigma, sigma)
    a = (1.0 - level) / 2.0
    lo = sigma * float(np.sqrt(dof / chi2_ppf(1.0 - a, dof)))
    hi = sigma * float(np.sqrt(dof / chi2_ppf(a, dof)))
    return (lo, hi)


def density_interval(
    density: FloatArray, dof_per_freq: float, level: float = 0.95
) -> tuple[FloatArray, FloatArray]:
    """Pointwise ``level`` interval of a spectral density with ν_f degrees of freedom."""
    a = (1.0 - level) / 2.0
    return (
        density * dof_per_freq / chi2_ppf(1.0 - a, dof_per_freq),
        density * dof_per_freq / chi2_ppf(a, dof_per_freq),
    )


def duration_for_precision(duration_s: float, dof: float, rel_halfwidth: float = 0.05) -> float:
    """Record length (s) for a 95 % interval of σ of ± ``rel_halfwidth`` (relative).

    ν grows in proportion to T; the half-width of the σ interval is about ``1.96/√(2ν)``.
    """
    if not np.isfinite(dof) or dof <= 0:
        return 0.0
    needed = 0.5 * (1.959964 / rel_halfwidth) ** 2
    return duration_s * needed / dof


def unbiased_dof(value: float, var: float) -> float:
    """Satterthwaite's ν = 2θ²/var(θ̂) of a variance-like estimate θ̂, with θ² estimated
    without bias (``E θ̂² = θ² + var``): ``ν = 2θ̂²/var − 2``, at least 1; ``inf`` if var is 0.

    The plain ``2θ̂²/var`` overstates ν when var is itself estimated from the same few
    spectral values (for ν/2 equal exponential values it gives ν + 2 on average).
    """
    if not var > 0.0:
        return float("inf")
    return max(1.0, 2.0 * value * value / var - 2.0)


#: draws of the fixed table of χ²₁ values that ``weighted_chi2_factors`` takes quantiles from
CHI2_TABLE_DRAWS = 40_000
_CHI2_TABLE: dict[int, FloatArray] = {}


def _chi2_table(columns: int) -> FloatArray:
    """``CHI2_TABLE_DRAWS`` rows of ``columns`` independent χ²₁ values, the same in every run
    (seeded): a table, not a random experiment."""
    if columns not in _CHI2_TABLE:
        z = np.random.default_rng(20231).standard_normal((CHI2_TABLE_DRAWS, columns))
        _CHI2_TABLE[columns] = z * z
    return _CHI2_TABLE[columns]


def weighted_chi2_factors(weights: FloatArray, level: float = 0.95) -> tuple[float, float]:
    """(G, H) of ``mls_interval`` for a pivot ``Q = Σ w_k χ²₁,k`` (normalised, ``Σ w = 1``),
    from Q's quantiles over a fixed table of ``CHI2_TABLE_DRAWS`` draws (the 2.5 % quantile
    to about ±2 %).

    Neither Satterthwaite's two moments nor Pearson's three get the lower tail of such a sum
    right when one χ²₁ dominates it (a drift's first cosine coefficient): for weights
    ∝ 1/k², k = 1 … 20, the 2.5 % quantile is 0.156, Satterthwaite's χ² puts it at 0.03 (an
    upper end five times too high) and Pearson's shifted χ² at 0.28 (an upper end too low,
    just when σ reads low).

    Examples
    --------
    >>> g, h = weighted_chi2_factors(np.full(10, 0.1))
    >>> round(g, 2), round(h, 2)  # χ² of 10 degrees of freedom: 0.512 and 2.080 (the table: ±2 %)
    (0.51, 2.06)
    """
    w = np.asarray(weights, dtype=float)
    w = w / w.sum()
    q = np.einsum("ij,j->i", _chi2_table(len(w)), w)  # numpy's loop: no BLAS threads (sums)
    a = (1.0 - level) / 2.0
    q_lo, q_hi = np.quantile(q, [a, 1.0 - a])
    return 1.0 - 1.0 / float(q_hi), 1.0 / max(float(q_lo), 1e-12) - 1.0


def mls_interval(
    total: float,
    parts: Sequence[tuple[float, ...]],
    gaussian_var: float = 0.0,
    level: float = 0.95,
) -> tuple[float, float]:
    """Interval for a sum of variance components (Graybill & Wang's modified large-sample
    method), plus a Gaussian term.

    ``total`` = Σ θ̂_i + (the Gaussian term's estimate); ``parts`` the independent
    components ``(θ̂_i, ν_i)`` with ``θ̂_i ~ θ_i χ²_{ν_i}/ν_i``; ``gaussian_var`` the variance
    of a normally distributed remainder. With ``G_i = 1 − ν_i/χ²_{1−α/2,ν_i}``,
    ``H_i = ν_i/χ²_{α/2,ν_i} − 1`` and z the normal quantile::

        lo = total − √(Σ (θ̂_i G_i)² + z² V),   hi = total + √(Σ (θ̂_i H_i)² + z² V)

    Exact for one χ² component, and close to the level for several (each keeps its own skew,
    which a single pooled ν would lose when a component of few degrees of freedom, a slow
    drift, sits beside one of many). A part may carry its own ``(θ̂, ν, G, H)`` when its
    pivot ``θ̂/θ`` is not a scaled χ² (``G = 1 − 1/q_hi``, ``H = 1/q_lo − 1`` from the pivot's
    quantiles; ``weighted_chi2_factors``).

    Examples
    --------
    >>> lo, hi = mls_interval(1.0, [(1.0, 100.0)])
    >>> round(lo, 3), round(hi, 3)
    (0.772, 1.347)
    """
    a = (1.0 - level) / 2.0
    lo2 = hi2 = 0.0
    for part in parts:
        value, dof = part[0], part[1]
        if value <= 0.0 or not np.isfinite(dof):
            continue
        if len(part) == 4:  # the component's own (G, H): a pivot that is not a scaled χ²
            g, h = float(part[2]), float(part[3])
        else:
            g = 1.0 - dof / float(chi2_ppf(1.0 - a, dof))
            h = dof / float(chi2_ppf(a, dof)) - 1.0
        lo2 += (value * g) ** 2
        hi2 += (value * h) ** 2
    z2 = float(ndtri(1.0 - a)) ** 2 * max(gaussian_var, 0.0)
    return total - float(np.sqrt(lo2 + z2)), total + float(np.sqrt(hi2 + z2))
