"""Analysis core: the published method (eqs. 1–2), uncertainty and frequency response.

Public API::

    analyze(t_ref, x_ref_deg, t_dev, y_dev_deg, *, max_lag_s=None, band_hz=None,
            compensate_delay="none", timebase="given") -> AnalysisResult
    analyze_recording(path, axis, **same options) -> AnalysisResult
    load_csv_pair(...) / load_single_csv(...)  (see ``inputs``)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from benchctl.analysis.core import analyze, default_max_lag
from benchctl.analysis.result import AnalysisResult


def analyze_recording(path: str | Path, axis: str, **options: Any) -> AnalysisResult:
    """Analyse one axis of a benchctl recording folder (options as :func:`analyze`)."""
    from benchctl.recording import load_recording

    t_ref, x_ref, t_dev, y_dev = load_recording(path).pair(axis)
    options.setdefault("source", str(path))
    return analyze(t_ref, x_ref, t_dev, y_dev, axis=axis, **options)


__all__ = ["AnalysisResult", "analyze", "analyze_recording", "default_max_lag"]
