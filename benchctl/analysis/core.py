"""The analysis: from two angle streams to σ, its interval, the error PSD and H(f).

Pure computation on arrays (no I/O). The steps follow Gryazin & Belova (2023), see
``docs/method.md``: align (``align``), correlations R_x, R_y, R_xy, R_yx and eq. 2
(``correlation``), the error density by eq. 1 (``psd``), σ = √(area); then the cross-checks,
the frequency response, the decomposition and the interval.

Max-lag rule (``spectra``): ``L = ⌊N/10⌋`` samples of the analysis grid (N = grid length,
gaps included), at least 8; ``max_lag_s`` overrides it (rounded to samples, at most N/2).

When the record holds whole periods of a known line set (given, from ``period_s``, or
detected in the reference; which, and over which periods: ``linechoice``) the line-wise
estimate (``linewise``) gives H at the lines with intervals, the unbiased linear/incoherent
split and the interval of σ; the published σ (eqs. 1–2) stays the headline.

Departures (``departures``): the intervals where the stand's motion was not the profile's
are left out as gaps are, on whole periods when the record holds them (``exclusion``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from benchctl.analysis import frf as frf_mod
from benchctl.analysis.align import Aligned, align
from benchctl.analysis.budget import Reference, uncertainty_budget
from benchctl.analysis.correlation import demean
from benchctl.analysis.departures import Departures
from benchctl.analysis.exclusion import Exclusion, exclude, exclusion_warnings
from benchctl.analysis.linechoice import known_period, line_analysis
from benchctl.analysis.lineperiods import periods_from_lines
from benchctl.analysis.lines import LineSet, LinesMode
from benchctl.analysis.psd import WelchEstimate, band_area, trapezoid_area, welch_by_runs
from benchctl.analysis.result import AnalysisResult
from benchctl.analysis.skew import WARN_PPM as SKEW_WARN_PPM
from benchctl.analysis.skew import Skew, deskewed, estimate_skew
from benchctl.analysis.spectra import Spectra, delay_estimate, max_lag_samples, spectra
from benchctl.analysis.timebase import label_of
from benchctl.analysis.timing import TimingBudget, error_rate_covariance, timing_budget
from benchctl.analysis.uncertainty import (
    density_interval,
    dof_of_variance,
    duration_for_precision,
    sigma_interval,
)
from benchctl.errors import AnalysisError, DataError

FloatArray = NDArray[np.float64]
DelayMode = Literal["none", "auto"] | float

PARSEVAL_RTOL = 1e-8
WELCH_SIGMAS = 4.0
SKEW_PASSES = 3  # a skew is measured again after its correction, at most this many times
TIMING_FLOOR_DEG2 = 1e-18  # … and is more than rounding (an error of exactly zero)


def _check_band(band_hz: tuple[float, float] | None, al: Aligned, resolution: float) -> None:
    if band_hz is None:
        return
    lo, hi = float(band_hz[0]), float(band_hz[1])
    nyq = 0.5 / al.dt
    if not (0.0 <= lo < hi <= nyq):
        raise DataError(
            f"band {lo:g} … {hi:g} Hz: expected 0 ≤ lo < hi ≤ fs/2 = {nyq:.6g} Hz"
        )
    span = len(al.mask) * al.dt
    if lo > 0 and span * lo < 2.0:
        raise DataError(
            f"record too short for the band {lo:g} … {hi:g} Hz: {span:.6g} s holds fewer than "
            f"two periods of {lo:g} Hz; expected at least {2.0 / lo:.6g} s"
        )
    if hi - lo < 1.0 / span:
        raise DataError(
            f"band {lo:g} … {hi:g} Hz is narrower than the record's resolution "
            f"{1.0 / span:.4g} Hz (1/{span:.6g} s); give a wider band or a longer record"
        )


def _check_psd_band(band_hz: tuple[float, float], resolution: float) -> None:
    """A band-limited σ from the smoothed PSD (no line-wise estimate) needs a band at least as
    wide as the PSD's resolution (from the lines it needs only the record's, 1/T)."""
    lo, hi = band_hz
    if hi - lo < resolution:
        raise DataError(
            f"band {lo:g} … {hi:g} Hz is narrower than the resolution {resolution:.4g} Hz of "
            "the estimate (no line-wise estimate, whose bins are 1/T apart, to take it from); "
            "give a wider band or a longer max lag"
        )


def _delay_mode(compensate_delay: DelayMode) -> float | None:
    """None: no compensation; nan: auto; else the delay in seconds."""
    if isinstance(compensate_delay, str):
        if compensate_delay == "none":
            return None
        if compensate_delay == "auto":
            return float("nan")
        raise DataError(
            f"compensate_delay: expected 'none', 'auto' or seconds, got {compensate_delay!r}"
        )
    d = float(compensate_delay)
    if not np.isfinite(d):
        raise DataError(f"compensate_delay: expected a finite number of seconds, got {d!r}")
    return d


def _prepared(
    al_all: Aligned, departures: Departures | None, max_lag_s: float | None,
    lines: LinesMode, period_s: float | None,
) -> tuple[Aligned, int, Spectra, Exclusion | None]:
    """The departures left out of ``al_all``, the max lag and the spectra. When what is left
    cannot be analysed (too few samples, no sample pairs at some lag), the whole record is,
    and the exclusion says σ is not to be judged."""
    al, ex = exclude(al_all, departures, lines, period_s)
    if ex is not None and ex.over == "kept" and ex.removed:
        try:
            lag = max_lag_samples(al, max_lag_s)
            return al, lag, spectra(al, lag), ex
        except DataError as e:
            ex.too_little = f"what is left cannot be analysed ({e})"
            ex.over = "all"
            al = al_all
    lag = max_lag_samples(al, max_lag_s)
    return al, lag, spectra(al, lag), ex


def analyze(
    t_ref: ArrayLike,
    x_ref_deg: ArrayLike,
    t_dev: ArrayLike,
    y_dev_deg: ArrayLike,
    *,
    max_lag_s: float | None = None,
    band_hz: tuple[float, float] | None = None,
    compensate_delay: DelayMode = "none",
    timebase: Literal["auto", "given", "fitted"] = "auto",
    reference_timebase: Literal["auto", "given", "fitted"] = "auto",
    lines: LinesMode = "auto",
    period_s: float | None = None,
    source: str = "",
    axis: str | None = None,
    departures: Departures | None = None,
    reference: Reference | None = None,
) -> AnalysisResult:
    """Dynamic error of an instrument from its output and the measured stand angle.

    Parameters
    ----------
    t_ref, x_ref_deg : array_like
        Reference (measured stand angle) instants, s, and angles, deg.
    t_dev, y_dev_deg : array_like
        Instrument instants, s, and output, deg. Any rates; the reference is evaluated at
        the instrument's instants (see ``align``); the instrument is never interpolated.
    max_lag_s : float, optional
        Maximum correlation lag, s. Default: a tenth of the record (see module notes).
    band_hz : (lo, hi), optional
        Band for the band-limited σ and for the frequency-response grid, Hz.
    compensate_delay : "none" | "auto" | float
        Remove an acquisition delay (s, positive when the device lags) before the analysis:
        the reference is evaluated at ``t_dev − delay``. "auto" uses the delay estimated from
        the cross-correlation peak. The delay found before compensation is always reported.
    timebase : {"auto", "given", "fitted"}
        Device instants as given, or fitted to a uniform clock (jittery receipt times), or
        (``auto``, the default) the fitted clock when the data show the stamps' scatter
        about it to be the stamps' own error (``benchctl.analysis.timing``), else as given.
    reference_timebase : {"auto", "given", "fitted"}
        The same for the reference's instants (a reference sampled on a uniform clock whose
        stamps jitter). Instants labelled with their time base (``timebase.Instants``, as
        ``Recording.pair`` gives them) are used as given and keep their label.
    lines : LineSet | "auto" | "off"
        The excited lines of a periodic multisine (e.g. from a recording's profile, see
        ``benchctl.analysis.lines.line_set_from_recording``); "auto" (default): detected in
        the reference when the record holds two or more whole periods; "off": none.
    period_s : float, optional
        The motion's repetition period, s (the record must hold whole periods of it); the
        lines are those of its harmonics the reference is excited at. Overrides "auto".
    source, axis : str
        Labels carried into the result.
    departures : Departures, optional
        Where the stand's motion was not the profile's (on the instants' clock, e.g.
        :func:`benchctl.analysis.departures.departures_of` a recording): left out as gaps are
        (module notes); the result's ``departures`` says how many, how long and why.
    reference : Reference, optional
        The reference angle's resolution and standard uncertainty, for σ's uncertainty budget
        (``benchctl.analysis.budget``). Default: what labelled reference instants carry
        (``info["encoder_resolution_deg"]``, ``info["encoder_uncertainty_deg"]``, as
        ``Recording.pair`` gives them from the bench config), else not stated.

    Returns
    -------
    AnalysisResult
        σ (deg, about the mean), its 95 % interval, the error PSD (one-sided, deg²/Hz),
        H1, coherence, decomposition, gaps and cross-checks; with lines, the line-wise
        estimate (``lines``) and H, periods and the interval of σ from it.

    Raises
    ------
    DataError
        Bad input: non-finite values, non-monotonic times, constant signals, no overlap,
        a record too short for the lag or band.
    AnalysisError
        The area under the error PSD and the time-domain variance of ε disagree (Parseval).

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(6000) * 0.05                     # 300 s at 20 Hz
    >>> x = 5 * np.sin(2 * np.pi * 0.1 * t)
    >>> noise = np.random.default_rng(1).normal(0, 0.1, t.size)
    >>> r = analyze(t, x, t, 0.98 * x + noise)
    >>> round(r.sigma, 2), round(r.periods[-1]["gain"], 3)   # σ² = (0.02·5)²/2 + 0.1²
    (0.12, 0.98)
    """
    tr, xr = np.asarray(t_ref, dtype=float), np.asarray(x_ref_deg, dtype=float)
    td, yd = np.asarray(t_dev, dtype=float), np.asarray(y_dev_deg, dtype=float)
    mode = _delay_mode(compensate_delay)
    if period_s is not None and not (np.isfinite(period_s) and period_s > 0):
        raise DataError(f"period: expected a positive number of seconds, got {period_s!r}")
    if not isinstance(lines, LineSet) and lines not in ("auto", "off"):
        raise DataError(f"lines: expected a LineSet, 'auto' or 'off', got {lines!r}")
    labels = (label_of(t_ref), label_of(t_dev))
    if reference is None:
        reference = Reference.of(None if labels[0] is None else labels[0][2])
    al = align(tr, xr, td, yd, timebase=timebase, reference_timebase=reference_timebase,
               labels=labels)
    asked = (timebase, reference_timebase)
    timebase, reference_timebase = al.modes  # "auto" chosen once, from the stamps as given …
    choice = al.choice
    al, lag, sp, ex = _prepared(al, departures, max_lag_s, lines, period_s)
    # the instrument's stamps drifting against the reference's (its own clock fast or slow):
    # measured from the cross-spectrum's phase turning over the record, taken out (skew.py)
    motion_period = known_period(al, lines, period_s)
    skew = estimate_skew(al.x, al.y, al.mask, al.dt, motion_period, _t0(al))
    if skew is not None and skew.significant:
        total, pending = None, skew
        for i in range(SKEW_PASSES):  # each pass measures what the last one left
            td = deskewed(td, pending)
            total = pending if total is None else total.plus(pending)
            # … or, with a skew, on the stamps without it (a drift of the delay swamps the
            # error's slope on rate × scatter that tells stamps' errors from true instants)
            modes = asked if i == 0 else (timebase, reference_timebase)
            al = align(tr, xr, td, yd, timebase=modes[0], reference_timebase=modes[1],
                       labels=labels)
            if i == 0:
                timebase, reference_timebase = al.modes
                choice = al.choice
            al, lag, sp, ex = _prepared(al, departures, max_lag_s, lines, period_s)
            # the period again: a motion periodic on the reference's clock is periodic on
            # the corrected grid, not on the skewed one (whole periods, no window's leakage)
            motion_period = known_period(al, lines, period_s)
            rest = estimate_skew(al.x, al.y, al.mask, al.dt, motion_period, _t0(al))
            if rest is None or not rest.left:
                break
            pending = rest
        skew = total
    _check_band(band_hz, al, sp.grid.resolution_hz)
    delay_raw = delay_estimate(sp, al)
    shift = 0.0
    if mode is not None:
        shift = delay_raw if np.isnan(mode) else mode
        if not np.isfinite(shift):
            raise DataError("compensate_delay=auto: no delay could be estimated (no excited band)")
        if shift != 0.0:
            al = align(tr, xr, td, yd, shift_s=shift, timebase=timebase,
                       reference_timebase=reference_timebase, labels=labels)
            al, lag, sp, ex = _prepared(al, departures, max_lag_s, lines, period_s)
    al = dataclasses.replace(al, choice=choice)
    return _result(al, sp, lag, band_hz, delay_raw, shift, mode, source, axis, lines, period_s,
                   ex, skew, reference)


def _t0(al: Aligned) -> float:
    """The grid's first instant (its first slot always holds a sample)."""
    ok = np.flatnonzero(np.isfinite(al.t))
    return float(al.t[ok[0]]) if ok.size else 0.0


def _timing_budget(al: Aligned, eps: FloatArray, ci: tuple[float, float],
                   centre: float, skew: Skew | None) -> TimingBudget:
    """σ's interval with timing in it (``timing.timing_budget``): the variance the instants'
    residual errors add, and an offset between the streams through cov(ε, ẋ) — the time
    bases' (``Aligned.offset_u_s``) and, for a skew taken out, the correction's own: a slope
    off by its standard error leaves a delay off by that × (t − t₀), on average × T/2."""
    m = al.mask
    full = bool(m.all())  # no gap: no copies of ε and ẋ at the samples
    rate = al.rate() if full else al.rate()[m]
    e = eps if full else eps[m]
    cov = error_rate_covariance(e, rate)
    n = max(len(e), 1)
    random = 2.0 * float(np.sqrt(np.mean(np.square(e * rate)))) * al.random_residual_s / n**0.5
    offset = al.offset_u_s
    if skew is not None:  # the correction's own (its mean less its start), or what a skew
        offset = math.hypot(offset, skew.anchor_se_s if skew.significant  # left uncorrected
                            else skew.unexplained_s)
    return timing_budget(centre, ci, al.timing_variance, cov, offset, random)


def _skew_fields(skew: Skew | None) -> dict[str, Any]:
    """The skew for the result's ``timing`` (None fields: the record too short to measure it)."""
    if skew is None:
        return {"skew_ppm": None, "skew_ci95_ppm": None, "skew_corrected": False}
    return {"skew_ppm": skew.ppm, "skew_ci95_ppm": list(skew.ci95_ppm),
            "skew_corrected": skew.significant, "skew_drift_s": skew.drift_s,
            "skew_degree": skew.degree, "skew_wander_s": skew.wander_s}


def _mean_removal(eps: FloatArray, mask: NDArray[np.bool_]) -> float:
    """The variance the mean removal takes out, var(ε̄) ≈ G(0)/(2T): half the error's
    periodogram at the lowest bin 1/T (the density taken flat between 0 and 1/T), deg²."""
    n, n_valid = len(eps), int(mask.sum())
    if n < 4:
        return 0.0
    e1 = np.sum(eps * np.exp(-2j * np.pi * np.arange(n) / n))
    return float(abs(e1) ** 2 / n_valid**2)


def _result(
    al: Aligned,
    sp: Spectra,
    lag: int,
    band_hz: tuple[float, float] | None,
    delay_raw: float,
    shift: float,
    mode: float | None,
    source: str,
    axis: str | None,
    lines: LinesMode = "off",
    period_s: float | None = None,
    ex: Exclusion | None = None,
    skew: Skew | None = None,
    reference: Reference | None = None,
) -> AnalysisResult:
    grid = sp.grid
    warnings: list[str] = []
    if skew is not None and skew.significant and (abs(skew.ppm) > SKEW_WARN_PPM
                                                  or skew.degree > 1):
        lo_p, hi_p = skew.ci95_ppm
        curve = (f"; its rate changes over the record: the delay follows a curve of degree "
                 f"{skew.degree}, up to {1e3 * skew.wander_s:.3g} ms off a steady drift"
                 if skew.degree > 1 else "")
        warnings.append(
            f"timing: the instrument's stamps drift against the reference's by "
            f"{skew.ppm:+.4g} ppm (95 % {lo_p:+.4g} … {hi_p:+.4g}; {1e3 * skew.drift_s:+.4g} ms "
            f"over the record{curve}): its clock runs fast or slow. Corrected, anchored at the "
            "record's start (its clock taken as right when the record began); set the "
            "instrument's clock, or record its stamps with the host's receipt times")
    eps_raw = np.where(al.mask, al.y - al.x, 0.0)
    n = al.n_valid
    mean_error = float(eps_raw.sum() / n)
    eps = demean(eps_raw, al.mask)
    del eps_raw  # a record's length of memory less at the analysis's peak (line-wise, below)
    variance = float(np.dot(eps, eps) / n)  # np.dot: the Parseval check's last bits as before
    area = trapezoid_area(grid.freq, sp.gee)
    tol = PARSEVAL_RTOL * variance + 1e-13 * sp.r0_scale
    if not abs(area - variance) <= tol:
        raise AnalysisError(
            f"Parseval check failed: area under the error PSD {area!r} deg² differs from the "
            f"time-domain variance of ε {variance!r} deg² by more than {tol:.3g}"
        )
    sigma = float(np.sqrt(variance))
    time_variance = variance  # the samples' own: the cross-checks are about it
    dof_f = grid.dof(n)
    duration_eff = n * al.dt
    resp = frf_mod.frequency_response(grid.freq, sp.gxx, sp.gyy, sp.gxy, band_hz)
    dec = frf_mod.decompose(grid.freq, sp.gxx, sp.gxy, sp.gee, dof_f)
    linear = trapezoid_area(grid.freq, dec.linear)
    dof = dof_of_variance(grid.freq, dec.linear, dec.incoherent, duration_eff, dof_f)
    dof_rand = dof_of_variance(
        grid.freq, dec.linear, dec.incoherent, duration_eff, dof_f, motion_random=True
    )
    la = line_analysis(al, lines, period_s, warnings, ex, band_hz)
    if ex is not None:
        warnings[:0] = exclusion_warnings(ex)
    if la is not None:
        mean_removal = la.mean_removal
        ci = la.sigma_ci95
        dof = la.dof
        # the record just short of whole periods: the lines over its whole periods, or over
        # whole periods that hold a gap at the end (``linechoice``); either way σ over the
        # samples present is not over whole periods, and reads the lines' motion unevenly
        span = la.n_periods * la.lines.period_s
        part = span < (len(al.mask) - 1) * al.dt or span > len(al.mask) * al.dt + max(
            2.0 * al.dt, 1e-4 * la.lines.period_s)
        if n < len(al.mask) or part:
            # samples missing (gaps, exclusions): the σ over the samples present weighs the
            # motion's phases unevenly (an error that depends on the motion then reads off);
            # the lines, fitted on the samples present, estimate the whole period's — the σ
            # the interval is about. (Without gaps the two coincide.)
            sample_sigma = sigma
            variance = max(la.variance - la.mean_removal, 0.0)
            sigma = float(np.sqrt(variance))
            if not part and not ci[0] <= sample_sigma <= ci[1]:
                warnings.append(
                    f"σ is the line-wise estimate over the whole period(s) ({sigma:.5g}°): "
                    f"over the {n} samples present it would read {sample_sigma:.5g}°, outside "
                    f"its interval {ci[0]:.5g} … {ci[1]:.5g}° — the gaps fall unevenly on the "
                    "motion"
                )
        elif not ci[0] <= sigma <= ci[1]:
            warnings.append(
                f"σ over the samples present ({sigma:.5g}°) lies outside the line-wise "
                f"interval {ci[0]:.5g} … {ci[1]:.5g}° (line-wise σ {la.sigma:.5g}°): the "
                "record is not stationary"
            )
    else:
        mean_removal = _mean_removal(eps, al.mask)
        ci = sigma_interval(float(np.sqrt(variance + mean_removal)), dof)
    ci_rand = sigma_interval(sigma, dof_rand)
    welch = welch_by_runs(eps, al.mask, al.dt, 2 * lag)
    cross = _welch_check(
        welch, time_variance, dof_rand * (welch.n_used / n if welch else 1.0), warnings
    )
    cross.update(
        {
            "parseval_area": area,
            "time_variance": time_variance,
            "parseval_rel_diff": (
                abs(area - time_variance) / time_variance if time_variance > 0 else 0.0
            ),
        }
    )
    band = None if la is None else la.band  # from the lines: no leakage, with its interval
    if band_hz is not None and band is None:
        _check_psd_band(band_hz, grid.resolution_hz)
        bv = band_area(grid.freq, sp.gee, band_hz[0], band_hz[1])
        band = {
            "lo": float(band_hz[0]),
            "hi": float(band_hz[1]),
            "method": "psd",  # the smoothed PSD's area: no interval (replaced by the lines')
            "variance": bv,
            "sigma": float(np.sqrt(max(bv, 0.0))),
            "variance_ci95": None,
            "sigma_ci95": None,
        }
    # timing in σ's interval; a warning when it moves the interval noticeably (timing.py)
    budget = _timing_budget(al, eps, ci, float(np.sqrt(variance + mean_removal)), skew)
    ci = budget.ci
    # σ's uncertainty budget (budget.py): the same sources, GUM style, for the headline σ
    sigma_corrected = float(np.sqrt(variance + mean_removal))
    stationarity = (None if la is None or la.stationarity is None
                    else la.stationarity.to_dict())
    drift = None if la is None or la.drift is None else la.drift.to_dict()
    gum = uncertainty_budget(
        sigma=sigma, sigma_corrected=sigma_corrected, ci_statistical=budget.ci_statistical,
        dof=dof, timing_cross_variance=budget.cross, timing_bias_variance=budget.bias,
        bridge_variance=al.bridge_variance, reference=reference or Reference(),
        stationarity=stationarity, drift=drift)
    if budget.warn and al.timing_variance + budget.cross > TIMING_FLOOR_DEG2:
        warnings.append(al.timing_warning(variance, budget.cross, budget.offset_u_s))
    if al.device.gap_count:
        warnings.append(
            f"device stream has {al.device.gap_count} gap(s), {al.device.missing_samples} "
            f"missing sample(s), longest {al.device.longest_gap_s:.6g} s; gaps are masked"
        )
    if al.excluded:
        warnings.append(
            f"{al.excluded} device sample(s) excluded: outside the reference's span or in its gaps"
        )
    if la is not None:
        keep = np.ones(len(la.freq), dtype=bool)
        if band_hz is not None:
            keep = (la.freq >= band_hz[0]) & (la.freq <= band_hz[1])
        frf_arrays = (la.freq[keep], la.gain[keep], la.phase_deg[keep], la.coherence[keep],
                      la.gain_ci95[keep], la.phase_ci95_deg[keep])
        frf_reliable: NDArray[np.bool_] | None = la.reliable[keep]
        periods = periods_from_lines(la, frf_mod.TRADITIONAL_PERIODS_S)
        frf_source = "lines"
        split = (la.linear, la.incoherent, "lines")
    else:
        gci, pci = frf_mod.h1_intervals(resp, dof_f)
        frf_arrays = (resp.freq, resp.gain, resp.phase_deg, resp.coherence, gci, pci)
        frf_reliable = None
        periods = frf_mod.at_periods(resp, dof_f, grid.freq, sp.gxx, grid.resolution_hz)
        frf_source = "h1"
        split = (linear, variance - linear, "lag_window")
    if len(frf_arrays[0]) == 0:
        warnings.append("no excited frequency in the band: no frequency response")
    return AnalysisResult(
        sigma=sigma,
        variance=variance,
        mean_error=mean_error,
        rms_error=float(np.sqrt(variance + mean_error**2)),
        sigma_ci95=ci,
        dof=dof,
        delay=delay_raw,
        delay_compensated=shift,
        n_samples=n,
        duration=len(al.mask) * al.dt,
        sample_rate=1.0 / al.dt,
        max_lag=lag * al.dt,
        max_lag_samples=lag,
        resolution_hz=grid.resolution_hz,
        dof_per_frequency=dof_f,
        psd_freq=grid.freq,
        psd_error=sp.gee,
        psd_ci95=density_interval(sp.gee, dof_f),
        welch_freq=None if welch is None else welch.freq,
        welch_error=None if welch is None else welch.density,
        frf_freq=frf_arrays[0],
        frf_gain=frf_arrays[1],
        frf_phase_deg=frf_arrays[2],
        frf_coherence=frf_arrays[3],
        frf_gain_ci95=frf_arrays[4],
        frf_phase_ci95_deg=frf_arrays[5],
        frf_source=frf_source,
        frf_reliable=frf_reliable,
        periods=periods,
        linear=split[0],
        incoherent=split[1],
        components_source=split[2],
        lines=la,
        band=band,
        gaps=_gaps(al),
        departures=None if ex is None else ex.to_dict(),
        timing={
            "device_dt": al.device.dt,
            "device_jitter_rms": al.device.jitter_rms,
            "reference_dt": al.reference.dt,
            "reference_jitter_rms": al.reference.jitter_rms,
            **al.timing_fields(),
            "timing_share": al.timing_variance / variance if variance > 0 else 0.0,
            **_skew_fields(skew),
            **budget.fields(),
        },
        cross_checks=cross,
        uncertainty={
            "method": "lines" if la is not None else "lag_window",
            "mean_removal": mean_removal,
            "sigma_corrected": sigma_corrected,
            "dof_parts": None if la is None else dict(la.dof_parts),
            "stationarity": stationarity,
            "drift": drift,
            "dof_motion_random": dof_rand if np.isfinite(dof_rand) else None,
            "sigma_ci95_motion_random": [ci_rand[0], ci_rand[1]],
            "duration_for_5pct": duration_for_precision(duration_eff, dof),
            "compensate_delay": "none" if mode is None else ("auto" if np.isnan(mode) else "fixed"),
        },
        source=source,
        axis=axis,
        warnings=warnings,
        budget=gum,
    )


def _welch_check(
    welch: WelchEstimate | None, variance: float, dof: float, warnings: list[str]
) -> dict[str, Any]:
    """Welch's area against the variance, within ``WELCH_SIGMAS`` standard deviations of a
    variance estimate with ``dof`` (the fully random ν, scaled to the samples Welch used)."""
    if welch is None:
        warnings.append("no gap-free run of 64 samples: Welch cross-check skipped")
        return {"welch_area": None, "welch_tolerance": None, "welch_agrees": None}
    area = welch.area
    tol = WELCH_SIGMAS * variance * float(np.sqrt(2.0 / dof)) if np.isfinite(dof) else 0.0
    tol += 1e-9 * variance
    agrees = abs(area - variance) <= tol
    if not agrees:
        warnings.append(
            f"Welch area {area:.6g} deg² differs from the variance {variance:.6g} deg² by more "
            f"than its statistical tolerance {tol:.3g} (non-stationary record?)"
        )
    return {"welch_area": area, "welch_tolerance": tol, "welch_agrees": bool(agrees)}


def _gaps(al: Aligned) -> dict[str, Any]:
    return {
        "device": {
            "count": al.device.gap_count,
            "missing_samples": al.device.missing_samples,
            "longest_s": al.device.longest_gap_s,
        },
        "reference": {
            "count": al.reference.gap_count,
            "missing_samples": al.reference.missing_samples,
            "longest_s": al.reference.longest_gap_s,
        },
        "excluded_samples": al.excluded,
    }
