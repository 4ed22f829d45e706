"""The input ranges: what a stream's instants and angles must be for the analysis to take it.

Finite, strictly increasing instants, at least ``MIN_SAMPLES``; ``|t| ≤ MAX_ABS_TIME_S``, a
median step within ``MIN_STEP_S … MAX_STEP_S`` and a grid of at most ``MAX_GRID_FACTOR`` × the
samples and ``MAX_GRID_SLOTS`` slots; finite angles, ``|angle| ≤ MAX_ABS_ANGLE_DEG``, not
constant. Beyond them a stream is refused (``DataError``), not analysed
(``docs/reference/analyze.md``, "Input ranges"). Used by :mod:`benchctl.analysis.align` and
by the CSV reader (:mod:`benchctl.analysis.inputs`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from benchctl.errors import DataError

FloatArray = NDArray[np.float64]

MIN_SAMPLES = 64
# Input ranges (docs/reference/analyze.md, "Input ranges"): beyond them a stream is refused,
# not analysed
MAX_GRID_FACTOR = 100  # a stream's grid (span / median step): at most 100× its samples …
MAX_GRID_SLOTS = 10_000_000  # … and at most 10 million slots
MIN_STEP_S = 1e-6  # median step at least 1 µs …
MAX_STEP_S = 1e6  # … and at most 10⁶ s
MAX_ABS_TIME_S = 1e12  # |time| at most 10¹² s
MAX_ABS_ANGLE_DEG = 1e6  # |angle| at most 10⁶ deg


def check_times(t: FloatArray, name: str) -> None:
    """Raise ``DataError`` unless ``t`` is finite and strictly increasing."""
    if len(t) < MIN_SAMPLES:
        raise DataError(f"{name}: {len(t)} sample{'s' if len(t) != 1 else ''}, at least "
                        f"{MIN_SAMPLES} are needed")
    bad = ~np.isfinite(t)
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(f"{name}: time at sample {i} is {t[i]}, expected a finite number")
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0)) + 1
        what = "duplicate" if d[i - 1] == 0 else "decreasing"
        raise DataError(
            f"{name}: {what} timestamp at sample {i}: {t[i]!r} after {t[i - 1]!r}; "
            "times must be strictly increasing"
        )


def check_grid(t: FloatArray, name: str, where: Callable[[int], str] | None = None) -> None:
    """Raise ``DataError`` unless the instants ``t`` (finite, increasing) are within the input
    ranges: ``|t| ≤ MAX_ABS_TIME_S``, a median step within ``MIN_STEP_S … MAX_STEP_S``, and a
    grid (span / median step) of at most ``MAX_GRID_FACTOR`` × the samples and
    ``MAX_GRID_SLOTS`` slots (a wild time or a huge gap would make an astronomically long
    grid). ``where(i)`` names sample ``i`` in messages (default ``sample i``)."""
    at = where or (lambda i: f"sample {i}")
    big = np.abs(t) > MAX_ABS_TIME_S
    if big.any():
        i = int(np.argmax(big))
        raise DataError(
            f"{name}: {at(i)}: time {float(t[i])!r}; expected |time| ≤ {MAX_ABS_TIME_S:g} s"
        )
    d = np.diff(t)
    step = float(np.median(d))
    if not MIN_STEP_S <= step <= MAX_STEP_S:
        raise DataError(
            f"{name}: median time step {step!r} s; expected {MIN_STEP_S:g} … {MAX_STEP_S:g} s"
        )
    slots = float(t[-1] - t[0]) / step + 1.0
    limit = min(MAX_GRID_FACTOR * len(t), MAX_GRID_SLOTS)
    if slots > limit:
        i = int(np.argmax(d)) + 1
        raise DataError(
            f"{name}: {at(i)}: time {float(t[i])!r} after {float(t[i - 1])!r}, a gap of "
            f"{d[i - 1] / step:.4g} "
            f"median steps ({step:.6g} s): the record would span {slots:.4g} steps for "
            f"{len(t)} samples; expected at most {limit} ({MAX_GRID_FACTOR}× the samples, "
            f"never more than {MAX_GRID_SLOTS})"
        )


def check_values(v: FloatArray, name: str) -> None:
    """Raise ``DataError`` on NaN/inf, ``|angle| > MAX_ABS_ANGLE_DEG`` or a constant signal."""
    bad = ~np.isfinite(v) | (np.abs(v) > MAX_ABS_ANGLE_DEG)
    if bad.any():
        i = int(np.argmax(bad))
        raise DataError(
            f"{name}: value at sample {i} is {v[i]}, expected a finite angle, "
            f"|angle| ≤ {MAX_ABS_ANGLE_DEG:g} deg"
        )
    if float(np.ptp(v)) == 0.0:
        raise DataError(f"{name}: the signal is constant ({float(v[0])!r} deg); nothing to analyse")
