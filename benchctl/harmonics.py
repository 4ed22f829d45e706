"""A harmonic table: the stand motion as a sum of cosines with a smooth fade in and out.

Pure computation, no I/O. This is the one definition of a polyharmonic motion shared by the
synthesis (``benchctl.profiles.synthesis``), the stand driver (table upload), and the simulated
stand (which plays an uploaded table itself), so all three agree to the last bit.

    x(t) = e(t) · Σ_k A_k cos(2π f_k t + φ_k),   0 ≤ t ≤ duration

with the envelope e(t) a raised-cosine fade: 0 → 1 over ``fade_in_s``, 1 → 0 over the last
``fade_out_s``, and 1 between. Angles in degrees, frequencies in Hz, phases in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

_CHUNK = 65536


def fade_envelope(
    t_s: ArrayLike, duration_s: float, fade_in_s: float, fade_out_s: float, derivative: int = 0
) -> FloatArray:
    """Raised-cosine fade envelope and its first two derivatives (``derivative`` 0, 1 or 2).

    Zero outside ``[0, duration_s]``. The envelope and its first derivative are continuous, so a
    faded motion starts and ends at rest with zero rate.
    """
    t = np.asarray(t_s, dtype=float)
    out = np.zeros_like(t)
    inside = (t >= 0.0) & (t <= duration_s)
    out[inside] = 1.0 if derivative == 0 else 0.0
    for start, length, sign in ((0.0, fade_in_s, 1.0), (duration_s - fade_out_s, fade_out_s, -1.0)):
        if length <= 0.0:
            continue
        sel = (t >= start) & (t <= start + length) & inside
        u = (t[sel] - start) / length  # 0..1 across the fade
        w = np.pi / length
        if derivative == 0:
            val = 0.5 * (1.0 - np.cos(np.pi * u)) if sign > 0 else 0.5 * (1.0 + np.cos(np.pi * u))
        elif derivative == 1:
            val = sign * 0.5 * w * np.sin(np.pi * u)
        elif derivative == 2:
            val = sign * 0.5 * w * w * np.cos(np.pi * u)
        else:
            raise ValueError(f"derivative must be 0, 1 or 2, got {derivative}")
        out[sel] = val
    return out


def fade_envelope_at(t: float, duration_s: float, fade_in_s: float, fade_out_s: float) -> float:
    """:func:`fade_envelope` at one instant, in scalar arithmetic: the same operations in the
    same order (``math.cos`` gives numpy's ``cos`` to the bit here; a test compares the two), at
    a twentieth of the cost of a one-element array."""
    if t < 0.0 or t > duration_s:
        return 0.0
    out = 1.0
    if fade_in_s > 0.0 and t <= fade_in_s:
        out = 0.5 * (1.0 - math.cos(math.pi * (t / fade_in_s)))
    start = duration_s - fade_out_s
    if fade_out_s > 0.0 and start <= t <= start + fade_out_s:
        out = 0.5 * (1.0 + math.cos(math.pi * ((t - start) / fade_out_s)))
    return out


@dataclass(frozen=True)
class HarmonicTable:
    """Lines of a polyharmonic motion for one axis, plus its fades and duration."""

    freq_hz: FloatArray
    amp_deg: FloatArray
    phase_rad: FloatArray
    duration_s: float
    fade_in_s: float = 0.0
    fade_out_s: float = 0.0
    period_s: float | None = None  # the repetition period T_p when the lines are on k/T_p
    meta: dict[str, object] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        f = np.asarray(self.freq_hz, dtype=float)
        a = np.asarray(self.amp_deg, dtype=float)
        p = np.asarray(self.phase_rad, dtype=float)
        if not (f.shape == a.shape == p.shape) or f.ndim != 1:
            raise ValueError(
                f"freq_hz, amp_deg, phase_rad must be 1-D of one length, got {f.shape}, "
                f"{a.shape}, {p.shape}"
            )
        if self.fade_in_s < 0 or self.fade_out_s < 0:
            raise ValueError("fade_in_s and fade_out_s must be >= 0")
        if self.fade_in_s + self.fade_out_s > self.duration_s:
            raise ValueError(
                f"fades ({self.fade_in_s} s + {self.fade_out_s} s) longer than the duration "
                f"{self.duration_s} s"
            )
        object.__setattr__(self, "freq_hz", f)
        object.__setattr__(self, "amp_deg", a)
        object.__setattr__(self, "phase_rad", p)
        # 2π·f_k, as ``at`` multiplies it (the same product, once)
        object.__setattr__(self, "_w", 2.0 * np.pi * f)

    @property
    def n_lines(self) -> int:
        return int(self.freq_hz.size)

    @property
    def variance_deg2(self) -> float:
        """Variance of the steady (unfaded) motion, Σ A_k²/2."""
        return float(np.sum(self.amp_deg**2) / 2.0)

    def steady(self, t_s: ArrayLike, derivative: int = 0) -> FloatArray:
        """The unfaded sum of cosines (or its 1st/2nd time derivative) at times ``t_s``."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        out = np.empty_like(t)
        w = 2.0 * np.pi * self.freq_hz
        amp = self.amp_deg * w**derivative
        # d/dt cos = -w sin = w cos(. + π/2): each derivative adds π/2 of phase
        phase = self.phase_rad + derivative * (np.pi / 2.0)
        for i in range(0, t.size, _CHUNK):
            tc = t[i : i + _CHUNK]
            out[i : i + _CHUNK] = np.cos(np.outer(tc, w) + phase) @ amp
        return out

    def evaluate(self, t_s: ArrayLike, derivative: int = 0) -> FloatArray:
        """The faded motion x(t) (0), its rate (1) or acceleration (2): deg, deg/s, deg/s²."""
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        env = [
            fade_envelope(t, self.duration_s, self.fade_in_s, self.fade_out_s, d) for d in range(3)
        ]
        s = [self.steady(t, d) for d in range(derivative + 1)]
        if derivative == 0:
            return env[0] * s[0]
        if derivative == 1:
            return env[1] * s[0] + env[0] * s[1]
        if derivative == 2:
            return env[2] * s[0] + 2.0 * env[1] * s[1] + env[0] * s[2]
        raise ValueError(f"derivative must be 0, 1 or 2, got {derivative}")

    def at(self, t_s: float) -> float:
        """x(t) at one instant, cheap enough for a 1 kHz simulation tick: the envelope in
        scalar arithmetic (:func:`fade_envelope_at`, the same value as :func:`fade_envelope`)."""
        if t_s < 0.0 or t_s > self.duration_s:
            return 0.0
        e = fade_envelope_at(t_s, self.duration_s, self.fade_in_s, self.fade_out_s)
        if e == 0.0:
            return 0.0
        w: FloatArray = self._w  # type: ignore[attr-defined]
        return e * float(np.dot(self.amp_deg, np.cos(w * t_s + self.phase_rad)))
