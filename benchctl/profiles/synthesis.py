"""Multisine synthesis: lines on k/T_p, seeded phases, crest-factor reduction, fast sampling.

Pure computation, no I/O. Angles in degrees, frequencies in Hz, phases in radians, spectra
one-sided in deg²/Hz. A synthesised axis is a :class:`benchctl.harmonics.HarmonicTable`:

    x(t) = e(t) · Σ_k A_k cos(2π f_k t + φ_k),   f_k = k / T_p,   Δf = 1 / T_p

Amplitudes (``method``):

- ``"point"``: ``A_k = √(2 G(f_k) Δf)``, the textbook rule (Gryazin & Belova 2023);
- ``"cell"`` (default): ``A_k = √(2 ∫_cell G df)`` over the line's cell ``[f_k − Δf/2, f_k + Δf/2]``
  clipped to the band, the first and last cells stretched to the band edges. It is the same
  rule with G averaged over the cell, and makes ``Σ A_k²/2 = ∫_band G df`` hold exactly even
  with few lines or a narrow peak.

Phases come from ``numpy.random.Generator(PCG64(SeedSequence([seed, stream])))`` — PCG64 and
SeedSequence are specified bit for bit, so one seed gives the same phases on any machine.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from benchctl.harmonics import HarmonicTable, fade_envelope

FloatArray = NDArray[np.float64]
Density = Callable[[FloatArray], FloatArray]

AXIS_STREAM = {"roll": 0, "pitch": 1}
"""Random stream per axis: roll and pitch get independent phases from one seed."""

_FINE_PER_CELL = 32  # sub-intervals per line cell for the cell integral
_FAST_MIN_SAMPLES = 2048  # below this a direct sum is as quick as the FFT path


@dataclass(frozen=True)
class LineDesign:
    """Lines of one axis: frequencies, amplitudes, and what they should add up to."""

    freq_hz: FloatArray
    amp_deg: FloatArray
    harmonic: NDArray[np.int64]  # k, with f_k = k / period_s
    period_s: float
    band_hz: tuple[float, float]
    target_variance_deg2: float  # ∫_band G df
    method: str

    @property
    def variance_deg2(self) -> float:
        return float(np.sum(self.amp_deg**2) / 2.0)


def line_harmonics(band_hz: tuple[float, float], period_s: float) -> NDArray[np.int64]:
    """Harmonic numbers k ≥ 1 with ``k/T_p`` inside the closed band."""
    lo, hi = band_hz
    eps = 1e-9
    k_lo = max(1, math.ceil(lo * period_s - eps))
    k_hi = math.floor(hi * period_s + eps)
    return np.arange(k_lo, k_hi + 1, dtype=np.int64)


@dataclass(frozen=True)
class LineSelection:
    """Which of a band's harmonics an axis excites (the ``multisine`` option of a profile).

    ``kept``: the excited harmonics k; ``detection``: odd (or candidate) harmonics left out on
    purpose, at random, so that nonlinear distortion shows at them; ``odd``, ``interleave``,
    ``group``: the option itself.
    """

    kept: NDArray[np.int64]
    detection: NDArray[np.int64]
    odd: bool
    interleave: bool
    group: int

    def to_meta(self) -> dict[str, object]:
        return {
            "odd": self.odd,
            "interleave_axes": self.interleave,
            "detection_group": self.group,
            "detection_harmonics": [int(k) for k in self.detection],
        }


def select_lines(
    harmonics: ArrayLike,
    *,
    odd: bool = False,
    detection_group: int = 0,
    interleave_axes: bool = False,
    seed: int = 0,
    stream: int = 0,
) -> LineSelection:
    """The excited harmonics of one axis of an (odd) random-phase multisine.

    The candidates are ``harmonics`` (the band's k), reduced to the odd k with ``odd``; with
    ``interleave_axes`` each axis takes its own residue class, so that two axes never share a
    line (roll ``k ≡ 1``, pitch ``k ≡ 3 (mod 4)`` when odd; else roll odd k, pitch even k).
    With ``detection_group = g ≥ 2`` the candidates are cut into consecutive groups of g and one
    line of every whole group is left out, drawn uniformly from
    ``Generator(PCG64(SeedSequence([seed, stream, 1])))`` (Pintelon & Schoukens' detection
    lines: a nonlinearity shows at them, a linear system leaves only noise there).
    """
    k = np.asarray(harmonics, dtype=np.int64)
    if odd:
        k = k[k % 2 == 1]
    if interleave_axes:
        step, residue = (4, (1, 3)[stream % 2]) if odd else (2, (1, 0)[stream % 2])
        k = k[k % step == residue]
    left: list[int] = []
    if detection_group >= 2 and k.size >= detection_group:
        rng = np.random.Generator(
            np.random.PCG64(np.random.SeedSequence([int(seed), int(stream), 1]))
        )
        for start in range(0, k.size - detection_group + 1, detection_group):
            left.append(int(k[start + int(rng.integers(detection_group))]))
    detection = np.asarray(left, dtype=np.int64)
    kept = np.setdiff1d(k, detection).astype(np.int64)
    return LineSelection(kept, detection, odd, interleave_axes, int(detection_group))


def band_integral(
    density: Density, edges_hz: FloatArray, breakpoints_hz: ArrayLike | None = None
) -> FloatArray:
    """∫ G df over each interval between consecutive ``edges_hz`` (deg²).

    Composite trapezoid on a grid of ``32`` sub-intervals per interval plus every breakpoint
    of a piecewise-linear density (exact for those; O(h²) for smooth densities).
    """
    edges = np.asarray(edges_hz, dtype=float)
    u = np.linspace(0.0, 1.0, _FINE_PER_CELL + 1)[:-1]
    fine = (edges[:-1, None] + np.diff(edges)[:, None] * u[None, :]).ravel()
    grid = np.concatenate([fine, edges[-1:]])
    if breakpoints_hz is not None:
        bp = np.asarray(breakpoints_hz, dtype=float)
        bp = bp[(bp > edges[0]) & (bp < edges[-1])]
        grid = np.union1d(grid, bp)
    g = np.asarray(density(grid), dtype=float)
    cum = np.concatenate([[0.0], np.cumsum(np.diff(grid) * (g[1:] + g[:-1]) / 2.0)])
    at_edges = np.interp(edges, grid, cum)
    return np.asarray(np.diff(at_edges))


def design_lines(
    density: Density,
    band_hz: tuple[float, float],
    period_s: float,
    *,
    method: str = "cell",
    breakpoints_hz: ArrayLike | None = None,
    keep: ArrayLike | None = None,
) -> LineDesign:
    """Lines ``f_k = k/T_p`` inside ``band_hz`` with amplitudes from the one-sided density.

    Parameters
    ----------
    density : callable
        ``G(f)``, deg²/Hz, vectorised over an array of frequencies in Hz.
    band_hz : (float, float)
        Closed band ``[f_lo, f_hi]``, Hz.
    period_s : float
        Repetition period ``T_p``; the line spacing is ``Δf = 1/T_p``.
    method : {"cell", "point"}
        Amplitude rule (module docstring).
    breakpoints_hz : array_like, optional
        Kinks of a piecewise-linear density, integrated exactly.
    keep : array_like of int, optional
        Only these harmonics k (a subset of the band's, see :func:`select_lines`). Each kept
        line then stands for the density over its own, wider cell (edges halfway to the next
        kept line, the first and last stretched to the band edges): ``cell`` amplitudes still
        add up to ``Σ A_k²/2 = ∫_band G df`` and follow the density's shape; ``point`` uses
        ``A_k = √(2 G(f_k) w_k)`` with ``w_k`` that cell's width.

    Returns
    -------
    LineDesign
        With ``target_variance_deg2 = ∫_band G df``. Raises ``ValueError`` if no line fits.
    """
    lo, hi = band_hz
    k = line_harmonics(band_hz, period_s)
    if k.size == 0:
        raise ValueError(f"no line k/{period_s:g} s falls inside the band {lo:g}…{hi:g} Hz")
    df = 1.0 / period_s
    if keep is not None:
        kk = np.asarray(keep, dtype=np.int64)
        if kk.size == 0 or not np.all(np.isin(kk, k)):
            raise ValueError(f"keep: expected a non-empty subset of the band's harmonics {k}")
        k = np.unique(kk)
    f = k / period_s
    edges = np.concatenate([[lo], (f[:-1] + f[1:]) / 2.0, [hi]])
    cells = band_integral(density, edges, breakpoints_hz)
    target = float(np.sum(cells))
    if method == "cell":
        power = cells
    elif method == "point":
        width = np.diff(edges) if keep is not None else df
        power = np.asarray(density(f), dtype=float) * width
    else:
        raise ValueError(f"method must be 'cell' or 'point', got {method!r}")
    amp = np.sqrt(2.0 * np.clip(power, 0.0, None))
    return LineDesign(f, amp, k, float(period_s), (float(lo), float(hi)), target, method)


def random_phases(n: int, seed: int, stream: int = 0) -> FloatArray:
    """``n`` phases uniform in [0, 2π) from ``Generator(PCG64(SeedSequence([seed, stream])))``."""
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), int(stream)])))
    return np.asarray(rng.uniform(0.0, 2.0 * np.pi, n))


# --- crest factor -----------------------------------------------------------------------


@dataclass(frozen=True)
class CrestReport:
    """What the crest-factor reduction did (crest factor = peak |x| / rms of one period)."""

    method: str
    crest_before: float
    crest_after: float
    iterations: int = 0

    def to_dict(self) -> dict[str, object]:
        return {
            "method": self.method,
            "crest_before": round(self.crest_before, 4),
            "crest_after": round(self.crest_after, 4),
            "iterations": self.iterations,
        }


def _period_grid_size(k_max: int, oversample: int = 16) -> int:
    return int(2 ** math.ceil(math.log2(max(64, oversample * k_max))))


def _one_period(
    harmonic: ArrayLike, amp: ArrayLike, phase: ArrayLike, n: int, derivative: int = 0
) -> FloatArray:
    """One period of ``Σ A_k cos(2πkt/T + φ_k)`` (or its d-th derivative in units of 2π/T per
    power) on ``n`` equally spaced points, by inverse real FFT."""
    k = np.asarray(harmonic, dtype=np.int64)
    spec = np.zeros(n // 2 + 1, dtype=complex)
    coef = np.asarray(amp, dtype=float) * np.exp(1j * np.asarray(phase, dtype=float))
    if derivative:
        coef = coef * (1j * k) ** derivative
    np.add.at(spec, k, coef * (n / 2.0))
    return np.asarray(np.fft.irfft(spec, n))


def crest_factor(harmonic: ArrayLike, amp: ArrayLike, phase: ArrayLike) -> float:
    """Crest factor of the steady multisine, from one period sampled 16× over its top line."""
    a = np.asarray(amp, dtype=float)
    rms = math.sqrt(float(np.sum(a**2)) / 2.0)
    if rms == 0.0:
        return 0.0
    k = np.asarray(harmonic, dtype=np.int64)
    x = _one_period(k, a, phase, _period_grid_size(int(k.max())))
    return float(np.max(np.abs(x)) / rms)


def schroeder_phases(amp: ArrayLike) -> FloatArray:
    """Schroeder (1970) low-crest phases for an arbitrary power spectrum over contiguous lines.

    ``φ_n = −2π Σ_{l<n} (n − l) p_l`` with ``p_l = A_l² / Σ A²``. Deterministic (no seed).
    """
    a = np.asarray(amp, dtype=float)
    p = a**2 / np.sum(a**2)
    n = np.arange(1, a.size + 1, dtype=float)
    cum_p = np.concatenate([[0.0], np.cumsum(p)[:-1]])
    cum_lp = np.concatenate([[0.0], np.cumsum(n * p)[:-1]])
    return np.asarray(np.mod(-2.0 * np.pi * (n * cum_p - cum_lp), 2.0 * np.pi))


def clip_phases(
    harmonic: ArrayLike,
    amp: ArrayLike,
    phase: ArrayLike,
    iterations: int = 100,
    clip_ratio: float = 0.9,
) -> tuple[FloatArray, int]:
    """Iterative clipping (Van der Ouderaa, Schoukens & Renneboog 1988): clip one period at
    ``clip_ratio`` of its peak, keep the clipped signal's phases at the lines, restore the
    amplitudes, repeat. Returns the phases with the lowest crest factor seen and the number of
    iterations run. Amplitudes (the spectrum) never change."""
    k = np.asarray(harmonic, dtype=np.int64)
    a = np.asarray(amp, dtype=float)
    ph = np.asarray(phase, dtype=float).copy()
    n = _period_grid_size(int(k.max()), oversample=8)
    best, best_peak = ph.copy(), math.inf
    for _ in range(iterations):
        x = _one_period(k, a, ph, n)
        peak = float(np.max(np.abs(x)))
        if peak < best_peak:
            best, best_peak = ph.copy(), peak
        level = clip_ratio * peak
        spec = np.fft.rfft(np.clip(x, -level, level))
        ph = np.angle(spec[k])
    return np.asarray(np.mod(best, 2.0 * np.pi)), iterations


def reduce_crest(
    harmonic: ArrayLike,
    amp: ArrayLike,
    phase: ArrayLike,
    method: str = "none",
    iterations: int = 100,
) -> tuple[FloatArray, CrestReport]:
    """Apply a crest-factor reduction by phase choice and report before/after."""
    ph0 = np.asarray(phase, dtype=float)
    before = crest_factor(harmonic, amp, ph0)
    if method == "none" or np.asarray(amp).size < 2:
        return ph0, CrestReport(method if np.asarray(amp).size >= 2 else "none", before, before)
    if method == "schroeder":
        ph = schroeder_phases(amp)
        return ph, CrestReport("schroeder", before, crest_factor(harmonic, amp, ph))
    if method == "clip":
        ph, it = clip_phases(harmonic, amp, ph0, iterations)
        return ph, CrestReport("clip", before, crest_factor(harmonic, amp, ph), it)
    raise ValueError(f"crest method must be none, schroeder or clip, got {method!r}")


# --- fast evaluation of a harmonic table ------------------------------------------------


def _uniform_grid(t: FloatArray) -> tuple[float, int] | None:
    """(dt, i0) when ``t == (i0 + i)·dt`` to rounding, else None."""
    if t.size < 2:
        return None
    dt = (t[-1] - t[0]) / (t.size - 1)
    if not dt > 0:
        return None
    i0f = t[0] / dt
    i0 = round(i0f)
    scale = max(1.0, float(np.max(np.abs(t))))
    if abs(i0f - i0) * dt > 1e-11 * scale:
        return None
    ideal = (i0 + np.arange(t.size)) * dt
    if float(np.max(np.abs(t - ideal))) > 1e-11 * scale:
        return None
    return dt, i0


def _steady(table: HarmonicTable, t: FloatArray, derivative: int) -> FloatArray:
    """Unfaded sum of cosines: by tiling one inverse-FFT period when ``t`` is a uniform grid
    holding a whole number of samples per period (exact), else by direct summation."""
    tp = table.period_s
    grid = _uniform_grid(t) if (tp and t.size >= _FAST_MIN_SAMPLES and table.n_lines) else None
    if grid is not None and tp:
        dt, i0 = grid
        n_f = tp / dt
        n = round(n_f)
        k_f = table.freq_hz * tp
        k = np.round(k_f).astype(np.int64)
        if abs(n_f - n) < 1e-6 and np.all(np.abs(k_f - k) < 1e-6) and int(k.max()) < n // 2:
            per = _one_period(k, table.amp_deg, table.phase_rad, n, derivative)
            per *= (2.0 * np.pi / tp) ** derivative
            idx = (i0 + np.arange(t.size)) % n
            return np.asarray(per[idx])
    return table.steady(t, derivative)


def evaluate_table(table: HarmonicTable, t_s: ArrayLike, derivative: int = 0) -> FloatArray:
    """``table.evaluate`` (same semantics: faded, zero outside [0, duration]) but fast on the
    uniform sample grids a stand uses (see :func:`_steady`)."""
    if derivative not in (0, 1, 2):
        raise ValueError(f"derivative must be 0, 1 or 2, got {derivative}")
    t = np.atleast_1d(np.asarray(t_s, dtype=float))
    env = [
        fade_envelope(t, table.duration_s, table.fade_in_s, table.fade_out_s, d)
        for d in range(derivative + 1)
    ]
    s = [_steady(table, t, d) for d in range(derivative + 1)]
    if derivative == 0:
        return np.asarray(env[0] * s[0])
    if derivative == 1:
        return np.asarray(env[1] * s[0] + env[0] * s[1])
    return np.asarray(env[2] * s[0] + 2.0 * env[1] * s[1] + env[0] * s[2])


def sample_times(duration_s: float, rate_hz: float) -> FloatArray:
    """``i/rate`` for i = 0 … ⌊duration·rate⌋ (both ends included when they fall on the grid)."""
    n = math.floor(duration_s * rate_hz + 1e-9) + 1
    return np.arange(n) / rate_hz


def tables_to_csv(tables: Mapping[str, HarmonicTable]) -> str:
    """Harmonic-table export: ``axis,freq_hz,period_s,amplitude_deg,phase_rad`` with ``#`` header
    lines giving each axis's duration, fades and repetition period. Floats in ``repr``."""
    lines = [
        "# benchctl harmonic table: x(t) = e(t) * sum amplitude_deg*cos(2*pi*freq_hz*t + phase_rad)"
    ]
    for a, tab in tables.items():
        lines.append(
            f"# {a}: duration_s={tab.duration_s!r} fade_in_s={tab.fade_in_s!r} "
            f"fade_out_s={tab.fade_out_s!r} period_s={tab.period_s!r}"
        )
    lines.append("axis,freq_hz,period_s,amplitude_deg,phase_rad")
    for a, tab in tables.items():
        for f, amp, ph in zip(tab.freq_hz, tab.amp_deg, tab.phase_rad, strict=True):
            lines.append(f"{a},{float(f)!r},{1.0 / float(f)!r},{float(amp)!r},{float(ph)!r}")
    return "\n".join(lines) + "\n"


def periodogram_lines(x: ArrayLike, harmonic: ArrayLike, periods: int = 1) -> FloatArray:
    """Variance at each line ``k`` of a record holding exactly ``periods`` whole periods, deg².

    ``2 |X_{k·periods}|² / N²`` from the record's DFT: ``A_k²/2`` for a multisine sampled over
    whole periods (no leakage).
    """
    xs = np.asarray(x, dtype=float)
    spec = np.fft.rfft(xs)
    k = np.asarray(harmonic, dtype=np.int64) * int(periods)
    return np.asarray(2.0 * np.abs(spec[k]) ** 2 / xs.size**2)
