"""Kinematics of commanded stand motion: the setpoint check, the stop ramp, the rejoin path.

Pure computation, no I/O, no clock. Angles in degrees, rates deg/s, accelerations deg/s².

**A setpoint sequence as the stand plays it.** A stand takes position points at a fixed period
T (its own clock): a streaming stand moves its servo target from one setpoint to the next over
one period; a buffered stand (trajectory queue) interpolates linearly between queued points
spaced T. So the commanded motion is judged on the *sequence*: the rate of a step is
``(x_k − x_{k−1}) / T`` and the acceleration the change of that rate over T — never the host's
send intervals, so host jitter can never fail a valid profile. When a streaming stand got no
setpoint for longer than :data:`HELD_AFTER_PERIODS` periods it has held its last setpoint: its
commanded rate is then 0, and the next step is judged from rest (a host that does not know this
gets :class:`StaleSetpoint`, nothing is sent, and it plans a rejoin from rest).

**Leaving a state that is already over a limit.** A stop planned from the stand's *measured*
state may start beyond a limit (an overshoot measured at 31° against 30°, a rate of 33°/s against
30°/s). A step that does not move further out — |angle| not growing, |rate| not growing — is
accepted there; anything that moves further out is refused as always. This is what lets the safe
stop be accepted whatever happened before, without ever accepting motion away from safety.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from benchctl.errors import LimitError

HELD_AFTER_PERIODS = 1.5  # no setpoint for longer than this many periods: the stand has held
_REL_TOL = 1e-9


@dataclass(frozen=True)
class Limits:
    """Per-axis limits: angle (deg), rate (deg/s), acceleration (deg/s²)."""

    angle_deg: float
    rate_deg_s: float
    accel_deg_s2: float


@dataclass(frozen=True)
class AxisCommand:
    """The last commanded point of one axis: its angle and the rate of the step that led to it."""

    angle_deg: float
    rate_deg_s: float


class StaleSetpoint(LimitError):
    """The stand held its last setpoint (no setpoint for too long): the next step is judged from
    rest, and this one would need more acceleration than allowed. Nothing was sent; plan a
    rejoin from rest (``StandLoop`` does)."""


def check_step(
    axis: str,
    prev: AxisCommand,
    x_deg: float,
    limits: Limits,
    period_s: float,
    *,
    held: bool = False,
) -> AxisCommand:
    """Judge one setpoint ``x_deg`` after ``prev`` one period ``period_s`` earlier.

    Returns the new :class:`AxisCommand`; raises :class:`LimitError` (needed vs allowed) when
    the step breaks a limit, :class:`StaleSetpoint` when it breaks the acceleration limit only
    because the stand has held (``held``: its rate is 0, not ``prev.rate_deg_s``).
    """
    x = float(x_deg)
    if not math.isfinite(x):
        raise LimitError(f"setpoint {axis} = {x}: not a finite angle")
    tol = 1 + _REL_TOL
    if abs(x) > limits.angle_deg * tol and abs(x) > abs(prev.angle_deg):
        raise LimitError(
            f"setpoint {axis} = {x:.4f}°: needs |angle| {abs(x):.4f}°, allowed {limits.angle_deg}°"
        )
    v0 = 0.0 if held else prev.rate_deg_s
    v = (x - prev.angle_deg) / period_s
    if abs(v) > limits.rate_deg_s * tol and not (v * v0 >= 0 and abs(v) <= abs(v0)):
        raise LimitError(
            f"setpoint {axis} = {x:.4f}° after {prev.angle_deg:.4f}° one period "
            f"({period_s * 1e3:.1f} ms) earlier: needs rate {abs(v):.3f}°/s, allowed "
            f"{limits.rate_deg_s}°/s"
        )
    acc = (v - v0) / period_s
    if abs(acc) > limits.accel_deg_s2 * tol:
        cls = StaleSetpoint if held and abs(v - prev.rate_deg_s) / period_s <= (
            limits.accel_deg_s2 * tol
        ) else LimitError
        what = " (the stand held its last setpoint: its rate is 0)" if held else ""
        raise cls(
            f"setpoint {axis} = {x:.4f}°: rate changes {v0:.3f} → {v:.3f}°/s in one period "
            f"({period_s * 1e3:.1f} ms){what}: needs acceleration {abs(acc):.2f}°/s², "
            f"allowed {limits.accel_deg_s2}°/s²"
        )
    return AxisCommand(x, v)


def check_sequence(
    axis: str, start: AxisCommand, points_deg: NDArray[np.float64], limits: Limits, period_s: float
) -> AxisCommand:
    """:func:`check_step` over consecutive points (each one period after the last)."""
    prev = start
    for x in points_deg:
        prev = check_step(axis, prev, float(x), limits, period_s)
    return prev


def plan_ramp_to_zero(
    x0_deg: float, v0_deg_s: float, rate_deg_s: float, accel_deg_s2: float, dt_s: float
) -> NDArray[np.float64]:
    """Points every ``dt_s`` that bring an axis from angle x0, rate v0 to rest at 0.

    Each step changes the rate by at most ``accel_deg_s2``·dt and keeps it within
    ``rate_deg_s`` (a current rate above that is first brought down at the acceleration limit);
    the target rate is the largest that can still stop at zero, sign(−x)·min(rate, √(2a|x|)).
    The last point is exactly 0, reached with a step that is itself within the limits.

    Returns
    -------
    ndarray
        Angles in degrees, one per period after the start (the start itself excluded).
    """
    if not (rate_deg_s > 0 and accel_deg_s2 > 0 and dt_s > 0):
        raise ValueError("rate_deg_s, accel_deg_s2 and dt_s must be > 0")
    if not (math.isfinite(x0_deg) and math.isfinite(v0_deg_s)):
        raise ValueError(f"plan_ramp_to_zero: start ({x0_deg}, {v0_deg_s}) is not finite")
    x, v = float(x0_deg), float(v0_deg_s)
    dv = accel_deg_s2 * dt_s
    out: list[float] = []
    for _ in range(10_000_000):
        # finish when one step lands on 0 and the next holds there, both within the limits
        if abs(x) <= dv * dt_s and abs(x / dt_s + v) <= dv:
            out.append(0.0)
            return np.asarray(out)
        # braking distance from the rate after this step, with the discrete ramp's extra step
        v_des = -math.copysign(
            min(rate_deg_s, max(0.0, math.sqrt(2.0 * accel_deg_s2 * abs(x) + 0.25 * dv * dv)
                                - 0.5 * dv)),
            x,
        )
        v += min(max(v_des - v, -dv), dv)
        x += v * dt_s
        out.append(x)
    raise ValueError("plan_ramp_to_zero did not converge")  # pragma: no cover


@dataclass(frozen=True)
class Rejoin:
    """A path back onto the profile after missed slots: ``points[axis][i]`` is commanded at
    profile slot ``first_slot + i``; from ``first_slot + n`` on the profile itself is sent."""

    first_slot: int
    points: dict[str, NDArray[np.float64]]

    @property
    def n(self) -> int:
        return max((p.size for p in self.points.values()), default=0)


def profile_peaks(values: NDArray[np.float64], period_s: float) -> tuple[float, float]:
    """Largest |rate| and |acceleration| of a point sequence, by differences over ``period_s``."""
    if values.size < 2:
        return 0.0, 0.0
    v = np.diff(values) / period_s
    a = np.diff(v) / period_s if v.size > 1 else np.zeros(1)
    return float(np.max(np.abs(v))), float(np.max(np.abs(a), initial=0.0))


#: the share of the room the profile leaves under the limits that a rejoin path may use
REJOIN_SHARE = 0.8


def plan_rejoin(
    profile: Mapping[str, NDArray[np.float64]],
    slot: int,
    last: Mapping[str, AxisCommand],
    limits: Limits,
    period_s: float,
    peaks: Mapping[str, tuple[float, float]],
) -> Rejoin:
    """A path from the last commanded state onto the profile, within the limits.

    The profile is rejoined at ``slot``: point i of the path is the profile at slot ``slot + i``
    plus a deviation e_i that starts at the gap between the last command and the profile
    (e_{−1} = x_last − p[slot−1], with the matching rate difference) and comes to zero by
    :func:`plan_ramp_to_zero` within ``REJOIN_SHARE`` of the room the profile leaves — the
    limits minus the profile's own peak rate and acceleration (``peaks[axis]``). The whole
    path is then checked step by step against the limits (:func:`check_step`); ``LimitError``
    if no path fits.
    """
    out: dict[str, NDArray[np.float64]] = {}
    for a, p in profile.items():
        n_p = p.size
        prev = last[a]
        k0 = min(max(slot, 1), n_p - 1)
        p_prev = float(p[k0 - 1])
        v_prev = (p_prev - float(p[k0 - 2])) / period_s if k0 >= 2 else 0.0
        d0 = prev.angle_deg - p_prev
        dv0 = prev.rate_deg_s - v_prev
        rate_peak, acc_peak = peaks[a]
        room_v = limits.rate_deg_s - rate_peak
        room_a = limits.accel_deg_s2 - acc_peak
        if room_v <= 0.02 * limits.rate_deg_s or room_a <= 0.02 * limits.accel_deg_s2:
            raise LimitError(
                f"rejoin {a}: the profile uses {rate_peak:.3f}°/s and {acc_peak:.3f}°/s² of "
                f"the limits {limits.rate_deg_s}°/s, {limits.accel_deg_s2}°/s²: no room left "
                "to rejoin it after missed setpoints (use a buffered stand or a smaller profile)"
            )
        if abs(d0) < 1e-12 and abs(dv0) < 1e-9:
            out[a] = np.zeros(0)
            continue
        # REJOIN_SHARE of that room: the stand's servo follows the path a few per cent over
        # its acceleration where the path starts (a rejoin from rest at the full room met the
        # limit at 102.8 % in the safety campaign)
        dev = plan_ramp_to_zero(d0, dv0, REJOIN_SHARE * room_v, REJOIN_SHARE * room_a, period_s)
        ks = np.minimum(np.arange(k0, k0 + dev.size), n_p - 1)
        path = p[ks] + dev
        check_sequence(a, prev, path, limits, period_s)
        out[a] = path
    return Rejoin(min(max(slot, 1), min(p.size for p in profile.values()) - 1), out)


__all__ = [
    "HELD_AFTER_PERIODS",
    "AxisCommand",
    "Limits",
    "Rejoin",
    "StaleSetpoint",
    "check_sequence",
    "check_step",
    "plan_ramp_to_zero",
    "plan_rejoin",
    "profile_peaks",
]
