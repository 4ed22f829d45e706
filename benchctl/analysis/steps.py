"""The traditional linearity table from sine steps: gain and phase of the instrument at each
step of a ``sine_steps`` profile, with 95 % intervals, and a linearity verdict.

A ``sine_steps`` profile plays single sines one after the other (periods × amplitudes), each
faded in and out, with rests between. Only the step's **whole cycles at full amplitude** are
used (fades and rests excluded): the window ``[start, start + n·T]`` of each step, on the
analysis clock (the profile's time plus the motion's start, :func:`step_windows`).

For each step and each signal — the reference (the measured stand angle, at its own instants)
and the instrument (at its own instants) — a least-squares fit on the samples actually present
(gaps and non-uniform instants need no interpolation)::

    v(t) ≈ a + b·τ/T_w + Re(C·e^{j2πfτ}) + Σ_j Re(N_j·e^{j2π f_j τ}),   τ = t − t_mid

with ``f = 1/T`` the step's frequency, ``T_w = n·T`` the window, and ``f_j = k_j/T_w`` the
``NOISE_BINS`` DFT frequencies of the window nearest to ``f`` (``k_j ≥ 1``, not a multiple of
``n``: harmonics of the sine, where a distortion would sit, are left out). The step needs at
least ``MIN_CYCLES`` whole cycles. The trend takes out a drift; the ``N_j`` are pure noise, so
they measure the noise level *near f* (coloured noise is allowed, as long as its density is
about flat over those frequencies): with ``D = (AᵀA)⁻¹``,
``σ̂² = mean_j (Re²N_j/D_bb + Im²N_j/D_cc)/2`` (2 degrees of freedom per frequency, ``ν = 2J``)
and the covariance of ``(Re C, Im C)`` is ``σ̂²·D_CC`` (exact for white Gaussian noise).

``H = C_y/C_x``; gain ``|H|``, phase ``arg H`` (deg, negative = the instrument lags). The
intervals by the delta method (first order: the coefficients' standard deviations small against
their magnitude, as on a stand): ``var(ln|H|) = r_y/|C_y|² + r_x/|C_x|²`` with ``r`` the radial
variance of each ``C``, ``var(arg H) = q_y/|C_y|² + q_x/|C_x|²`` with ``q`` the tangential one;
each 95 % interval ``± t_{0.975,ν}·sd`` with ``ν`` from the two noise estimates by
Satterthwaite. The gain interval is ``|H|·(1 ± t·sd(ln|H|))``.

**Linearity verdict**: the spread of the gains over the axis's steps, ``max − min``, against a
limit (``run.linearity_spread_limit``): PASS when ``spread ≤ limit``. A step that cannot be
estimated (too few samples in its window) is listed with ``None`` and a note; with no step
estimated the verdict is FAIL.

Pure computation on arrays (and the profile's step schedule); no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.special import stdtrit

from benchctl.analysis.frf import TRADITIONAL_PERIODS_S, not_excited
from benchctl.errors import BenchError, DataError
from benchctl.outcomes import Outcome
from benchctl.profiles import parse_profile, synthesize

FloatArray = NDArray[np.float64]

NOISE_BINS = 8  # DFT frequencies of the window, nearest to the step's, behind its noise level
MIN_CYCLES = 2  # whole cycles at full amplitude a step needs (its noise frequencies)
MIN_SAMPLES = 32  # at least this many samples per signal and step, and 3 × the parameters
COND_MAX = 1e8  # the fit's design matrix must be better conditioned than this
LINEARITY_SPREAD_LIMIT = 0.01  # default limit of max − min gain (the paper's 0.990 … 0.998)


@dataclass(frozen=True)
class StepWindow:
    """The whole full-amplitude cycles of one step, on the analysis clock (s)."""

    axis: str
    period_s: float
    amplitude_deg: float
    start_s: float
    cycles: int

    @property
    def end_s(self) -> float:
        return self.start_s + self.cycles * self.period_s


def step_windows(motion: Any, axis: str, t0: float = 0.0) -> list[StepWindow]:
    """The windows of ``axis``'s steps of a ``StepMotion`` (its ``segments``), profile time 0
    at ``t0`` on the analysis clock. Each segment is ``fade_in + n·T + fade_out`` long; the
    window is its ``n`` whole cycles between the fades."""
    out = []
    for seg in getattr(motion, "segments", ()):
        if seg.axis != axis:
            continue
        tab = seg.table
        period = float(seg.period_s)
        steady = float(tab.duration_s) - float(tab.fade_in_s) - float(tab.fade_out_s)
        cycles = math.floor(steady / period + 1e-9)
        out.append(StepWindow(axis, period, float(seg.amplitude_deg),
                              t0 + float(seg.start_s) + float(tab.fade_in_s), cycles))
    return out


def step_windows_from_recording(
    meta: dict[str, Any], axis: str, t0: float | None
) -> tuple[list[StepWindow] | None, str | None]:
    """Re-synthesise a recording's ``sine_steps`` profile (``meta['profile']``, scaled by
    ``meta['scale']`` when the run scaled it to fit) and place its steps at the motion's start
    ``t0``: ``(windows, None)``, or ``(None, reason)`` — ``reason`` None when the profile is
    simply not a sine_steps one."""
    prof = meta.get("profile")
    if not isinstance(prof, dict) or not isinstance(prof.get("spec"), dict):
        return None, None
    if prof["spec"].get("kind") != "sine_steps":
        return None, None
    try:
        motion = synthesize(parse_profile(prof["spec"], prof.get("source")))
        scale = meta.get("scale")
        if isinstance(scale, int | float) and scale != 1.0:
            motion = motion.scaled(float(scale))
    except (BenchError, OSError, ValueError, TypeError) as e:
        return None, f"no step table: the profile could not be re-synthesised ({e})"
    if t0 is None:
        return None, "no step table: the recording has no motion_start event"
    wins = step_windows(motion, axis, t0)
    if not wins:
        return None, None
    return wins, None


# ------------------------------------------------------------------------------ the fit
@dataclass(frozen=True)
class SineFit:
    """One signal's fit over one window: ``coef`` the complex amplitude C at the step's
    frequency (``Re(C·e^{j2πfτ})``), ``cov`` the covariance of ``(Re C, Im C)``, ``noise``
    σ̂² (the white-equivalent noise variance per sample near f), ``dof`` its degrees of
    freedom, ``n`` the samples used."""

    coef: complex
    cov: FloatArray
    noise: float
    dof: float
    n: int

    @property
    def radial_var(self) -> float:
        u = np.array([self.coef.real, self.coef.imag]) / abs(self.coef)
        return float(u @ self.cov @ u)

    @property
    def tangential_var(self) -> float:
        v = np.array([-self.coef.imag, self.coef.real]) / abs(self.coef)
        return float(v @ self.cov @ v)


def noise_harmonics(cycles: int, count: int = NOISE_BINS) -> list[int]:
    """The ``count`` DFT bins ``k ≥ 1`` of a window of ``cycles`` whole cycles nearest to the
    step's bin ``cycles``, leaving out its multiples (the sine's harmonics)."""
    ks = [k for k in range(1, cycles + 3 * count + 2) if k % cycles != 0]
    ks.sort(key=lambda k: (abs(k - cycles), k))
    return sorted(ks[:count])


def fit_sine(t: ArrayLike, v: ArrayLike, window: StepWindow) -> tuple[SineFit | None, str]:
    """Least-squares fit of one signal over ``window`` (see the module's notes): the fit, or
    ``(None, why)`` when the window holds too few samples or the fit is ill-conditioned."""
    tt = np.asarray(t, dtype=float)
    vv = np.asarray(v, dtype=float)
    lo, hi = window.start_s, window.end_s
    sel = (tt >= lo) & (tt <= hi) & np.isfinite(vv)
    ts, vs = tt[sel], vv[sel]
    if window.cycles < MIN_CYCLES:
        return None, (f"{window.cycles} whole cycle(s) at full amplitude, at least "
                      f"{MIN_CYCLES} needed")
    ks = noise_harmonics(window.cycles)
    n = ts.size
    if n >= 2:
        nyquist = 0.5 / float(np.median(np.diff(ts)))
        ks = [k for k in ks if k / (hi - lo) < nyquist]
    p = 4 + 2 * len(ks)
    if n < max(MIN_SAMPLES, 3 * p) or len(ks) < 2:
        return None, f"{n} samples in the window, at least {max(MIN_SAMPLES, 3 * p)} needed"
    tm = 0.5 * (lo + hi)
    tau = ts - tm
    span = hi - lo
    w0 = 2.0 * math.pi / window.period_s
    cols = [np.ones(n), tau / span, np.cos(w0 * tau), np.sin(w0 * tau)]
    for k in ks:
        w = 2.0 * math.pi * k / span
        cols += [np.cos(w * tau), np.sin(w * tau)]
    a = np.column_stack(cols)
    q, r = np.linalg.qr(a)
    d = np.abs(np.diag(r))
    if d.min() <= d.max() / COND_MAX:
        return None, "the samples in the window do not determine the fit (gaps)"
    beta = np.linalg.solve(r, q.T @ vs)
    rinv = np.linalg.solve(r, np.eye(p))
    dmat = rinv @ rinv.T  # (AᵀA)⁻¹
    parts = []
    for j in range(len(ks)):
        i = 4 + 2 * j
        parts.append(beta[i] ** 2 / dmat[i, i] + beta[i + 1] ** 2 / dmat[i + 1, i + 1])
    noise = float(np.mean(parts)) / 2.0
    # v ≈ b cos + c sin = Re((b − jc) e^{jωτ})
    b, c = float(beta[2]), float(beta[3])
    coef = complex(b, -c)
    flip = np.array([[1.0, 0.0], [0.0, -1.0]])
    cov = noise * (flip @ dmat[2:4, 2:4] @ flip)
    return SineFit(coef, cov, noise, 2.0 * len(ks), n), ""


# ------------------------------------------------------------------------------ the steps
@dataclass
class StepEstimate:
    """One row of the table: the step and the instrument's gain and phase at its frequency."""

    window: StepWindow
    gain: float | None = None
    gain_ci95: tuple[float, float] | None = None
    phase_deg: float | None = None
    phase_ci95_deg: tuple[float, float] | None = None
    reference_amplitude_deg: float | None = None
    dof: float | None = None
    n_reference: int = 0
    n_device: int = 0
    note: str = ""

    def to_dict(self) -> dict[str, Any]:
        w = self.window
        return {
            "period_s": w.period_s,
            "amplitude_deg": w.amplitude_deg,
            "start_s": w.start_s,
            "end_s": w.end_s,
            "cycles": w.cycles,
            "gain": self.gain,
            "gain_ci95": None if self.gain_ci95 is None else list(self.gain_ci95),
            "phase_deg": self.phase_deg,
            "phase_ci95_deg": None if self.phase_ci95_deg is None else list(self.phase_ci95_deg),
            "reference_amplitude_deg": self.reference_amplitude_deg,
            "dof": self.dof,
            "n_reference": self.n_reference,
            "n_device": self.n_device,
            "note": self.note or None,
        }


def _satterthwaite(a: float, na: float, b: float, nb: float) -> float:
    den = (a * a / na if a > 0 else 0.0) + (b * b / nb if b > 0 else 0.0)
    return (a + b) ** 2 / den if den > 0 else math.inf


def estimate_step(
    t_ref: ArrayLike, x_ref: ArrayLike, t_dev: ArrayLike, y_dev: ArrayLike, window: StepWindow
) -> StepEstimate:
    """Gain and phase of the instrument against the reference over one step's window."""
    fx, why_x = fit_sine(t_ref, x_ref, window)
    fy, why_y = fit_sine(t_dev, y_dev, window)
    est = StepEstimate(window, n_reference=0 if fx is None else fx.n,
                       n_device=0 if fy is None else fy.n)
    if fx is None or fy is None:
        est.note = f"reference: {why_x}" if fx is None else f"instrument: {why_y}"
        return est
    if fx.coef == 0 or fy.coef == 0:
        est.note = "no motion at the step's frequency"
        return est
    h = fy.coef / fx.coef
    gain = abs(h)
    phase = math.degrees(math.atan2(h.imag, h.real))
    ax, ay = abs(fx.coef) ** 2, abs(fy.coef) ** 2
    gx, gy = fx.radial_var / ax, fy.radial_var / ay
    px, py = fx.tangential_var / ax, fy.tangential_var / ay
    nu_g = _satterthwaite(gx, fx.dof, gy, fy.dof)
    nu_p = _satterthwaite(px, fx.dof, py, fy.dof)
    tg = float(stdtrit(nu_g, 0.975)) if math.isfinite(nu_g) else 1.959963984540054
    tp = float(stdtrit(nu_p, 0.975)) if math.isfinite(nu_p) else 1.959963984540054
    dg = tg * math.sqrt(gx + gy)
    dp = math.degrees(tp * math.sqrt(px + py))
    est.gain = gain
    est.gain_ci95 = (gain * (1.0 - dg), gain * (1.0 + dg))
    est.phase_deg = phase
    est.phase_ci95_deg = (phase - dp, phase + dp)
    est.reference_amplitude_deg = abs(fx.coef)
    est.dof = nu_g
    return est


@dataclass
class StepsAnalysis:
    """The linearity table of one axis and its verdict (``spread = max − min`` of the gains
    of the estimated steps; PASS when ``spread ≤ limit``)."""

    steps: list[StepEstimate]
    limit: float
    warnings: list[str] = field(default_factory=list)

    def periods(self, periods_s: tuple[float, ...]) -> list[dict[str, Any]]:
        """Gain and phase at the traditional periods from the table: a period that was stepped
        takes its largest-amplitude step's estimate (the least noise), ``source`` ``steps``;
        one that was not is not excited — never a number from the frequency response of a
        sequence that never moved at that period."""
        out: list[dict[str, Any]] = []
        for period in periods_s:
            rows = [s for s in self.steps if s.gain is not None
                    and abs(s.window.period_s - period) <= 1e-6 * period]
            if not rows:
                out.append(not_excited(period))
                continue
            best = max(rows, key=lambda s: s.window.amplitude_deg)
            out.append({
                "period_s": period,
                "freq": 1.0 / period,
                "excited": True,
                "gain": best.gain,
                "gain_ci95": None if best.gain_ci95 is None else list(best.gain_ci95),
                "phase_deg": best.phase_deg,
                "phase_ci95_deg": (None if best.phase_ci95_deg is None
                                   else list(best.phase_ci95_deg)),
                "coherence": None,
                "source": "steps",
                "amplitude_deg": best.window.amplitude_deg,
            })
        return out

    @property
    def gains(self) -> list[float]:
        return [s.gain for s in self.steps if s.gain is not None]

    @property
    def spread(self) -> float | None:
        g = self.gains
        return max(g) - min(g) if g else None

    @property
    def amplitude_spread(self) -> float | None:
        """The largest spread of the gains over the amplitudes at one period (information:
        the dependence on amplitude alone, the instrument's dynamics taken out)."""
        by: dict[float, list[float]] = {}
        for s in self.steps:
            if s.gain is not None:
                by.setdefault(s.window.period_s, []).append(s.gain)
        spreads = [max(g) - min(g) for g in by.values() if len(g) > 1]
        return max(spreads) if spreads else None

    @property
    def passed(self) -> bool:
        s = self.spread
        return s is not None and s <= self.limit

    @property
    def verdict(self) -> Outcome:
        return Outcome.PASS if self.passed else Outcome.FAIL

    def to_dict(self) -> dict[str, Any]:
        g = self.gains
        return {
            "steps": [s.to_dict() for s in self.steps],
            "linearity": {
                "spread": self.spread,
                "gain_min": min(g) if g else None,
                "gain_max": max(g) if g else None,
                "amplitude_spread": self.amplitude_spread,
                "limit": self.limit,
                "verdict": self.verdict,
                "measure": "max - min gain over the steps",
            },
        }


def analyze_steps(
    t_ref: ArrayLike,
    x_ref: ArrayLike,
    t_dev: ArrayLike,
    y_dev: ArrayLike,
    windows: list[StepWindow],
    *,
    spread_limit: float = LINEARITY_SPREAD_LIMIT,
) -> StepsAnalysis:
    """The table (one :class:`StepEstimate` per window, in the profile's order) and the
    linearity verdict against ``spread_limit`` (max − min gain)."""
    if not (math.isfinite(spread_limit) and spread_limit > 0):
        raise DataError(
            f"linearity spread limit = {spread_limit!r}: expected a positive finite number"
        )
    tr = np.asarray(t_ref, dtype=float)
    xr = np.asarray(x_ref, dtype=float)
    td = np.asarray(t_dev, dtype=float)
    yd = np.asarray(y_dev, dtype=float)
    steps = [estimate_step(tr, xr, td, yd, w) for w in windows]
    out = StepsAnalysis(steps, float(spread_limit))
    for s in steps:
        if s.note:
            out.warnings.append(
                f"sine step {s.window.period_s:g} s × {s.window.amplitude_deg:g}°: no estimate "
                f"({s.note})"
            )
    if not out.gains:
        out.warnings.append("no sine step could be estimated: linearity FAIL")
    return out


# ------------------------------------------------------------------------------ recordings
def motion_start(events: list[dict[str, Any]]) -> float | None:
    """The motion's start (host monotonic s) from a recording's events (``motion_start``)."""
    for ev in events:
        if ev.get("kind") == "motion_start" and isinstance(ev.get("t_host"), int | float):
            return float(ev["t_host"])
    return None


def spread_limit_of(meta: dict[str, Any]) -> float:
    """``run.linearity_spread_limit`` of the bench config a recording holds (its metadata's
    ``config``), else the default ``LINEARITY_SPREAD_LIMIT``."""
    cfg = meta.get("config")
    run = cfg.get("run") if isinstance(cfg, dict) else None
    v = run.get("linearity_spread_limit") if isinstance(run, dict) else None
    if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v > 0:
        return float(v)
    return LINEARITY_SPREAD_LIMIT


def steps_for_recording(
    meta: dict[str, Any],
    events: list[dict[str, Any]],
    axis: str,
    t_ref: ArrayLike,
    x_ref: ArrayLike,
    t_dev: ArrayLike,
    y_dev: ArrayLike,
) -> tuple[StepsAnalysis | None, str | None]:
    """The linearity table of one axis of a recording (metadata and events already read):
    ``(None, None)`` when its profile is not sine_steps, ``(None, reason)`` when the table
    cannot be made."""
    wins, why = step_windows_from_recording(meta, axis, motion_start(events))
    if wins is None:
        return None, why
    return analyze_steps(t_ref, x_ref, t_dev, y_dev, wins, spread_limit=spread_limit_of(meta)), None


def _f(v: float | None, spec: str) -> str:
    return "—" if v is None else format(v, spec)


def format_steps(sa: StepsAnalysis, indent: str = "  ") -> list[str]:
    """The table as text, as the paper gives it (period × amplitude: gain and phase with their
    95 % intervals), then the linearity verdict."""
    out = [f"{indent}sine steps (whole cycles at full amplitude; 95 % intervals):",
           f"{indent}  period  ampl.   gain    95 % CI            phase     95 % CI"]
    for s in sa.steps:
        w = s.window
        if s.gain is None or s.gain_ci95 is None or s.phase_ci95_deg is None:
            out.append(f"{indent}  {w.period_s:4.3g} s  {w.amplitude_deg:4.3g}°  no estimate: "
                       f"{s.note}")
            continue
        out.append(
            f"{indent}  {w.period_s:4.3g} s  {w.amplitude_deg:4.3g}°  {s.gain:.4f}  "
            f"[{s.gain_ci95[0]:.4f}, {s.gain_ci95[1]:.4f}]  {_f(s.phase_deg, '7.2f')}°  "
            f"[{s.phase_ci95_deg[0]:.2f}, {s.phase_ci95_deg[1]:.2f}]°"
        )
    g = sa.gains
    rng = f"gain {min(g):.4f} … {max(g):.4f}, " if g else ""
    out.append(
        f"{indent}linearity: {rng}spread (max − min) {_f(sa.spread, '.4f')} vs limit "
        f"{sa.limit:g} → {sa.verdict}"
        + (f"   (largest over amplitudes at one period {sa.amplitude_spread:.4f})"
           if sa.amplitude_spread is not None else "")
    )
    return out


def attach_steps(result: Any, sa: StepsAnalysis) -> None:
    """Put the linearity table on an analysis result (``steps``) and take its gain and phase
    at the traditional periods from it (``periods``): a sine-steps run is measured there."""
    result.steps = sa
    result.periods = sa.periods(TRADITIONAL_PERIODS_S)
