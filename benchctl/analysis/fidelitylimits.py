"""What the excitation fidelity is judged against: the judgement's settings (alarm and abort
levels, weak lines and bands, the interval wanted: ``FidelityLimits``, from ``run.excitation``),
the stand's reach (``StandReach``, from ``stand.limits``: a line needing more on its own is
unreachable) and the bands (base-10 third-octave bands, or given edges). Shared by the
whole-period estimate (:mod:`benchctl.analysis.excitation`) and the running one
(:mod:`benchctl.analysis.runningfidelity`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

ALARM_DB = 1.5
ABORT_DB = 3.0
WEAK_LINE_DB = -30.0  # lines below this (amplitude, re the strongest) are not judged
WEAK_BAND_DB = -20.0  # bands below this (power, re the strongest band) are not judged
MAX_CI_DB = 0.5  # a band is judged once its 95 % half-width is below this


@dataclass(frozen=True)
class FidelityLimits:
    """The judgement's settings (:mod:`benchctl.analysis.excitation`, step 6).
    ``band_edges_hz``: the bands' edges, ascending (None: third-octave bands)."""

    alarm_db: float = ALARM_DB
    abort_db: float = ABORT_DB
    weak_line_db: float = WEAK_LINE_DB
    weak_band_db: float = WEAK_BAND_DB
    max_ci_db: float = MAX_CI_DB
    band_edges_hz: tuple[float, ...] | None = None


@dataclass(frozen=True)
class StandReach:
    """The stand's limits on one axis: a line needing more on its own is unreachable."""

    angle_deg: float
    rate_deg_s: float
    accel_deg_s2: float

    def unreachable(self, freq_hz: NDArray[np.float64], amp_deg: NDArray[np.float64]
                    ) -> NDArray[np.bool_]:
        """Lines whose angle, rate or acceleration alone is beyond these limits."""
        w = 2.0 * np.pi * freq_hz
        return np.asarray((amp_deg > self.angle_deg) | (amp_deg * w > self.rate_deg_s)
                          | (amp_deg * w * w > self.accel_deg_s2))


def third_octave_bands(f_lo: float, f_hi: float) -> list[tuple[float, float, float]]:
    """``(lo, centre, hi)`` of the base-10 third-octave bands (centres ``10^(m/10)`` Hz,
    edges ``10^((m ∓ ½)/10)``) that hold a frequency in ``[f_lo, f_hi]`` (f_lo > 0)."""
    m_lo = math.floor(10.0 * math.log10(f_lo) + 0.5)
    m_hi = math.floor(10.0 * math.log10(f_hi) + 0.5)
    return [
        (10.0 ** ((m - 0.5) / 10.0), 10.0 ** (m / 10.0), 10.0 ** ((m + 0.5) / 10.0))
        for m in range(m_lo, m_hi + 1)
    ]


def bands_of(limits: FidelityLimits, freq: FloatArray) -> list[tuple[float, float, float]]:
    if limits.band_edges_hz is None:
        return third_octave_bands(float(freq.min()), float(freq.max()))
    e = limits.band_edges_hz
    return [(a, math.sqrt(a * b), b) for a, b in itertools.pairwise(e)]


def limits_of(cfg: Any) -> FidelityLimits:
    """The settings from a config section with the same fields (``run.excitation``)."""
    edges = getattr(cfg, "band_edges_hz", None)
    return FidelityLimits(
        alarm_db=float(cfg.alarm_db), abort_db=float(cfg.abort_db),
        weak_line_db=float(cfg.weak_line_db), weak_band_db=float(cfg.weak_band_db),
        max_ci_db=float(cfg.max_ci_db),
        band_edges_hz=None if edges is None else tuple(float(v) for v in edges),
    )


def reach_of(limits: Any) -> StandReach:
    """The stand's reach from its limits (``stand.limits``: angle_deg, rate_deg_s,
    accel_deg_s2)."""
    return StandReach(float(limits.angle_deg), float(limits.rate_deg_s),
                      float(limits.accel_deg_s2))
