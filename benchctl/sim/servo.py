"""Physics of one stand axis: a second-order position servo with rate and acceleration limits.

Pure computation, no I/O, no clock. The simulated stand calls :func:`servo_step` once per tick
of length ``tick_s`` (semi-implicit Euler, exactly what :meth:`ServoModel.response` describes):

    a_k     = clip(ω_n² (r_k − x_k) − 2 ζ ω_n v_k, ±accel_limit)
    v_{k+1} = clip(v_k + a_k T, ±rate_limit)
    x_{k+1} = x_k + v_{k+1} T

with ω_n = 2π · natural_freq_hz. Angles in degrees, rates deg/s, accelerations deg/s².
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray


@dataclass(frozen=True)
class ServoModel:
    """Parameters of one axis servo. ``natural_freq_hz`` is the closed loop's natural frequency."""

    natural_freq_hz: float
    damping: float
    rate_limit_deg_s: float
    accel_limit_deg_s2: float
    tick_s: float

    def __post_init__(self) -> None:
        for name in (
            "natural_freq_hz",
            "damping",
            "rate_limit_deg_s",
            "accel_limit_deg_s2",
            "tick_s",
        ):
            if not getattr(self, name) > 0:
                raise ValueError(f"ServoModel.{name} must be > 0, got {getattr(self, name)}")
        wn_t = 2 * math.pi * self.natural_freq_hz * self.tick_s
        if wn_t > 0.5:
            raise ValueError(
                f"tick too long for the servo: ω_n·T = {wn_t:.3f} > 0.5 "
                f"(natural_freq_hz={self.natural_freq_hz}, tick_s={self.tick_s})"
            )

    @functools.cached_property
    def omega_n(self) -> float:
        return 2.0 * math.pi * self.natural_freq_hz

    def response(self, f_hz: ArrayLike) -> NDArray[np.complex128]:
        """Small-signal frequency response angle/setpoint of the ticked servo.

        Parameters
        ----------
        f_hz : array_like
            Frequencies in Hz (below the tick's Nyquist frequency).

        Returns
        -------
        ndarray of complex
            H(e^{jωT}) of the discrete system above (limits not reached):

            H(z) = ω_n² T² z / ((z − 1)(z − 1 + 2ζ ω_n T) + ω_n² T² z)

            |H| is the gain, arg H the phase (radians, negative = lag). H(0) = 1.

        Notes
        -----
        For ω_n T ≪ 1 this tends to the continuous ω_n² / (ω_n² − ω² + 2jζω_nω).
        """
        t = self.tick_s
        z = np.exp(2j * np.pi * np.asarray(f_hz, dtype=float) * t)
        k = (self.omega_n * t) ** 2
        c = 2.0 * self.damping * self.omega_n * t
        return np.asarray(k * z / ((z - 1.0) * (z - 1.0 + c) + k * z), dtype=np.complex128)


@dataclass
class AxisState:
    """True state of one axis: angle (deg) and rate (deg/s)."""

    angle_deg: float = 0.0
    rate_deg_s: float = 0.0


def servo_step(m: ServoModel, s: AxisState, target_deg: float) -> None:
    """Advance ``s`` by one tick towards ``target_deg`` (in place)."""
    wn = m.omega_n
    a = wn * wn * (target_deg - s.angle_deg) - 2.0 * m.damping * wn * s.rate_deg_s
    a = min(max(a, -m.accel_limit_deg_s2), m.accel_limit_deg_s2)
    v = s.rate_deg_s + a * m.tick_s
    v = min(max(v, -m.rate_limit_deg_s), m.rate_limit_deg_s)
    s.rate_deg_s = v
    s.angle_deg += v * m.tick_s


def brake_step(m: ServoModel, s: AxisState, accel_deg_s2: float | None = None) -> None:
    """Decelerate ``s`` towards rest at ``accel_deg_s2`` (default the servo's acceleration
    limit) for one tick (in place)."""
    dv = (m.accel_limit_deg_s2 if accel_deg_s2 is None else accel_deg_s2) * m.tick_s
    v = s.rate_deg_s
    v = 0.0 if abs(v) <= dv else v - math.copysign(dv, v)
    s.rate_deg_s = v
    s.angle_deg += v * m.tick_s


def quantise(angle_deg: float, resolution_deg: float) -> float:
    """The encoder reading of ``angle_deg``: a multiple of ``resolution_deg`` (0: exact)."""
    if resolution_deg <= 0:
        return angle_deg
    return round(angle_deg / resolution_deg) * resolution_deg
