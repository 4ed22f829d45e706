"""Checks before motion: peak angle, rate and acceleration against the stand's limits.

Pure computation. The peaks are measured on the samples the stand will get (the motion and
its exact first and second time derivatives evaluated on the setpoint grid ``i / rate_hz``),
fades included.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from benchctl.errors import LimitError
from benchctl.profiles.motion import Motion
from benchctl.profiles.synthesis import sample_times

if TYPE_CHECKING:  # a type only: the bench config's pydantic models cost `analyze` ~0.5 s
    from benchctl.config import StandLimits

_QUANTITIES = (
    ("angle_deg", "peak angle", "deg", "angle_deg"),
    ("rate_deg_s", "peak rate", "deg/s", "rate_deg_s"),
    ("accel_deg_s2", "peak acceleration", "deg/s²", "accel_deg_s2"),
)


@dataclass(frozen=True)
class Peaks:
    """Largest |angle| (deg), |rate| (deg/s) and |acceleration| (deg/s²) of one axis."""

    angle_deg: float
    rate_deg_s: float
    accel_deg_s2: float

    def to_dict(self) -> dict[str, float]:
        return {
            "angle_deg": self.angle_deg,
            "rate_deg_s": self.rate_deg_s,
            "accel_deg_s2": self.accel_deg_s2,
        }


@dataclass(frozen=True)
class MotionCheck:
    """Result of :func:`check_motion`: the motion to send (scaled if asked), its peaks per axis,
    the scale factor applied (1.0 when none), the limits and the check rate."""

    motion: Motion
    peaks: dict[str, Peaks]
    scale: float
    limits: StandLimits
    rate_hz: float
    unscaled_peaks: dict[str, Peaks]

    def to_dict(self) -> dict[str, object]:
        return {
            "ok": True,
            "scale": self.scale,
            "rate_hz": self.rate_hz,
            "limits": self.limits.model_dump(),
            "peaks": {a: p.to_dict() for a, p in self.peaks.items()},
            "unscaled_peaks": {a: p.to_dict() for a, p in self.unscaled_peaks.items()},
        }


def measure_peaks(motion: Motion, rate_hz: float) -> dict[str, Peaks]:
    """Peaks of the motion sampled at ``rate_hz`` over ``[0, duration]``, per axis."""
    if not rate_hz > 0:
        raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
    t = sample_times(motion.duration_s, rate_hz)
    d = [motion.evaluate(t, k) for k in range(3)]
    return {
        a: Peaks(
            float(np.max(np.abs(d[0][a]))),
            float(np.max(np.abs(d[1][a]))),
            float(np.max(np.abs(d[2][a]))),
        )
        for a in motion.axes
    }


def exceedances(
    peaks: dict[str, Peaks], limits: StandLimits
) -> list[tuple[str, str, float, float, str]]:
    """(axis, quantity, needed, allowed, unit) for every peak above its limit."""
    out = []
    for axis, p in peaks.items():
        for attr, label, unit, lim in _QUANTITIES:
            needed, allowed = getattr(p, attr), getattr(limits, lim)
            if needed > allowed:
                out.append((axis, label, needed, allowed, unit))
    return out


def check_motion(
    motion: Motion, limits: StandLimits, *, scale_to_fit: bool = False, rate_hz: float = 100.0
) -> MotionCheck:
    """Check a motion against the stand's per-axis limits before anything moves.

    Parameters
    ----------
    motion : Motion
        From :func:`benchctl.profiles.synthesize`.
    limits : benchctl.config.StandLimits
        ``angle_deg``, ``rate_deg_s``, ``accel_deg_s2``, applying to each axis.
    scale_to_fit : bool
        When a peak is over, scale the whole motion down (amplitudes × s, so angle, rate and
        acceleration all × s) by ``s = min(allowed/needed)`` rounded down to 4 significant
        digits, instead of refusing.
    rate_hz : float
        The stand's setpoint rate: peaks are measured on that sample grid.

    Returns
    -------
    MotionCheck
        ``motion`` (scaled or not), ``peaks`` per axis, ``scale``.

    Raises
    ------
    LimitError
        When over a limit and not scaling: one line per exceedance, "needed X, allowed Y".
    """
    peaks = measure_peaks(motion, rate_hz)
    over = exceedances(peaks, limits)
    if not over:
        return MotionCheck(motion, peaks, 1.0, limits, rate_hz, peaks)
    if not scale_to_fit:
        lines = [
            f"axis {a}: {label} needed {needed:.3f} {unit}, allowed {allowed:.3f} {unit}"
            for a, label, needed, allowed, unit in over
        ]
        ratio = min(allowed / needed for _, _, needed, allowed, _ in over)
        raise LimitError(
            f"motion {motion.name!r} exceeds the stand limits (checked at {rate_hz:g} Hz):\n  "
            + "\n  ".join(lines)
            + f"\n  scaling by {_round_down(ratio):.4g} would fit (--scale-to-fit)"
        )
    ratio = min(allowed / needed for _, _, needed, allowed, _ in over)
    scale = _round_down(ratio)
    scaled = motion.scaled(scale)
    new_peaks = measure_peaks(scaled, rate_hz)
    still = exceedances(new_peaks, limits)
    if still:  # cannot happen for a linear scale; never send a motion that was not verified
        a, label, needed, allowed, unit = still[0]
        raise LimitError(
            f"axis {a}: {label} needed {needed:.3f} {unit}, allowed {allowed:.3f} {unit} "
            "after scaling"
        )
    return MotionCheck(scaled, new_peaks, scale, limits, rate_hz, peaks)


def _round_down(x: float) -> float:
    """Round down to 4 significant digits (so a scaled peak lands strictly under its limit)."""
    if x <= 0:
        return 0.0
    e = math.floor(math.log10(x)) - 3
    return math.floor(x / 10.0**e * (1 - 1e-12)) * 10.0**e
