"""Analysis core: the published method (eqs. 1–2), uncertainty and frequency response.

Public API::

    analyze(t_ref, x_ref_deg, t_dev, y_dev_deg, *, max_lag_s=None, band_hz=None,
            compensate_delay="none", timebase="auto", reference_timebase="auto",
            lines="auto", period_s=None,
            departures=None) -> AnalysisResult
    departures_of(recording) -> Departures  (underruns and rejoins, see ``departures``)
    load_csv_pair(...) / load_single_csv(...)  (see ``inputs``)

The package works on arrays and reads no recording: turning a recording into the analysis's
arrays, lines and options is ``benchctl.evaluate`` (``evaluate``, ``analyze_recording``), the
one evaluation path above both.
"""

from __future__ import annotations

from benchctl.analysis.core import analyze
from benchctl.analysis.lines import LineSet, line_set_from_recording
from benchctl.analysis.result import AnalysisResult
from benchctl.analysis.spectra import default_max_lag

__all__ = [
    "AnalysisResult",
    "LineSet",
    "analyze",
    "default_max_lag",
    "line_set_from_recording",
]
