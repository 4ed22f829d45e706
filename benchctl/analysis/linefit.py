"""Fitting the lines to the samples: the least-squares coefficients of a mean and the excited
lines on the analysis grid, and the lines' period fitted to the reference.

Over whole periods of a gap-free uniform grid the fit is the DFT over the record
(``c_k = 2 X_k / N``) and is computed so; otherwise by conjugate gradients on the normal
equations, the sums ``Σ v_s e^{−j2π f_k s Δt}`` by chirp-z transforms (:func:`chirp_sum`: exact,
O(N log N)), with the instants' offsets from the grid (jittered or wandering stamps) taken in
by a Taylor expansion about each slot. :func:`refine_period` fits the period itself
(Gauss–Newton, the lines refitted at each step). Used by the line-wise estimate
(:mod:`benchctl.analysis.linewise`), the excitation fidelity and the cross-axis estimate.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.fft import fft, ifft, irfft, next_fast_len, rfft

from benchctl.analysis.lines import LinesError, LineSet
from benchctl.analysis.sums import dot

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]

PERIOD_PHASE_TOL = 1e-6  # period refinement: stop when the highest line turns less (rad)
REFINE_MAX_ITER = 6
REFINE_SKIP = 1e-14  # no refinement when the lines leave less of the reference's variance
CG_TOL = 1e-13
CG_MAX_ITER = 200
TAYLOR_TOL = 1e-10  # the instants' offsets from the grid: expansion remainder |ωδ|^(P+1)/(P+1)!
TAYLOR_MAX_ORDER = 12


def chirp_sum(x: NDArray[Any], alpha: float, n_out: int, sign: int) -> ComplexArray:
    """``Y_k = Σ_n x_n exp(sign·j2π·α·n·k)`` for k = 0 … n_out − 1, along the last axis.

    Bluestein's chirp-z algorithm (``nk = (n² + k² − (k − n)²)/2``): three FFTs of length
    ``next_fast_len(N + n_out − 1)``; exact to rounding for any α (the chirp's phase, in
    cycles, is reduced modulo 1 before it is scaled by 2π: for a million samples and
    α = 10⁻⁵ its error is a few nanoradians).
    """
    x = np.asarray(x, dtype=complex)
    n_in = x.shape[-1]
    length = next_fast_len(n_in + n_out - 1)
    big = max(n_in, n_out)
    k = np.arange(big, dtype=np.int64)
    half = 0.5 * alpha * (k * k).astype(float)  # α·k²/2 cycles (k² exact in int64)
    chirp = np.exp(sign * 2j * np.pi * np.mod(half, 1.0))
    a = x * chirp[:n_in]
    b = np.zeros(length, dtype=complex)
    b[:n_out] = np.conj(chirp[:n_out])
    b[length - n_in + 1 :] = np.conj(chirp[1:n_in][::-1])
    conv = ifft(fft(a, length, axis=-1) * fft(b), axis=-1)[..., :n_out]
    return np.asarray(conv * chirp[:n_out], dtype=complex)


@dataclass
class LineFit:
    """Least-squares line coefficients of C channels on one grid.

    ``coef[c, k]``: complex amplitude of line k (the component is ``Re(coef·e^{j2πf t})``);
    ``mean[c]``: the fitted constant; ``spectrum[c]``: rfft of the zero-filled residual;
    ``residual[c]``: data minus fit, zero in the gaps (on the DFT path made from the spectrum
    when first asked for); ``exact``: the DFT path (whole periods, no gaps); ``iterations``:
    conjugate-gradient iterations (0 on the DFT path).
    """

    coef: ComplexArray
    mean: FloatArray
    spectrum: ComplexArray
    exact: bool
    iterations: int
    n: int
    _residual: FloatArray | None = None
    _power: FloatArray | None = None

    @property
    def residual(self) -> FloatArray:
        if self._residual is None:
            self._residual = np.asarray(irfft(self.spectrum, self.n, axis=-1), dtype=float)
        return self._residual

    def residual_power(self) -> FloatArray:
        """``Σ_s r_s²`` of each channel (Parseval on the spectrum; made once, as the residual
        is: the spectrum is not changed after the fit)."""
        if self._power is None:
            a = self.spectrum.real**2 + self.spectrum.imag**2
            total = 2.0 * a.sum(axis=-1) - a[..., 0]
            if self.n % 2 == 0:
                total = total - a[..., -1]
            self._power = np.asarray(total / self.n, dtype=float)
        return self._power.copy()


class _Operator:
    """The design matrix A of ``c₀ + Re Σ c_k e^{j2π f_k t_s}`` on the masked grid, with
    parameters packed as ``(c₀, Re c, −Im c)`` (so ``c = a − jb``: ``a cos + b sin``).

    The instants are ``t_s = s·Δt + δ_s``: with offsets δ (jittered or wandering stamps) the
    exponential is expanded about the slot, ``e^{jωt} = e^{jωsΔt} Σ_p (jωδ)^p/p!``, to the
    order that makes the remainder below ``TAYLOR_TOL`` for the largest ``|ωδ|``; each term
    is one more chirp-z synthesis and analysis.
    """

    def __init__(self, n: int, mask: NDArray[np.bool_], dt: float, period: float,
                 harmonics: IntArray, offsets: FloatArray | None = None) -> None:
        self.n = n
        self.mask = mask
        self.k = harmonics
        self.m_lo = int(harmonics.min())
        self.m_count = int(harmonics.max()) - self.m_lo + 1
        self.alpha = dt / period
        cycles = self.alpha * self.m_lo * np.arange(n, dtype=float)  # f_lo·s·Δt
        self.shift = np.exp(-2j * np.pi * np.mod(cycles, 1.0))  # e^{−j2π f_lo s Δt}
        self.omega = 2.0 * np.pi * harmonics / period
        self.powers: list[FloatArray] = []  # δ^p/p!, p = 1 … P
        if offsets is not None:
            x = float(np.max(np.abs(offsets))) * float(self.omega.max())
            order, term = 0, 1.0
            while term > TAYLOR_TOL and order < TAYLOR_MAX_ORDER:
                order += 1
                term = x ** (order + 1) / math.factorial(order + 1)
            if term > TAYLOR_TOL:
                raise LinesError(
                    f"the sample instants stray up to {float(np.max(np.abs(offsets))):.3g} s "
                    "from the grid; too far to fit the lines on it"
                )
            self.powers = [offsets**p / math.factorial(p) for p in range(1, order + 1)]

    def analysis(self, v: FloatArray) -> ComplexArray:
        """``Σ_s v_s e^{−j2π f_k s Δt}`` for every line (v zero in the gaps)."""
        g = chirp_sum(v * self.shift, self.alpha, self.m_count, -1)
        return g[..., self.k - self.m_lo]

    def synthesis(self, coef: ComplexArray) -> FloatArray:
        """``Re Σ_k coef_k e^{j2π f_k s Δt}`` on every slot."""
        c = np.zeros((*coef.shape[:-1], self.m_count), dtype=complex)
        c[..., self.k - self.m_lo] = coef
        out = chirp_sum(c, self.alpha, self.n, +1) * np.conj(self.shift)
        return np.asarray(out.real, dtype=float)

    def forward(self, p: FloatArray) -> FloatArray:
        kk = len(self.k)
        coef = p[..., 1 : 1 + kk] - 1j * p[..., 1 + kk :]
        v = p[..., :1] + self.synthesis(coef)
        for order, w in enumerate(self.powers, start=1):
            v = v + w * self.synthesis(coef * (1j * self.omega) ** order)
        return np.where(self.mask, v, 0.0)

    def adjoint(self, v: FloatArray) -> FloatArray:
        g = self.analysis(v)
        for order, w in enumerate(self.powers, start=1):
            g = g + (-1j * self.omega) ** order * self.analysis(v * w)
        return np.concatenate((v.sum(axis=-1, keepdims=True), g.real, -g.imag), axis=-1)


def _aligned_bins(n: int, dt: float, period: float, harmonics: IntArray) -> IntArray | None:
    """The rfft bins of the lines when every line makes whole cycles over the N slots."""
    b = harmonics * (n * dt / period)
    bi = np.rint(b).astype(np.int64)
    if np.all(np.abs(b - bi) <= 1e-9 * np.maximum(1.0, b)) and bi.min() >= 1 and 2 * bi.max() < n:
        return bi
    return None


def fit_lines(
    values: FloatArray,
    mask: NDArray[np.bool_],
    dt: float,
    period_s: float,
    harmonics: IntArray,
    offsets: FloatArray | None = None,
    first_spectrum: ComplexArray | None = None,
) -> LineFit:
    """Least-squares fit of a mean and the lines ``harmonics/period_s`` to each row of
    ``values`` (C × N at the instants ``s·dt + offsets_s``; only slots where ``mask`` count).
    ``first_spectrum``: the rfft of the first row, if already made (used on the DFT path).

    Raises ``LinesError`` when the normal equations do not converge (gaps leave the lines
    indistinguishable).
    """
    v = np.where(mask, np.atleast_2d(np.asarray(values, dtype=float)), 0.0)
    n = v.shape[-1]
    n_valid = int(mask.sum())
    uniform = offsets is None or not np.any(offsets[mask])
    bins = _aligned_bins(n, dt, period_s, harmonics) if uniform and bool(mask.all()) else None
    if bins is not None:
        if first_spectrum is not None and v.shape[0] > 1:
            spec = np.vstack((first_spectrum[None, :], rfft(v[1:], axis=-1)))
        elif first_spectrum is not None:
            spec = first_spectrum[None, :].copy()
        else:
            spec = rfft(v, axis=-1)
        mean = spec[..., 0].real / n
        coef = 2.0 * spec[..., bins] / n
        spec[..., 0] = 0.0  # the residual's spectrum, in place (spec is this fit's own)
        spec[..., bins] = 0.0
        return LineFit(coef, mean, spec, True, 0, n)
    op = _Operator(n, mask, dt, period_s, harmonics, None if uniform else offsets)
    rhs = op.adjoint(v)
    kk = len(harmonics)
    diag = np.full(1 + 2 * kk, n_valid / 2.0)
    diag[0] = n_valid
    p = rhs / diag
    r = rhs - op.adjoint(op.forward(p))
    z = r / diag
    d = z.copy()
    rz = np.sum(r * z, axis=-1, keepdims=True)
    scale = np.sqrt(np.sum(rhs * rhs / diag, axis=-1)) + 1e-300
    it = 0
    for it in range(1, CG_MAX_ITER + 1):  # noqa: B007 - the count is reported
        if np.all(np.sqrt(np.abs(rz[..., 0])) <= CG_TOL * scale):
            break
        q = op.adjoint(op.forward(d))
        dq = np.sum(d * q, axis=-1, keepdims=True)
        step = np.divide(rz, dq, out=np.zeros_like(rz), where=dq != 0)
        p = p + step * d
        r = r - step * q
        z = r / diag
        rz_new = np.sum(r * z, axis=-1, keepdims=True)
        beta = np.divide(rz_new, rz, out=np.zeros_like(rz), where=rz != 0)
        d = z + beta * d
        rz = rz_new
    else:
        raise LinesError(
            f"the least-squares fit of {kk} line(s) did not converge in {CG_MAX_ITER} "
            "iterations (the gaps leave lines indistinguishable)"
        )
    coef = p[..., 1 : 1 + kk] - 1j * p[..., 1 + kk :]
    residual = np.where(mask, v - op.forward(p), 0.0)
    return LineFit(coef, p[..., 0], rfft(residual, axis=-1), False, it, n, residual)


def grid_offsets(t: FloatArray, mask: NDArray[np.bool_], dt: float) -> FloatArray | None:
    """The instants' offsets from the uniform grid ``t₀ + s·dt`` (t₀ fitted so they average
    0), zero in the gaps; None when they are all zero."""
    s = np.flatnonzero(mask)
    if s.size == 0:
        return None
    d = t[s] - s * dt
    d = d - d.mean()
    if not np.any(np.abs(d) > 1e-12 * max(1.0, float(np.abs(t[s]).max()))):
        return None
    out = np.zeros(len(mask))
    out[s] = d
    return out


def _derivative(fit: LineFit, n: int, dt: float, lines: LineSet, mask: NDArray[np.bool_],
                offsets: FloatArray | None) -> FloatArray:
    """``ẋ(t) = Re Σ jω_k c_k e^{jω_k t}`` of the fitted lines (first row) at the instants."""
    omega = 2.0 * np.pi * lines.freq
    c = 1j * omega * fit.coef[0]
    bins = _aligned_bins(n, dt, lines.period_s, lines.harmonics) if fit.exact else None
    if bins is not None:
        spec = np.zeros(n // 2 + 1, dtype=complex)
        spec[bins] = c * (n / 2.0)
        return np.asarray(irfft(spec, n), dtype=float)
    op = _Operator(n, mask, dt, lines.period_s, lines.harmonics, offsets)
    p = np.concatenate(([0.0], c.real, -c.imag))
    return op.forward(p)


def refine_period(
    x: FloatArray,
    mask: NDArray[np.bool_],
    dt: float,
    lines: LineSet,
    offsets: FloatArray | None = None,
    fit: LineFit | None = None,
    xvar: float | None = None,
) -> tuple[LineSet, bool]:
    """The line set with its period fitted to the reference (Gauss–Newton on T_p, the lines
    refitted at each step): a stand playing on its own clock, or a period detected from a
    grid step fitted to jittered stamps, is some ppm off the nominal period, and over a long
    record that would leave part of every line in the residual. Stops once a step turns the
    highest line by less than ``PERIOD_PHASE_TOL`` over the record (that last step is
    taken), or at once when the lines leave less than ``REFINE_SKIP`` of the reference's
    variance in the residual. ``fit``: a fit at ``lines`` whose first row is x, if made;
    ``xvar``: ``Σ (x − x̄)²`` over the mask, if known. Returns the line set and whether its
    period changed.
    """
    n = len(mask)
    span = n * dt
    if xvar is None:
        xd = np.where(mask, x - float(x[mask].mean()), 0.0)
        xvar = dot(xd, xd)
        del xd
    t: FloatArray | None = None  # made at the first step (none when the lines fit at once)
    changed = False
    for _ in range(REFINE_MAX_ITER):
        if fit is None:
            fit = fit_lines(x[None, :], mask, dt, lines.period_s, lines.harmonics, offsets)
        if float(fit.residual_power()[0]) <= REFINE_SKIP * xvar:
            break
        if t is None:
            grid = np.arange(n) * dt + (0.0 if offsets is None else offsets)
            # centred: the derivative then lies outside the lines' span
            t = np.asarray(grid - float(grid[mask].mean()), dtype=np.float64)
            del grid
        g = np.where(mask, -(t / lines.period_s) * _derivative(fit, n, dt, lines, mask, offsets),
                     0.0)
        gg = dot(g, g)
        if not gg > 0.0:
            break
        step = dot(fit.residual[0], g) / gg
        turn = 2.0 * np.pi * float(lines.freq.max()) * span * abs(step) / lines.period_s
        if turn < PERIOD_PHASE_TOL * 1e-3:
            break
        lines = dataclasses.replace(lines, period_s=lines.period_s + step)
        changed = True
        fit = None
        if turn < PERIOD_PHASE_TOL:  # converged: the last (small) step taken, no more fits
            break
    return lines, changed
