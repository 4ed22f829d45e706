"""Motion profiles: from a sea state, a ship or a recording to a safe, reproducible stand motion.

Public API (the run layer relies on these; see each docstring):

- ``load_profile(path) -> Profile`` — validated profile (``ConfigError`` naming file and field).
- ``synthesize(profile, *, duration_s=None, seed=None, setpoint_rate_hz=None) -> Motion``.
- ``check_motion(motion, limits, *, scale_to_fit=False, rate_hz=100.0) -> MotionCheck``
  (``LimitError`` "needed X, allowed Y" when over and not scaling).

Modules: ``spectra`` (wave spectra), ``roll`` (roll models), ``synthesis`` (multisine lines,
phases, crest factor, fast sampling), ``motion`` (the Motion classes), ``records`` (spectrum of
a recording), ``schema`` / ``loader`` (files), ``design`` (profile → motion), ``checks`` (limits).
"""

from __future__ import annotations

from benchctl.profiles.checks import MotionCheck, Peaks, check_motion, measure_peaks
from benchctl.profiles.design import choose_period, synthesize
from benchctl.profiles.loader import Profile, load_profile, parse_profile
from benchctl.profiles.motion import Motion, StepMotion, TableMotion
from benchctl.profiles.synthesis import sample_times, tables_to_csv

__all__ = [
    "Motion",
    "MotionCheck",
    "Peaks",
    "Profile",
    "StepMotion",
    "TableMotion",
    "check_motion",
    "choose_period",
    "load_profile",
    "measure_peaks",
    "parse_profile",
    "sample_times",
    "synthesize",
    "tables_to_csv",
]
