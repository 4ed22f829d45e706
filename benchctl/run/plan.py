"""The motion on the stand loop's grid: the profile evaluated once at ``k / rate_hz``.

Pure computation, no I/O: the stand loop sends (or queues) ``values[axis][k]`` at slot k.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from benchctl.errors import ConfigError
from benchctl.harmonics import HarmonicTable
from benchctl.kinematics import profile_peaks
from benchctl.options import MAX_PROFILE_SAMPLES
from benchctl.run.state import RunState


@dataclass(frozen=True)
class MotionPlan:
    """The profile on the loop's grid: ``values[axis][k]`` is the angle at ``k·period_s``.
    Immutable: a plan changed (equalised, say) is a new plan."""

    axes: tuple[str, ...]
    period_s: float
    values: dict[str, NDArray[np.float64]]
    duration_s: float
    fade_in_s: float
    fade_out_s: float
    mode: str = "stream"
    tables: dict[str, HarmonicTable] | None = None
    # per axis: largest |rate| and |acceleration| of the point sequence (by differences)
    peaks: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def n_slots(self) -> int:
        return int(next(iter(self.values.values())).size)

    def at(self, t: float) -> dict[str, float]:
        """The profile at profile time ``t`` (linear between grid points; 0 outside)."""
        if t <= 0.0 or t >= self.duration_s or self.n_slots < 2:
            return dict.fromkeys(self.axes, 0.0)
        x = t / self.period_s
        i = min(int(x), self.n_slots - 2)
        w = x - i
        return {a: float(v[i] + w * (v[i + 1] - v[i])) for a, v in self.values.items()}

    def ending_at(self, k_stop: int, fade_s: float) -> MotionPlan:
        """The plan ended early: the points up to slot ``k_stop`` as they are, then the motion
        faded out over ``fade_s`` (the profile's own raised-cosine fade, so the rate stays
        continuous and the stand comes to rest at zero), nothing after. Pure; ``self`` is
        left as it is."""
        n_fade = max(2, math.ceil(fade_s / self.period_s - 1e-9))
        if not 0 <= k_stop < self.n_slots:
            raise ValueError(f"slot {k_stop} outside the plan's 0 … {self.n_slots - 1}")
        u = np.arange(n_fade + 1, dtype=np.float64) / n_fade
        w = 0.5 * (1.0 + np.cos(np.pi * u))  # 1 → 0, zero slope at both ends
        values = {}
        for a, v in self.values.items():
            tail = v[k_stop : k_stop + n_fade + 1]
            if tail.size < n_fade + 1:  # the plan ends before the fade would: hold its last
                tail = np.concatenate((tail, np.full(n_fade + 1 - tail.size, v[-1])))
            values[a] = np.concatenate((v[:k_stop], tail * w))
        duration = (k_stop + n_fade) * self.period_s
        peaks = {a: profile_peaks(v, self.period_s) for a, v in values.items()}
        return MotionPlan(self.axes, self.period_s, values, duration, self.fade_in_s,
                          n_fade * self.period_s, self.mode, self.tables, peaks)

    def state_at(self, t: float) -> RunState:
        if t < self.fade_in_s:
            return RunState.FADE_IN
        if t < self.duration_s - self.fade_out_s:
            return RunState.RUNNING
        return RunState.FADE_OUT


def setpoint_count(duration_s: float, rate_hz: float) -> float:
    """Setpoints per axis of a motion of ``duration_s`` on the grid ``k / rate_hz`` (k = 0 …
    duration·rate, as :func:`make_plan` makes them); ``inf`` when that is not a finite number."""
    product = duration_s * rate_hz
    if not math.isfinite(product):
        return math.inf
    return float(math.floor(product + 1e-9) + 1)


def check_setpoints(duration_s: float, rate_hz: float, where: str) -> None:
    """``ConfigError`` naming ``where`` when a motion of ``duration_s`` at ``rate_hz`` has more
    than ``MAX_PROFILE_SAMPLES`` setpoints per axis (the plan would not fit in memory: a day at
    1000 Hz is 7.5 GB of arrays). Cheap: called before anything is synthesised."""
    n = setpoint_count(duration_s, rate_hz)
    if not (math.isfinite(rate_hz) and rate_hz > 0 and n <= MAX_PROFILE_SAMPLES):
        raise ConfigError(
            f"{where}: {n:.4g} setpoints at {rate_hz:g} Hz (the stand's rate) over "
            f"{duration_s:g} s, per axis; expected at most {MAX_PROFILE_SAMPLES} (a shorter "
            "duration or a lower rate)"
        )


def make_plan(
    evaluate: Callable[[NDArray[np.float64]], Mapping[str, NDArray[np.float64]]],
    axes: tuple[str, ...],
    duration_s: float,
    rate_hz: float,
    fade_in_s: float,
    fade_out_s: float,
    mode: str = "stream",
    tables: dict[str, HarmonicTable] | None = None,
) -> MotionPlan:
    """Evaluate the profile once on the loop's grid ``k / rate_hz`` for k = 0 … duration·rate;
    ``ConfigError`` before anything is evaluated when that is over ``MAX_PROFILE_SAMPLES``."""
    check_setpoints(duration_s, rate_hz, "motion plan")
    period = 1.0 / rate_hz
    n = math.floor(duration_s * rate_hz + 1e-9) + 1
    t = np.arange(n, dtype=np.float64) * period
    vals = evaluate(t)
    values = {a: np.asarray(vals[a], dtype=float) for a in axes}
    peaks = {a: profile_peaks(v, period) for a, v in values.items()}
    return MotionPlan(
        axes, period, values, duration_s, fade_in_s, fade_out_s, mode, tables, peaks
    )
