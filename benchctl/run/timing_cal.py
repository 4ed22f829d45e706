"""The bench's timing calibration: its stream-to-stream offset from a run of a reference of known
latency, and that offset stored, dated, in the bench config (``timing:``).

The procedure (docs/howto/timing-calibration.md): mount a reference whose response is a pure
delay ``L`` (certified), run any multisine profile as for a test (``benchctl run``), then
``benchctl timing calibrate RECORDING --reference-latency-s L --write CONFIG``. The recording's
instrument stream is set against the stand's over the profile's lines
(``benchctl.analysis.bench_timing.measure_delay``); the delay measured beyond ``L`` is what the
acquisition adds. A recording made with an offset already in its config was analysed with it
applied: the new offset adds what is still measured beyond ``L``.
"""

from __future__ import annotations

import datetime
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from benchctl.analysis.bench_timing import DelayFit, measure_delay
from benchctl.analysis.lines import line_set_from_recording
from benchctl.clock import REAL, Clock
from benchctl.errors import DataError
from benchctl.recording import Recording

#: a reference's gain this far from 1 is no pure delay: its phase would not be the bench's alone
MAX_GAIN_ERROR = 0.05


@dataclass(frozen=True)
class TimingCalibration:
    """One calibration: the offset to store (``offset_s``, s) and how it was found."""

    offset_s: float
    uncertainty_s: float
    measured_delay_s: float  # the reference's delay as this recording's analysis sees it
    reference_latency_s: float
    previous_offset_s: float  # applied when the recording was analysed
    axis: str
    fit: DelayFit
    recording: str
    date: datetime.date
    warnings: tuple[str, ...] = ()

    def reference_text(self, what: str | None = None) -> str:
        ref = what or "reference"
        return (f"{ref}, certified latency {self.reference_latency_s:g} s; recording "
                f"{Path(self.recording).name}, axis {self.axis}, {self.fit.n_lines} lines")

    def to_dict(self) -> dict[str, Any]:
        return {
            "offset_s": self.offset_s,
            "uncertainty_s": self.uncertainty_s,
            "measured_delay_s": self.measured_delay_s,
            "reference_latency_s": self.reference_latency_s,
            "previous_offset_s": self.previous_offset_s,
            "axis": self.axis,
            "n_lines": self.fit.n_lines,
            "gain": self.fit.gain,
            "phase_rms_rad": self.fit.phase_rms_rad,
            "recording": self.recording,
            "calibrated": self.date.isoformat(),
            "warnings": list(self.warnings),
        }


def calibrate_recording(
    rec: Recording,
    reference_latency_s: float,
    *,
    axis: str | None = None,
    date: datetime.date | None = None,
    clock: Clock = REAL,
) -> TimingCalibration:
    """The bench's offset from ``rec``, a run of a reference of latency ``reference_latency_s``,
    dated ``date`` (default: today on ``clock``).

    Raises ``DataError`` when the recording has no profile lines to measure on or no samples.
    """
    if not math.isfinite(reference_latency_s):
        raise DataError(f"reference latency {reference_latency_s!r}: expected a finite number")
    ax = axis or rec.axes[0]
    ls, why = line_set_from_recording(rec.meta, ax, rec.analysis_window)
    if ls is None:
        raise DataError(f"{rec.path}: no lines to measure the delay on: {why}")
    tr, xr, td, yd = rec.pair(ax)
    if len(tr) < 16 or len(td) < 16:
        raise DataError(f"{rec.path}: too few samples on axis {ax} ({len(tr)} stand, "
                        f"{len(td)} instrument)")
    res = float(getattr(td, "residual_s", math.nan))
    fit = measure_delay(tr, xr, td, yd, ls.harmonics / ls.period_s,
                        resolution_s=res if math.isfinite(res) else 0.0)
    prev = rec.timing_offset_s
    warnings = []
    if abs(fit.gain - 1.0) > MAX_GAIN_ERROR:
        warnings.append(f"the reference's gain is {fit.gain:.4f}, not 1: is it a pure delay? "
                        "(its phase is taken as the bench's and its latency's alone)")
    return TimingCalibration(
        offset_s=prev + fit.delay_s - reference_latency_s,
        uncertainty_s=fit.uncertainty_s,
        measured_delay_s=fit.delay_s,
        reference_latency_s=reference_latency_s,
        previous_offset_s=prev,
        axis=ax,
        fit=fit,
        recording=str(rec.path),
        date=date or clock.now_utc().date(),
        warnings=tuple(warnings),
    )


_TOP_KEY = re.compile(r"^[A-Za-z_][\w-]*\s*:")


def timing_section(cal: TimingCalibration, reference: str | None = None) -> str:
    """The ``timing:`` section for a bench config (YAML text, its own lines)."""
    ref = cal.reference_text(reference).replace('"', "'")
    return (
        "timing:                      # the bench's own stream-to-stream delay (benchctl timing "
        "calibrate)\n"
        f"  offset_s: {cal.offset_s:.7f}\n"
        f"  uncertainty_s: {cal.uncertainty_s:.7f}\n"
        f"  calibrated: {cal.date.isoformat()}\n"
        f'  reference: "{ref}"\n'
    )


def write_timing(config_text: str, section: str) -> str:
    """``config_text`` with its top-level ``timing:`` section replaced by ``section`` (appended
    when it has none); every other line, comments included, as it was."""
    lines = config_text.splitlines(keepends=True)
    start = next((i for i, ln in enumerate(lines) if re.match(r"^timing\s*:", ln)), None)
    if start is None:
        sep = "" if not config_text or config_text.endswith("\n") else "\n"
        return config_text + sep + section
    end = start + 1
    while end < len(lines) and not _TOP_KEY.match(lines[end]):
        end += 1
    # comment lines just before the next key belong to it, not to this section
    while end - 1 > start and lines[end - 1].lstrip().startswith("#") \
            and not lines[end - 1].startswith(" "):
        end -= 1
    return "".join(lines[:start]) + section + "".join(lines[end:])
