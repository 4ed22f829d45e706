"""From a validated :class:`Profile` to a :class:`Motion`: targets, line design, phases, fades.

Pure computation (the profile's recorded spectra were read by the loader).

Repetition period rule (T_p): the steady part of a spectral profile, ``duration − fade_in −
fade_out``, always holds a whole number ``n`` of periods, so an analysis over the steady part
has no leakage. Without ``repeat_period_s``, ``n = 1`` and ``T_p`` is the whole steady part
(the finest line spacing). With it, ``n = max(1, round(steady / repeat_period_s))`` and
``T_p = steady / n``. The same rule applies when the run overrides the duration, so a shorter
or longer run still holds whole periods.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchctl.errors import ConfigError
from benchctl.harmonics import HarmonicTable
from benchctl.profiles import roll, spectra
from benchctl.profiles.loader import Profile, sine_steps_duration
from benchctl.profiles.motion import AxisTarget, Motion, StepMotion, StepSegment, TableMotion
from benchctl.profiles.schema import (
    ExpCosSpec,
    HarmonicsProfile,
    RecordedProfile,
    RollSpectrumProfile,
    SeaStateProfile,
    SineProfile,
    SineStepsProfile,
    SpectralBase,
    TableSpec,
)
from benchctl.profiles.synthesis import (
    AXIS_STREAM,
    CrestReport,
    design_lines,
    line_harmonics,
    random_phases,
    reduce_crest,
    select_lines,
)

FloatArray = NDArray[np.float64]
Density = Callable[[FloatArray], FloatArray]


def choose_period(steady_s: float, repeat_period_s: float | None) -> tuple[float, int]:
    """(T_p, n): the repetition period and how many of them the steady part holds."""
    if repeat_period_s is None:
        return steady_s, 1
    n = max(1, round(steady_s / repeat_period_s))
    return steady_s / n, n


def total_variance(density: Density, kinks: FloatArray | None = None) -> float:
    """``∫_0^∞ G(f) df`` (deg²): the whole variance of a target model, whatever band is kept.

    Adaptive quadrature (scipy ``quad``) split at the density's peak (found on a log grid), its
    kinks (tables, records) and a high split frequency, with the tail integrated to infinity.
    """
    # scipy.integrate: about 0.4 s to import, for a model without a closed form only
    from scipy.integrate import quad

    def g(f: float) -> float:
        return float(np.asarray(density(np.array([f], dtype=float)))[0])

    grid = np.geomspace(1e-4, 50.0, 4000)
    vals = np.asarray(density(grid), dtype=float)
    pts = {float(grid[int(np.argmax(vals))])} if np.any(vals > 0) else set()
    if kinks is not None:
        pts |= {float(k) for k in np.asarray(kinks, dtype=float) if k > 0}
    top = max(50.0, 2.0 * max(pts, default=0.0))
    edges = [0.0, *sorted(p for p in pts if p < top), top]
    total = 0.0
    for a, b in itertools.pairwise(edges):
        if b > a:
            total += quad(g, a, b, limit=400)[0]
    total += quad(g, top, np.inf, limit=400)[0]
    return float(total)


def axis_density(profile: Profile, axis: str) -> tuple[Density, FloatArray | None]:
    """The target one-sided roll density G(f) (deg²/Hz) of one axis, and its kinks if any."""
    spec = profile.spec
    if isinstance(spec, SeaStateProfile):
        sea = spec.sea
        hs = sea.hs_m if sea.hs_m is not None else spectra.wmo_sea_state(sea.wmo_code or 0).hs_m
        ship = spec.axes[axis]  # type: ignore[index]

        def wave(f: FloatArray) -> FloatArray:
            if sea.spectrum == "jonswap":
                return spectra.jonswap(
                    f,
                    hs,
                    sea.tp_s,
                    sea.gamma if sea.gamma is not None else 3.3,
                    sea.sigma_a if sea.sigma_a is not None else 0.07,
                    sea.sigma_b if sea.sigma_b is not None else 0.09,
                )
            return spectra.pierson_moskowitz(f, hs, sea.tp_s)

        def sea_density(f: FloatArray) -> FloatArray:
            return roll.roll_response_psd(
                f, wave(f), ship.natural_period_s, ship.damping_ratio, ship.slope_coefficient
            )

        return sea_density, None
    if isinstance(spec, RollSpectrumProfile):
        model = spec.axes[axis]  # type: ignore[index]
        if isinstance(model, ExpCosSpec):
            alpha, beta = roll.exp_cos_parameters(model.period_s, model.damping)
            sigma = model.sigma_deg
            return (lambda f: roll.exp_cos_psd(f, sigma, alpha, beta)), None
        assert isinstance(model, TableSpec)
        fx = np.asarray(model.freq_hz, dtype=float)
        gx = np.asarray(model.density_deg2_hz, dtype=float)
        return (lambda f: roll.breakpoint_psd(f, fx, gx)), fx
    if isinstance(spec, RecordedProfile):
        rec = profile.recorded[axis]
        return rec.density, rec.freq_hz
    raise TypeError(f"kind {profile.kind} has no target density")


def _fades(profile: Profile, duration: float) -> tuple[float, float]:
    spec = profile.spec
    fi, fo = float(spec.fade_in_s), float(spec.fade_out_s)
    if fi + fo >= duration:
        raise ConfigError(
            f"{profile.label('fade_in_s/fade_out_s')}: fades {fi:g} s + {fo:g} s leave no motion "
            f"in a duration of {duration:g} s; expected fade_in_s + fade_out_s < duration"
        )
    return fi, fo


def _spectral(
    profile: Profile, duration: float, seed: int, setpoint_rate_hz: float | None
) -> TableMotion:
    spec: SpectralBase = profile.spec
    fi, fo = _fades(profile, duration)
    steady = duration - fi - fo
    tp, n_periods = choose_period(steady, spec.repeat_period_s)
    tables: dict[str, HarmonicTable] = {}
    targets: dict[str, AxisTarget | None] = {}
    crest: dict[str, CrestReport] = {}
    for axis, ax in spec.axes.items():  # type: ignore[attr-defined]
        band = ax.band_hz or spec.band_hz
        where = f"axes.{axis}.band_hz" if ax.band_hz else "band_hz"
        if band is None:
            raise ConfigError(
                f"{profile.label('band_hz')}: missing; give band_hz for the profile or for "
                f"axes.{axis}"
            )
        lo, hi = float(band[0]), float(band[1])
        if lo * tp < 1.0 - 1e-9:
            raise ConfigError(
                f"{profile.label(where)} = [{lo:g}, {hi:g}]: the low edge {lo:g} Hz is below the "
                f"resolution 1/T_p = {1 / tp:.4g} Hz of a {tp:g} s period (duration {duration:g} s "
                f"minus fades); raise the low edge to >= {1 / tp:.4g} Hz or lengthen the duration"
            )
        if setpoint_rate_hz is not None and hi >= setpoint_rate_hz / 2:
            raise ConfigError(
                f"{profile.label(where)} = [{lo:g}, {hi:g}]: the high edge must be below half the "
                f"setpoint rate ({setpoint_rate_hz / 2:g} Hz)"
            )
        k = line_harmonics((lo, hi), tp)
        ms = spec.multisine
        selection = None
        if ms is not None:
            selection = select_lines(
                k,
                odd=ms.odd,
                detection_group=ms.detection_group,
                interleave_axes=ms.interleave_axes,
                seed=seed,
                stream=AXIS_STREAM[axis],
            )
            k = selection.kept
        if k.size < spec.min_lines:
            raise ConfigError(
                f"{profile.label(where)} = [{lo:g}, {hi:g}]: holds {k.size} line(s) at spacing "
                f"1/T_p = {1 / tp:.4g} Hz"
                + ("" if selection is None else " (after the multisine option's selection)")
                + f", expected at least min_lines = {spec.min_lines}; widen "
                f"the band or lengthen the duration"
            )
        density, kinks = axis_density(profile, axis)
        design = design_lines(density, (lo, hi), tp, method=spec.amplitudes, breakpoints_hz=kinks,
                              keep=None if selection is None else selection.kept)
        if design.target_variance_deg2 <= 0:
            raise ConfigError(f"{profile.label(where)}: the target spectrum is zero in this band")
        phase = random_phases(design.freq_hz.size, seed, AXIS_STREAM[axis])
        phase, report = reduce_crest(
            design.harmonic, design.amp_deg, phase, spec.crest.method, spec.crest.iterations
        )
        crest[axis] = report
        tables[axis] = HarmonicTable(
            design.freq_hz,
            design.amp_deg,
            phase,
            duration,
            fi,
            fo,
            tp,
            {"band_hz": (lo, hi), "n_periods": n_periods, "amplitudes": spec.amplitudes}
            | ({} if selection is None else {"multisine": selection.to_meta()}),
        )
        targets[axis] = AxisTarget(
            density,
            (lo, hi),
            design.target_variance_deg2,
            model_variance_deg2=total_variance(density, kinks),
        )
    note = (
        f"T_p = {tp:g} s: the steady part ({steady:g} s = duration {duration:g} s - fades) holds "
        f"{n_periods} whole period(s)"
    )
    return TableMotion(profile.name, profile.kind, tables, targets, seed, crest, 1.0, (note,))


def _harmonics(profile: Profile, duration: float, seed: int) -> TableMotion:
    spec: HarmonicsProfile = profile.spec
    fi, fo = _fades(profile, duration)
    tp = spec.repeat_period_s
    tables: dict[str, HarmonicTable] = {}
    for axis, ax in spec.axes.items():
        f = np.array([ln.frequency_hz for ln in ax.lines])
        amp = np.array([ln.amplitude_deg for ln in ax.lines])
        drawn = random_phases(len(ax.lines), seed, AXIS_STREAM[axis])
        phase = np.array(
            [
                math.radians(ln.phase_deg) if ln.phase_deg is not None else drawn[i]
                for i, ln in enumerate(ax.lines)
            ]
        )
        if tp is not None:
            k = f * tp
            off = np.nonzero(np.abs(k - np.round(k)) > 1e-6)[0]
            if off.size:
                raise ConfigError(
                    f"{profile.label(f'axes.{axis}.lines.{int(off[0])}')}: frequency "
                    f"{f[off[0]]:.6g} Hz is not a multiple of 1/repeat_period_s = {1 / tp:.6g} Hz"
                )
        tables[axis] = HarmonicTable(f, amp, phase, duration, fi, fo, tp)
    return TableMotion(profile.name, profile.kind, tables, dict.fromkeys(tables), seed)


def _sine(profile: Profile, duration: float, seed: int) -> TableMotion:
    spec: SineProfile = profile.spec
    fi, fo = _fades(profile, duration)
    tables: dict[str, HarmonicTable] = {
        axis: HarmonicTable(
            np.array([1.0 / s.period_s]),
            np.array([s.amplitude_deg]),
            np.array([math.radians(s.phase_deg)]),
            duration,
            fi,
            fo,
            s.period_s,
        )
        for axis, s in spec.axes.items()
    }
    return TableMotion(profile.name, profile.kind, tables, dict.fromkeys(tables), seed)


def _sine_steps(profile: Profile, duration: float | None) -> StepMotion:
    spec: SineStepsProfile = profile.spec
    total = sine_steps_duration(spec)
    if duration is not None and abs(duration - total) > 1e-6:
        raise ConfigError(
            f"{profile.source or '<profile>'}: a sine_steps profile lasts {total:g} s (its grid "
            f"of periods x amplitudes); a duration override of {duration:g} s cannot be imposed "
            "(omit the duration)"
        )
    segs: list[StepSegment] = []
    t = 0.0
    for axis in spec.axes:
        for period in spec.periods_s:
            for amp in spec.amplitudes_deg:
                t += spec.rest_s
                fade = spec.fade_cycles * period
                length = (spec.cycles + 2 * spec.fade_cycles) * period
                table = HarmonicTable(
                    np.array([1.0 / period]),
                    np.array([amp]),
                    np.array([-np.pi / 2]),
                    length,
                    fade,
                    fade,
                    period,
                )  # phase −π/2: a sine, starting from zero
                segs.append(StepSegment(axis, t, period, amp, table))
                t += length
    return StepMotion(
        profile.name, profile.kind, tuple(spec.axes), tuple(segs), total, profile.seed
    )


def synthesize(
    profile: Profile,
    *,
    duration_s: float | None = None,
    seed: int | None = None,
    setpoint_rate_hz: float | None = None,
) -> Motion:
    """The stand motion a profile asks for.

    Parameters
    ----------
    profile : Profile
        From :func:`benchctl.profiles.load_profile`.
    duration_s : float, optional
        Overrides the profile's duration (T_p then follows the module's rule, so the steady
        part still holds whole periods). Refused for sine_steps, whose length is its grid.
    seed : int, optional
        Overrides the profile's seed (phases).
    setpoint_rate_hz : float, optional
        The stand's setpoint rate; the band must lie below half of it.

    Returns
    -------
    Motion
        ``TableMotion`` (one :class:`HarmonicTable` per axis) for every kind but sine_steps,
        which gives a ``StepMotion`` (``tables`` is None). Raises ``ConfigError`` naming the
        file and field when the profile cannot be synthesised as asked.
    """
    spec: Any = profile.spec
    if seed is not None and seed < 0:
        raise ConfigError(f"{profile.label('seed')}: override {seed} must be >= 0")
    use_seed = profile.seed if seed is None else int(seed)
    if isinstance(spec, SineStepsProfile):
        return _sine_steps(profile, duration_s)
    duration = float(spec.duration_s if duration_s is None else duration_s)
    if not duration > 0:
        raise ConfigError(f"{profile.label('duration_s')}: override {duration:g} must be > 0")
    if isinstance(spec, SpectralBase):
        return _spectral(profile, duration, use_seed, setpoint_rate_hz)
    if isinstance(spec, HarmonicsProfile):
        return _harmonics(profile, duration, use_seed)
    if isinstance(spec, SineProfile):
        return _sine(profile, duration, use_seed)
    raise TypeError(f"unhandled profile kind {profile.kind}")  # pragma: no cover
