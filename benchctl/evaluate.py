"""One evaluation path: a recording's samples, per axis, to ``AnalysisResult``.

``benchctl.analysis`` works on arrays: two streams of instants and angles in, σ and the rest
out. What turns a *recording* into those arrays, and the profile into the analysis's lines, is
here, once, for every caller: the run's verdict (``run.evaluation.analyse``), the running
precision check (``run.precision.check_window``), ``benchctl analyze`` on a recording (and
:func:`analyze_recording`, its Python form) and ``benchctl predict``. Each step is the same for
all of them:

1. the recording (``benchctl.recording.Recording``), its integrity checked when asked;
2. per axis, the reference's and the instrument's instants (``Recording.pair``: the time bases,
   the bench's timing calibration), cropped to the analysis window — the one given (the live
   run's whole periods; the reference kept ``WINDOW_MARGIN_S`` beyond it, as
   ``Recording.pair`` does with the window a finished run wrote in ``end.json``) or else the
   recording's own;
3. where the stand's motion was not the profile's (underruns, rejoins: ``departures_of``), left
   out as gaps are;
4. the line-wise estimate on the profile's own lines: the tables the run played
   (:class:`RunProfile`), or re-synthesised from the recording's metadata, unless a period or
   lines are given;
5. ``analysis.analyze`` with the options (:class:`EvaluationOptions`);
6. what the profile adds: a sine-steps profile's linearity table, the measured excitation
   fidelity, and for a two-axis record each output against the other axis's motion.

What stays with each caller is its own: the verdict and the report (the session), the stopping
rule (the precision check), the printing and JSON (``benchctl analyze``), the prediction
(``benchctl predict``).

This module sits above ``recording`` and ``analysis`` and below ``run`` and the command line,
outside the ``run`` package so that ``benchctl analyze`` does not import the run's machinery.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from benchctl.analysis import AnalysisResult, LineSet, analyze
from benchctl.analysis.core import DelayMode
from benchctl.analysis.crossaxis import cross_axis_for
from benchctl.analysis.departures import Departures, departures_of
from benchctl.analysis.excitation import Fidelity, breached, fidelity_of_table
from benchctl.analysis.fidelitylimits import FidelityLimits, StandReach, limits_of, reach_of
from benchctl.analysis.lines import line_set_from_recording, line_set_from_tables
from benchctl.analysis.steps import (
    analyze_steps,
    attach_steps,
    motion_start,
    step_windows,
    steps_for_recording,
)
from benchctl.config import ExcitationConfig, StandLimits
from benchctl.errors import BenchError, DataError
from benchctl.profiles import parse_profile, synthesize
from benchctl.recording import Recording, load_recording
from benchctl.recording.reader import WINDOW_MARGIN_S

MIN_SAMPLES = 16  # fewer samples of either stream in the window: no analysis
RECORDED = "recorded"  # departures: the recording's own (its events and setpoints)


@dataclass(frozen=True)
class EvaluationOptions:
    """The analysis's options (as :func:`benchctl.analysis.analyze` takes them) and the
    recording's instrument time base (``Recording.pair``'s ``timebase``).

    ``lines``: ``None`` (the default) — the profile's lines, unless ``period_s`` is given, else
    detected; ``"auto"`` — detected (or from ``period_s``); ``"off"``; or a ``LineSet``.
    ``extra``: any other keyword ``analyze`` takes, passed as it is."""

    max_lag_s: float | None = None
    band_hz: tuple[float, float] | None = None
    compensate_delay: DelayMode = "none"
    timebase: Literal["auto", "given", "fitted"] = "auto"
    reference_timebase: Literal["auto", "given", "fitted"] = "auto"
    period_s: float | None = None
    lines: LineSet | str | None = None
    recording_timebase: str = "best"
    extra: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def of_config(cls, analysis: Any) -> EvaluationOptions:
        """The options a bench config states (``run.analysis``), as the run's verdict uses."""
        return cls(max_lag_s=analysis.max_lag_s, band_hz=analysis.band_hz,
                   compensate_delay=analysis.compensate_delay)


@dataclass(frozen=True)
class RunProfile:
    """The profile as the run plays it (the session and its precision check know it; a
    recording read later has it re-synthesised from its metadata): the harmonic tables per
    axis, the motion (a sine-steps profile's segments), when the motion started (host s), and
    the settings from the bench config — the linearity spread limit, the excitation judgement's
    limits and the stand's reach."""

    tables: Mapping[str, Any]
    motion: Any
    t_motion_start: float | None
    spread_limit: float
    excitation_limits: FidelityLimits
    reach: StandReach

    @classmethod
    def of_run(cls, motion: Any, t_motion_start: float | None, cfg: Any) -> RunProfile:
        """The profile of a run of bench config ``cfg`` (its ``run`` and ``stand`` sections)."""
        return cls(dict(getattr(motion, "tables", None) or {}), motion, t_motion_start,
                   cfg.run.linearity_spread_limit, limits_of(cfg.run.excitation),
                   reach_of(cfg.stand.limits))


@dataclass(frozen=True)
class EvaluationRequest:
    """What to evaluate.

    - ``axes``: the axes to analyse (None: every recorded axis);
    - ``window``: [t0, t1] host s, the instrument's samples inside it and the reference's up to
      ``WINDOW_MARGIN_S`` beyond (None: the window the finished run wrote, else everything);
    - ``departures``: ``RECORDED`` (left out, with ``settle_s`` or the recording's bench
      config's settling), ``None`` (nothing left out) or given ``Departures``;
    - ``profile``: the profile as the run plays it (None: re-synthesised from the metadata);
    - ``steps``, ``excitation``, ``cross_axis``: what the profile adds, each on or off;
      ``excitation_alarm``: a warning per axis with a band beyond the alarm level (the run's
      verdict gives one, ``Evaluation.alarms``);
    - ``require_intact``: refuse a recording altered after its run closed it
      (``IntegrityError``);
    - ``label_errors``: an analysis's ``DataError`` gets ``"<source> [<axis>]: "`` in front;
    - ``source``: the name in the results (None: the recording's path as given)."""

    axes: Sequence[str] | None = None
    window: tuple[float, float] | None = None
    options: EvaluationOptions = field(default_factory=EvaluationOptions)
    departures: Departures | str | None = RECORDED
    settle_s: float | None = None
    profile: RunProfile | None = None
    steps: bool = True
    excitation: bool = True
    excitation_alarm: bool = False
    cross_axis: bool = True
    require_intact: bool = True
    label_errors: bool = False
    source: str | None = None


@dataclass
class Evaluation:
    """Per axis, the analysis (``results``), the measured excitation (``fidelity``: a
    ``Fidelity``, or why there is none), the warning when a band is beyond its alarm level
    (``alarms``, when asked) and the note on the profile's lines when they could not be used
    (``line_notes``); the recording it came from."""

    recording: Recording
    results: dict[str, AnalysisResult] = field(default_factory=dict)
    fidelity: dict[str, Fidelity | str] = field(default_factory=dict)
    alarms: dict[str, str] = field(default_factory=dict)
    line_notes: dict[str, str] = field(default_factory=dict)


Pair = tuple[Any, Any, Any, Any]


def _pair(rec: Recording, axis: str, window: tuple[float, float] | None, timebase: str,
          label: str) -> Pair:
    """One axis's (t_ref, x_ref, t_dev, y_dev), cropped to ``window`` when one is given."""
    if window is None:
        return rec.pair(axis, timebase=timebase)
    tr, xr, td, yd = rec.pair(axis, window=False, timebase=timebase)
    lo, hi = window
    kr = (tr >= lo - WINDOW_MARGIN_S) & (tr <= hi + WINDOW_MARGIN_S)
    kd = (td >= lo) & (td <= hi)
    if kd.sum() < MIN_SAMPLES or kr.sum() < MIN_SAMPLES:
        raise DataError(
            f"{label}: too few samples for axis {axis} in the analysis window "
            f"({int(kr.sum())} stand, {int(kd.sum())} instrument)"
        )
    return tr[kr], xr[kr], td[kd], yd[kd]


def _profile_lines(rec: Recording, req: EvaluationRequest, axis: str,
                   span: tuple[float, float] | None) -> tuple[LineSet | None, str | None]:
    """The profile's lines of ``axis``: from the run's tables (no reason given when there are
    none: a profile without tables has no lines to say anything about), else re-synthesised
    from the recording's metadata (the reason when they cannot be)."""
    if req.profile is None:
        return line_set_from_recording(rec.meta, axis, span)
    tables = req.profile.tables
    if axis not in tables:
        return None, None
    others = [t for a, t in tables.items() if a != axis]
    ls, _why = line_set_from_tables(tables[axis], None if span is None else span[1] - span[0],
                                    others)
    return ls, None


@dataclass(frozen=True)
class _Excitation:
    """What the excitation fidelity of an axis needs: the profile's tables, the window, the
    motion's start, the judgement's limits, the stand's reach, the profile's scale."""

    tables: Mapping[str, Any]
    window: tuple[float, float]
    t0: float
    limits: FidelityLimits
    reach: StandReach
    scale: float = 1.0


def _run_excitation(profile: RunProfile,
                    window: tuple[float, float] | None) -> _Excitation | str | None:
    if not profile.tables or getattr(profile.motion, "segments", None):
        return None
    if window is None or profile.t_motion_start is None:
        return "no analysis window or motion start (the run did not finish)"
    return _Excitation(profile.tables, window, profile.t_motion_start,
                       profile.excitation_limits, profile.reach)


def _recorded_excitation(rec: Recording,
                         window: tuple[float, float] | None) -> _Excitation | str | None:
    """A recording whose profile gives harmonic tables: its tables re-synthesised, the bench
    config's ``run.excitation`` settings and ``stand.limits`` as recorded (else the defaults);
    None when there is nothing to judge, why when it cannot be judged."""
    meta = rec.meta
    prof = meta.get("profile")
    if not isinstance(prof, dict) or not isinstance(prof.get("spec"), dict):
        return None
    if prof["spec"].get("kind") == "sine_steps":
        return None  # its steps have their own table
    window = window if window is not None else rec.analysis_window
    t0 = motion_start(rec.events)
    if window is None or t0 is None:
        return ("the recording has no analysis window or motion_start event (the run did not "
                "finish)")
    try:
        seed, duration = meta.get("seed"), meta.get("duration_s")
        motion = synthesize(
            parse_profile(prof["spec"], prof.get("source")),
            duration_s=float(duration) if isinstance(duration, int | float) else None,
            seed=int(seed) if isinstance(seed, int) else None,
        )
    except (BenchError, OSError, ValueError, TypeError) as e:
        return f"the profile could not be re-synthesised ({e})"
    cfg: Any = meta.get("config") if isinstance(meta.get("config"), dict) else {}
    limits, reach = FidelityLimits(), None
    with contextlib.suppress(ValueError, TypeError, KeyError, AttributeError):  # older ones
        limits = limits_of(ExcitationConfig(**cfg["run"]["excitation"]))
    with contextlib.suppress(ValueError, TypeError, KeyError, AttributeError):
        reach = reach_of(StandLimits(**cfg["stand"]["limits"]))
    if reach is None:
        reach = StandReach(math.inf, math.inf, math.inf)
    scale = meta.get("scale")
    return _Excitation(dict(getattr(motion, "tables", None) or {}), window, t0, limits, reach,
                       float(scale) if isinstance(scale, int | float) else 1.0)


def _alarm(axis: str, fid: Fidelity) -> str | None:
    """The warning when a band of ``axis`` is beyond the alarm level (``run.excitation``)."""
    bad = breached(fid)
    if not bad:
        return None
    worst = fid.worst_band or {}
    return (f"excitation {fid.judgement.upper()} on {axis}: {len(bad)} band(s) beyond "
            f"±{fid.limits.alarm_db:g} dB, worst {worst.get('error_db', math.nan):+.2f} dB "
            f"at {worst.get('centre_hz', math.nan):.3g} Hz (run.excitation)")


def _steps(rec: Recording, req: EvaluationRequest, axis: str, res: AnalysisResult,
           pair: Pair) -> None:
    """A sine-steps profile: the linearity table of ``axis`` (``res.steps``) on the same
    samples, each step's whole full-amplitude cycles placed on the motion's start."""
    p = req.profile
    if p is None:
        sa, why = steps_for_recording(rec.meta, rec.events, axis, *pair)
        if why:
            res.warnings.append(why)
    else:
        if not getattr(p.motion, "segments", None) or p.t_motion_start is None:
            return
        wins = step_windows(p.motion, axis, p.t_motion_start)
        sa = analyze_steps(*pair, wins, spread_limit=p.spread_limit) if wins else None
    if sa is not None:
        attach_steps(res, sa)
        res.warnings.extend(sa.warnings)


def evaluate(recording: Recording | str | Path,
             request: EvaluationRequest | None = None) -> Evaluation:
    """The per-axis analysis of a recording (a ``Recording`` or its folder), as ``request``
    says (see the module's notes for the steps). Raises ``DataError`` (a missing axis, too few
    samples, an analysis that cannot be made) and ``IntegrityError``."""
    request = request if request is not None else EvaluationRequest()
    rec = recording if isinstance(recording, Recording) else load_recording(recording)
    if request.require_intact:
        rec.require_intact()  # the recording was altered after its run closed it
    opts, label = request.options, str(request.source or (
        rec.path if isinstance(recording, Recording) else recording))
    axes = list(rec.axes) if request.axes is None else list(request.axes)
    window = request.window
    span = window if window is not None else rec.analysis_window
    dep = request.departures  # RECORDED (a str): the recording's own
    departures = departures_of(rec, request.settle_s) if isinstance(dep, str) else dep
    out = Evaluation(rec)
    pairs: dict[str, Pair] = {}
    for axis in axes:
        pairs[axis] = _pair(rec, axis, window, opts.recording_timebase, label)
    profile_lines = {a: _profile_lines(rec, request, a, span) for a in axes}
    excitation: _Excitation | str | None = None
    if request.excitation:
        excitation = (_recorded_excitation(rec, window) if request.profile is None
                      else _run_excitation(request.profile, window))
    for axis in axes:
        lines: Any = opts.lines if opts.lines is not None else "auto"
        if opts.lines is None and opts.period_s is None:
            ls, why = profile_lines[axis]
            if ls is not None:
                lines = ls
            elif why:
                out.line_notes[axis] = f"lines not taken from the profile: {why}"
        try:
            res = analyze(*pairs[axis], max_lag_s=opts.max_lag_s, band_hz=opts.band_hz,
                          compensate_delay=opts.compensate_delay, timebase=opts.timebase,
                          reference_timebase=opts.reference_timebase, period_s=opts.period_s,
                          lines=lines, source=label, axis=axis, departures=departures,
                          **opts.extra)
        except DataError as e:
            if not request.label_errors:
                raise
            raise DataError(f"{label} [{axis}]: {e}") from None
        if axis in out.line_notes:
            res.warnings.append(out.line_notes[axis])
        if request.steps:
            _steps(rec, request, axis, res, pairs[axis])
        if isinstance(excitation, str):
            res.warnings.append(f"no excitation fidelity: {excitation}")
            out.fidelity[axis] = excitation
        elif excitation is not None and axis in excitation.tables:
            e_ = excitation
            try:
                fid = fidelity_of_table(pairs[axis][0], pairs[axis][1], e_.tables[axis],
                                        e_.window, e_.t0, limits=e_.limits, reach=e_.reach,
                                        scale=e_.scale)
            except DataError as e:
                res.warnings.append(f"no excitation fidelity: {e}")
                out.fidelity[axis] = str(e)
            else:
                res.excitation = fid.to_dict()
                res.warnings.extend(fid.warnings)
                out.fidelity[axis] = fid
                alarm = _alarm(axis, fid) if request.excitation_alarm else None
                if alarm:
                    res.warnings.append(alarm)
                    out.alarms[axis] = alarm
        out.results[axis] = res
    if request.cross_axis and opts.lines != "off":
        _cross_axis(rec, request, out, pairs, profile_lines, span, label)
    return out


def _cross_axis(rec: Recording, req: EvaluationRequest, out: Evaluation, pairs: dict[str, Pair],
                profile_lines: dict[str, tuple[LineSet | None, str | None]],
                span: tuple[float, float] | None, label: str) -> None:
    """A two-axis record: each output against the other axis's motion on the profile's lines
    (``result.cross_axis``), or a warning why not (the first axis whose lines are not known,
    when the recording's metadata says why)."""
    every = list(rec.axes)
    if len(every) < 2:
        return
    for a in every:  # an axis recorded but not asked for: its motion is still the input
        if a not in pairs:
            pairs[a] = _pair(rec, a, req.window, req.options.recording_timebase, label)
        if a not in profile_lines:
            profile_lines[a] = _profile_lines(rec, req, a, span)
    missing = next((profile_lines[a][1] for a in every if profile_lines[a][0] is None), None)
    lines = {a: ls for a, (ls, _) in profile_lines.items() if ls is not None}
    for axis, res in out.results.items():
        cross: dict[str, Any] | None = None
        why: str | None = f"no cross-axis estimate: {missing}" if missing else None
        if not missing:
            cross, why = cross_axis_for(pairs, lines, axis)
        res.cross_axis = cross
        if why:
            res.warnings.append(why)


def analyze_recording(path: str | Path | Recording, axis: str,
                      **options: Any) -> AnalysisResult:
    """Analyse one axis of a benchctl recording folder as ``benchctl analyze`` does (options as
    :func:`benchctl.analysis.analyze`; ``departures``: given, or ``None`` for nothing left
    out; ``lines``/``period_s``: instead of the profile's lines). Moved here from
    ``benchctl.analysis`` (which works on arrays and reads no recording)."""
    names = {f for f in EvaluationOptions.__dataclass_fields__ if f != "extra"}
    known = {k: options.pop(k) for k in list(options) if k in names}
    departures = options.pop("departures", RECORDED)
    source: str | None = options.pop("source", None)
    request = EvaluationRequest(axes=[axis], options=EvaluationOptions(**known, extra=options),
                                departures=departures, source=source)
    return evaluate(path, request).results[axis]


__all__ = [
    "RECORDED",
    "Evaluation",
    "EvaluationOptions",
    "EvaluationRequest",
    "RunProfile",
    "analyze_recording",
    "evaluate",
]
