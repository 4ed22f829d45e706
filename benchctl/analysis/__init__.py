"""Analysis core: the published method (eqs. 1–2), uncertainty and frequency response.

Public API::

    analyze(t_ref, x_ref_deg, t_dev, y_dev_deg, *, max_lag_s=None, band_hz=None,
            compensate_delay="none", timebase="auto", reference_timebase="auto",
            lines="auto", period_s=None,
            departures=None) -> AnalysisResult
    analyze_recording(path, axis, **same options) -> AnalysisResult
    departures_of(recording) -> Departures  (underruns and rejoins, see ``departures``)
    load_csv_pair(...) / load_single_csv(...)  (see ``inputs``)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from benchctl.analysis.core import analyze, default_max_lag
from benchctl.analysis.lines import LineSet, line_set_from_recording
from benchctl.analysis.result import AnalysisResult


def analyze_recording(path: str | Path, axis: str, **options: Any) -> AnalysisResult:
    """Analyse one axis of a benchctl recording folder (options as :func:`analyze`).

    The line-wise estimate uses the lines of the recording's profile (re-synthesised from
    its metadata: profile, seed, duration) unless ``lines`` or ``period_s`` is given; when
    they cannot be re-synthesised, a warning says why and the lines are detected as for any
    record. A recording of a ``sine_steps`` profile also gets its linearity table
    (``result.steps``, :mod:`benchctl.analysis.steps`). Where the stand's motion was not
    the profile's (its underruns and rejoins, :mod:`benchctl.analysis.departures`) is left out
    unless ``departures`` is given (``None``: nothing left out).
    """
    from benchctl.analysis.departures import departures_of
    from benchctl.recording import load_recording

    rec = load_recording(path)
    rec.require_intact()  # IntegrityError: the recording was altered after its run closed it
    t_ref, x_ref, t_dev, y_dev = rec.pair(axis)
    options.setdefault("source", str(path))
    note = ""
    if "lines" not in options and options.get("period_s") is None:
        ls, why = line_set_from_recording(rec.meta, axis, rec.analysis_window)
        if ls is not None:
            options["lines"] = ls
        else:
            note = f"lines not taken from the profile: {why}"
    options.setdefault("departures", departures_of(rec))
    result = analyze(t_ref, x_ref, t_dev, y_dev, axis=axis, **options)
    if note:
        result.warnings.append(note)
    if options.get("lines") != "off":  # a two-axis record: this output against the other axis
        from benchctl.analysis.crossaxis import recording_cross_axis

        result.cross_axis, why_cross = recording_cross_axis(rec, axis)
        if why_cross:
            result.warnings.append(why_cross)
    from benchctl.analysis.steps import attach_steps, steps_for_recording

    steps, why = steps_for_recording(rec.meta, rec.events, axis, t_ref, x_ref, t_dev, y_dev)
    if why:
        result.warnings.append(why)
    if steps is not None:
        attach_steps(result, steps)
        result.warnings.extend(steps.warnings)
    return result


__all__ = [
    "AnalysisResult",
    "LineSet",
    "analyze",
    "analyze_recording",
    "default_max_lag",
    "line_set_from_recording",
]
