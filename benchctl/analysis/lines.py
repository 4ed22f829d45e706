"""The excited lines of a periodic multisine: what a line set is and where it comes from.

A :class:`LineSet` is the lines ``f_k = k/T_p`` a record is analysed at (the line-wise
estimate, :mod:`benchctl.analysis.linewise`): re-synthesised from a recording's profile
(:func:`line_set_from_recording`, :func:`line_set_from_tables`), or found in the reference
(:func:`detect_period` over its whole periods, :func:`reference_lines`); and whether a record
holds whole periods of it (:func:`whole_periods`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.fft import fft, ifft, irfft, next_fast_len, rfft

from benchctl.errors import BenchError

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
IntArray = NDArray[np.int64]

NOISE_BINS = 8  # unexcited DFT bins behind one line's noise estimate …
NOISE_REACH = 16  # … found within ± this many bins of the line
LPM_LINES = 15  # neighbours of a line in its local-polynomial window (degree LPM_DEGREE)
LPM_DEGREE = 2
WHOLE_PERIODS_TOL = 0.05  # cycles a line (and the period) may miss being whole over the record
DETECT_OFF_GRID = 0.01  # detection: at most this share of the reference's power off the grid …
DETECT_MIN_LINE = 1e-6  # … and a line holds at least this share of the strongest one …
DETECT_FLOOR = 100.0  # … and this many times the median power of the off-grid bins
PERIOD_PHASE_TOL = 1e-6  # period refinement: stop when the highest line turns less (rad)
REFINE_MAX_ITER = 6
REFINE_SKIP = 1e-14  # no refinement when the lines leave less of the reference's variance
CG_TOL = 1e-13
CG_MAX_ITER = 200
TAYLOR_TOL = 1e-10  # the instants' offsets from the grid: expansion remainder |ωδ|^(P+1)/(P+1)!
TAYLOR_MAX_ORDER = 12


class LinesError(ValueError):
    """The line-wise estimate cannot be made (the reason is the message)."""


@dataclass(frozen=True)
class LineSet:
    """Excited lines ``f_k = harmonics_k / period_s`` and where they come from.

    ``source``: ``"profile"`` (re-synthesised from a recording's profile), ``"period"`` (given
    period, lines found in the reference) or ``"detected"`` (period and lines found in the
    reference). ``odd``: an odd multisine (its unexcited odd and even harmonics show
    nonlinear distortion, :mod:`benchctl.analysis.distortion`): from the profile's
    ``multisine`` option, or for lines found in the reference when there are at least
    two and all are odd. ``others``: the harmonics (of the same period) excited on the
    profile's other axes, never counted as unexcited.
    """

    period_s: float
    harmonics: IntArray
    source: str
    odd: bool = False
    others: IntArray | None = None

    @property
    def all_excited(self) -> IntArray:
        """The harmonics excited on any axis."""
        if self.others is None or self.others.size == 0:
            return self.harmonics
        return np.asarray(np.union1d(self.harmonics, self.others), dtype=np.int64)

    @property
    def is_odd_multisine(self) -> bool:
        if self.odd:
            return True
        h = self.harmonics
        return self.source != "profile" and h.size >= 2 and bool(np.all(h % 2 == 1))

    @property
    def freq(self) -> FloatArray:
        return np.asarray(self.harmonics / self.period_s, dtype=float)


# ----------------------------------------------------------------------------------- sums
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

    @property
    def residual(self) -> FloatArray:
        if self._residual is None:
            self._residual = np.asarray(irfft(self.spectrum, self.n, axis=-1), dtype=float)
        return self._residual

    def residual_power(self) -> FloatArray:
        """``Σ_s r_s²`` of each channel (Parseval on the spectrum)."""
        a = self.spectrum.real**2 + self.spectrum.imag**2
        total = 2.0 * a.sum(axis=-1) - a[..., 0]
        if self.n % 2 == 0:
            total = total - a[..., -1]
        return np.asarray(total / self.n, dtype=float)


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
        resid_spec = spec.copy()
        resid_spec[..., 0] = 0.0
        resid_spec[..., bins] = 0.0
        return LineFit(coef, mean, resid_spec, True, 0, n)
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


# ------------------------------------------------------------------------ finding the lines
def periodogram(values: FloatArray, mask: NDArray[np.bool_]) -> FloatArray:
    """``|X_j|²`` of the zero-filled, demeaned series, j = 0 … N/2 (DC set to 0)."""
    v = np.where(mask, values, 0.0)
    v = np.where(mask, v - v.sum() / max(1, int(mask.sum())), 0.0)
    spec = rfft(v)
    p = spec.real**2 + spec.imag**2
    p[0] = 0.0
    return np.asarray(p, dtype=float)


def detect_period(
    x: FloatArray, mask: NDArray[np.bool_], power: FloatArray | None = None
) -> int | None:
    """The number n ≥ 2 of whole periods of the reference in the record, or None.

    A reference periodic in ``T = N·Δt/n`` has its spectrum over the record (DFT bins
    ``j/(NΔt)``) on the bins ``j ≡ 0 (mod n)`` only. The candidates are the divisors of the
    strongest bin; the largest n whose off-grid bins hold at most ``DETECT_OFF_GRID`` of the
    power (plus twice the share the gaps' own spectrum puts off the grid) is the period.
    One period per record (n = 1) cannot be told from a non-periodic reference: state it
    with ``period_s``. ``power``: :func:`periodogram` of x, if already computed.
    """
    p = periodogram(x, mask) if power is None else power
    total = float(p[1:].sum())
    if not total > 0.0:
        return None
    j_max = int(np.argmax(p))
    mp = None
    if not bool(mask.all()):
        ms = rfft(mask.astype(float))
        mp = ms.real**2 + ms.imag**2
        mp_total = float(mp.sum())
    best = None
    for cand in range(2, j_max + 1):
        if j_max % cand:
            continue
        off = 1.0 - float(p[::cand].sum()) / total  # p[0] = 0: the DC bin holds nothing
        allowed = DETECT_OFF_GRID
        if mp is not None:
            allowed += 2.0 * (1.0 - float(mp[::cand].sum()) / mp_total)
        if off <= allowed:
            best = cand
    return best


def reference_lines(
    x: FloatArray, mask: NDArray[np.bool_], n_periods: int, power: FloatArray | None = None
) -> IntArray:
    """Harmonics k of ``T_p = N·Δt/n`` where the reference is excited: bin ``n·k`` holds at
    least ``DETECT_MIN_LINE`` of the strongest bin's power and ``DETECT_FLOOR`` times the
    median power of the off-grid bins (of the upper half of the spectrum when n = 1).
    ``power``: :func:`periodogram` of x, if already computed."""
    p = periodogram(x, mask) if power is None else power
    j = np.arange(len(p))
    on = (j % n_periods == 0) & (j > 0) & (2 * j < 2 * (len(p) - 1))
    floor_bins = p[(j % n_periods != 0)] if n_periods > 1 else p[len(p) // 2 :]
    floor = float(np.median(floor_bins)) if floor_bins.size else 0.0
    strongest = float(p[on].max()) if on.any() else 0.0
    keep = on & (p >= DETECT_MIN_LINE * strongest) & (p > DETECT_FLOOR * floor) & (p > 0)
    return np.asarray(j[keep] // n_periods, dtype=np.int64)


def _table_harmonics(table: Any, period: float) -> IntArray | None:
    freq = np.asarray(table.freq_hz, dtype=float)
    freq = freq[np.asarray(table.amp_deg, dtype=float) > 0]
    k = freq * period
    ki = np.rint(k).astype(np.int64)
    if freq.size == 0 or np.any(np.abs(k - ki) > WHOLE_PERIODS_TOL) or ki.min() < 1:
        return None
    return np.unique(ki)


def line_set_from_tables(
    table: Any, window_s: float | None, others: Sequence[Any] = ()
) -> tuple[LineSet | None, str | None]:
    """The line set of one axis's ``HarmonicTable`` (freq_hz, amp_deg, period_s), or
    ``(None, reason)``. Without a period, the analysis window is the period (its lines must
    make whole cycles in it). ``others``: the tables of the profile's other axes (their lines
    go into ``LineSet.others``); the table's ``meta["multisine"]`` (an odd multisine) sets
    ``LineSet.odd``."""
    amp = np.asarray(table.amp_deg, dtype=float)
    if not np.any(amp > 0):
        return None, "the profile's table has no line"
    period = table.period_s if table.period_s else window_s
    if not period:
        return None, "the profile's lines have no repetition period"
    ki = _table_harmonics(table, period)
    if ki is None:
        return None, f"the profile's lines are not whole harmonics of {period:g} s"
    rest = [h for h in (_table_harmonics(t, period) for t in others) if h is not None]
    other = np.unique(np.concatenate(rest)).astype(np.int64) if rest else None
    meta = getattr(table, "meta", None) or {}
    ms = meta.get("multisine") if isinstance(meta, dict) else None
    odd = isinstance(ms, dict) and bool(ms.get("odd"))
    return LineSet(float(period), ki, "profile", odd, other), None


def line_set_from_recording(
    meta: dict[str, Any], axis: str, window: tuple[float, float] | None
) -> tuple[LineSet | None, str | None]:
    """Re-synthesise the lines of ``axis`` from a recording's metadata (``profile``, ``seed``,
    ``duration_s``): ``(LineSet, None)``, or ``(None, reason)`` when it cannot be done."""
    # imported here: the profile schema (pydantic) costs `benchctl analyze` of a CSV, which
    # never needs it, about 0.6 s of its 2.4 s (python -X importtime)
    from benchctl.profiles import parse_profile, synthesize

    prof = meta.get("profile")
    if not isinstance(prof, dict) or not isinstance(prof.get("spec"), dict):
        return None, "the recording holds no profile"
    try:
        profile = parse_profile(prof["spec"], prof.get("source"))
        seed = meta.get("seed")
        duration = meta.get("duration_s")
        motion = synthesize(
            profile,
            duration_s=float(duration) if isinstance(duration, int | float) else None,
            seed=int(seed) if isinstance(seed, int) else None,
        )
    except (BenchError, OSError, ValueError, TypeError) as e:
        return None, f"its profile could not be re-synthesised ({e})"
    tables = motion.tables
    if not tables or axis not in tables:
        return None, f"the profile gives no harmonic table for {axis}"
    span = None if window is None else window[1] - window[0]
    others = [t for a, t in tables.items() if a != axis]
    return line_set_from_tables(tables[axis], span, others)


# ------------------------------------------------------------------------ noise at the lines
@dataclass(frozen=True)
class _Noise:
    power: FloatArray  # s_k: variance a line picks up from the noise, deg²
    dof: FloatArray  # real degrees of freedom of each estimate
    lpm: NDArray[np.bool_]  # True where from the local polynomial method
    var_sum: float  # variance of Σ_k s_k (estimation error)


def _nearest_offsets(reach: int) -> IntArray:
    o = np.arange(-reach, reach + 1)
    return np.asarray(o[np.lexsort((o, np.abs(o)))], dtype=np.int64)  # 0, −1, 1, −2, 2 …


def _line_noise(
    e: ComplexArray, cx: ComplexArray, freq: FloatArray, bins: IntArray, u: FloatArray,
    probe: NDArray[np.bool_],
) -> _Noise:
    """Noise power at each line (see module notes, step 2). ``u``: the residual's periodogram
    in line units (``2|R_j|²/N_v²``); ``probe``: the bins that are neither DC, Nyquist nor a
    line."""
    kk = len(e)
    nb = len(u)
    off = _nearest_offsets(NOISE_REACH)
    idx = bins[:, None] + off[None, :]
    inside = (idx >= 0) & (idx < nb)
    ok = inside & probe[np.clip(idx, 0, nb - 1)]
    rank = np.cumsum(ok, axis=1)
    take = ok & (rank <= NOISE_BINS)
    enough = rank[:, -1] >= NOISE_BINS
    power = np.zeros(kk)
    dof = np.zeros(kk)
    weight = np.zeros(nb)
    if enough.any():
        vals = np.where(take, u[np.clip(idx, 0, nb - 1)], 0.0)
        power[enough] = vals[enough].sum(axis=1) / NOISE_BINS
        dof[enough] = 2.0 * NOISE_BINS
        np.add.at(weight, np.clip(idx, 0, nb - 1)[enough][take[enough]], 1.0 / NOISE_BINS)
    var_sum = float(np.sum(weight**2 * u**2 / 2.0))
    lpm = ~enough
    if lpm.any():
        size = LPM_LINES + 1  # the line itself and LPM_LINES neighbours
        if kk < size:
            raise LinesError(
                f"too few lines ({kk}) and unexcited bins to estimate the noise at the lines"
            )
        pos = np.flatnonzero(lpm)
        start = np.clip(pos - size // 2, 0, kk - size)
        win = start[:, None] + np.arange(size)[None, :]
        use = (win != pos[:, None]).astype(float)  # leave the line out: its noise estimate is
        d = freq[win] - freq[pos][:, None]  # then independent of its own noise (Student t)
        d = d / np.maximum(np.abs(d).max(axis=1, keepdims=True), 1e-300)
        phi = cx[win][:, :, None] * d[:, :, None] ** np.arange(LPM_DEGREE + 1)[None, None, :]
        phi = phi * use[:, :, None]
        rhs = e[win] * use
        gram = np.einsum("kjp,kjq->kpq", phi.conj(), phi)
        proj = np.einsum("kjp,kj->kp", phi.conj(), rhs)
        theta = np.linalg.solve(gram, proj[:, :, None])[:, :, 0]
        res = rhs - np.einsum("kjp,kp->kj", phi, theta)
        free = LPM_LINES - (LPM_DEGREE + 1)
        power[pos] = np.sum(np.abs(res) ** 2, axis=1) / (2.0 * free)
        dof[pos] = 2.0 * free
        w = np.zeros(kk)
        np.add.at(w, win.ravel(), use.ravel() / free)
        var_sum += float(np.sum(w**2 * power**2))
    return _Noise(power, dof, lpm, var_sum)


def whole_periods(n_slots: int, dt: float, lines: LineSet) -> int:
    """The number of whole periods ``T_p`` the record of ``n_slots·dt`` holds, or raise
    ``LinesError`` when it does not hold whole periods (within ``WHOLE_PERIODS_TOL`` of a
    cycle of the period and of every line)."""
    span = n_slots * dt
    nf = span / lines.period_s
    n = round(nf)
    cyc = lines.freq * span
    if n < 1 or abs(nf - n) > WHOLE_PERIODS_TOL or np.any(
        np.abs(cyc - np.rint(cyc)) > WHOLE_PERIODS_TOL
    ):
        raise LinesError(
            f"the record ({span:.6g} s) does not hold whole periods of {lines.period_s:.6g} s "
            f"({nf:.4g} periods)"
        )
    if 2 * int(np.rint(lines.freq.max() * span)) >= n_slots:
        raise LinesError("a line lies at or above the Nyquist frequency of the record")
    return n


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
) -> tuple[LineSet, bool]:
    """The line set with its period fitted to the reference (Gauss–Newton on T_p, the lines
    refitted at each step): a stand playing on its own clock, or a period detected from a
    grid step fitted to jittered stamps, is some ppm off the nominal period, and over a long
    record that would leave part of every line in the residual. Stops once a step turns the
    highest line by less than ``PERIOD_PHASE_TOL`` over the record (that last step is
    taken), or at once when the lines leave less than ``REFINE_SKIP`` of the reference's
    variance in the residual. ``fit``: a fit at ``lines`` whose first row is x, if made.
    Returns the line set and whether its period changed.
    """
    n = len(mask)
    span = n * dt
    xd = np.where(mask, x - float(x[mask].mean()), 0.0)
    xvar = float(np.dot(xd, xd))
    t = np.arange(n) * dt + (0.0 if offsets is None else offsets)
    t = t - float(t[mask].mean())  # centred: the derivative then lies outside the lines' span
    changed = False
    for _ in range(REFINE_MAX_ITER):
        if fit is None:
            fit = fit_lines(x[None, :], mask, dt, lines.period_s, lines.harmonics, offsets)
        if float(fit.residual_power()[0]) <= REFINE_SKIP * xvar:
            break
        g = np.where(mask, -(t / lines.period_s) * _derivative(fit, n, dt, lines, mask, offsets),
                     0.0)
        gg = float(np.dot(g, g))
        if not gg > 0.0:
            break
        step = float(np.dot(fit.residual[0], g)) / gg
        turn = 2.0 * np.pi * float(lines.freq.max()) * span * abs(step) / lines.period_s
        if turn < PERIOD_PHASE_TOL * 1e-3:
            break
        lines = dataclasses.replace(lines, period_s=lines.period_s + step)
        changed = True
        fit = None
        if turn < PERIOD_PHASE_TOL:  # converged: the last (small) step taken, no more fits
            break
    return lines, changed

