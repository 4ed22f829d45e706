"""The simulated instrument's measurement model: pure computation, no I/O, no clock.

What the instrument outputs at its output instant ``t`` (host monotonic seconds) for each axis:

``y(t) = gain · (h * x)(t − L) + bias + drift · (t − t0) + n(t)``, then quantised,

with ``x`` the true stand angle (deg), ``h`` the impulse response of the dynamics (identity, a
first-order lag ``1 / (1 + τs)``, a second-order response ``ωn² / (s² + 2ζωn s + ωn²)``, or both
in cascade), ``L`` the latency (s), ``n`` white Gaussian noise of standard deviation σ (deg,
independent per output sample and axis) and ``t0`` the first output instant. Quantisation
rounds to the nearest multiple of ``quantisation_deg``.

Optional static effects act on each axis's input ``u`` before the dynamics (all off by
default, leaving the model linear and its output bit-identical): the cross-axis coupling
``u_roll = roll + k_rp · pitch``, ``u_pitch = pitch + k_pr · roll`` (``cross_axis``; a
misaligned sensing axis), then a cubic term ``u + c·u³`` (``cubic_per_deg2``), then a
saturation ``clip(u, −s, s)`` (``saturation_deg``). The coupling is linear: the response of
one axis's output to the other axis's angle is ``k · H(f)`` (:meth:`cross_transfer_function`).

The dynamics are integrated exactly for an input that is linear between sub-steps (first-order
hold, by the matrix exponential of the augmented system) at ``substep_hz``. For a sine of
frequency f the linear interpolation departs from the sine by a relative amplitude of at most
``(π f h)² / 2`` (h the sub-step); at the default 4 kHz that is 3e-6 at 1 Hz and 3e-4 at 10 Hz,
so ``transfer_function`` (the continuous system's) is the response the simulation really has,
well inside 0.1 %, up to about 15 Hz.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.linalg import expm

from benchctl.config import SimInstrumentConfig
from benchctl.devices.base import AXES

MotionFn = Callable[[float], Mapping[str, float]]
_OTHER = {"roll": "pitch", "pitch": "roll"}
#: output samples whose noise is drawn in one call: the generator gives the same numbers in one
#: call of ``size=(n, axes)`` as in n calls of ``size=(axes,)`` (each ``loc + scale · z``, z
#: from the bit stream in order)
_NOISE_BATCH = 256


def _state_space(cfg: SimInstrumentConfig) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                                     NDArray[np.float64]]:
    """Continuous (A, B, C) of the unit-DC-gain dynamics; zero states for a pure pass-through."""
    blocks: list[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]] = []
    if cfg.natural_freq_hz is not None:
        wn = 2.0 * math.pi * cfg.natural_freq_hz
        z = cfg.damping
        blocks.append((np.array([[0.0, 1.0], [-wn * wn, -2.0 * z * wn]]),
                       np.array([[0.0], [wn * wn]]), np.array([[1.0, 0.0]])))
    if cfg.lag_s > 0:
        tau = cfg.lag_s
        blocks.append((np.array([[-1.0 / tau]]), np.array([[1.0 / tau]]), np.array([[1.0]])))
    n = sum(b[0].shape[0] for b in blocks)
    a = np.zeros((n, n))
    b = np.zeros((n, 1))
    c = np.zeros((1, n))
    # cascade: the input drives block 0, block i drives block i+1, the last one is the output
    i0 = 0
    prev_c: NDArray[np.float64] | None = None
    prev_i0 = 0
    for ab, bb, cb in blocks:
        k = ab.shape[0]
        a[i0:i0 + k, i0:i0 + k] = ab
        if prev_c is None:
            b[i0:i0 + k] = bb
        else:
            a[i0:i0 + k, prev_i0:prev_i0 + prev_c.shape[1]] = bb @ prev_c
        prev_c, prev_i0 = cb, i0
        i0 += k
    if prev_c is not None:
        c[:, prev_i0:prev_i0 + prev_c.shape[1]] = prev_c
    return a, b, c


class InstrumentModel:
    """Gain, dynamics, latency, bias, drift, white noise and quantisation of one instrument.

    Parameters
    ----------
    cfg : SimInstrumentConfig
        The model's parameters (degrees, seconds, Hz).
    axes : sequence of str
        The axes it reports, e.g. ``("roll", "pitch")``; each gets its own state and noise.

    Notes
    -----
    Call :meth:`output` with increasing output instants; it samples the motion at the instant
    minus the latency (and, with dynamics, at sub-steps since the previous instant). The first
    call starts the dynamics at rest at the input's value (no start-up transient for a constant
    input; a sine has a transient decaying with the lag's time constant).
    """

    def __init__(self, cfg: SimInstrumentConfig, axes: Sequence[str] = AXES) -> None:
        self.cfg = cfg
        self.axes = tuple(axes)
        self.period_s = 1.0 / cfg.rate_hz
        self._a, self._b, self._c = _state_space(cfg)
        self._rng = np.random.default_rng(cfg.seed)
        self._noise: list[list[float]] = []  # drawn ahead, one row per output sample
        self._noise_i = 0
        self._cache: dict[float, tuple[NDArray[np.float64], ...]] = {}
        self._collapsed_cache: dict[
            tuple[float, int], tuple[NDArray[np.float64], NDArray[np.float64]]
        ] = {}
        #: ``_collapsed``'s answers by the exact sub-step (a float key is cheaper than rounding
        #: it); emptied with ``_collapsed_cache``, so it only ever holds what that would give
        self._collapsed_by_h: dict[
            tuple[float, int], tuple[NDArray[np.float64], NDArray[np.float64]]
        ] = {}
        self._x: NDArray[np.float64] | None = None  # states x axes
        self._u: NDArray[np.float64] | None = None  # last input per axis
        self._tm: float | None = None  # last measurement instant
        self._t0: float | None = None
        self._h_max = 1.0 / cfg.substep_hz
        self._ramps: dict[int, NDArray[np.float64]] = {}  # 1 … steps, by steps
        ca = cfg.cross_axis
        self._coupling = {a: k for a, k in (("roll", ca.roll_from_pitch),
                                            ("pitch", ca.pitch_from_roll)) if k}
        self._static = bool(cfg.cubic_per_deg2) or cfg.saturation_deg is not None

    # ------------------------------------------------------------------ frequency domain
    def dynamics_response(self, f_hz: ArrayLike) -> NDArray[np.complex128]:
        """Response of the dynamics alone (unit DC gain, no latency) at ``f_hz`` (Hz)."""
        f = np.asarray(f_hz, dtype=float)
        s = 2j * math.pi * f
        h = np.ones_like(s)
        if self.cfg.natural_freq_hz is not None:
            wn = 2.0 * math.pi * self.cfg.natural_freq_hz
            h = h * wn * wn / (s * s + 2.0 * self.cfg.damping * wn * s + wn * wn)
        if self.cfg.lag_s > 0:
            h = h / (1.0 + self.cfg.lag_s * s)
        return np.asarray(h, dtype=np.complex128)

    def transfer_function(self, f_hz: ArrayLike) -> NDArray[np.complex128]:
        """True response from the stand angle to the instrument's output.

        Parameters
        ----------
        f_hz : array_like
            Frequencies in Hz (≥ 0).

        Returns
        -------
        ndarray of complex
            ``H(f) = gain · exp(−j2πfL) · H_dyn(j2πf)``: output/input amplitude ratio and
            phase (negative = output lags) for a sine of the stand angle. Bias, drift, noise and
            quantisation are not part of it.

        Examples
        --------
        A 0.1 s first-order lag at its corner frequency halves the power:

        >>> from benchctl.config import SimInstrumentConfig
        >>> m = InstrumentModel(SimInstrumentConfig(lag_s=0.1))
        >>> round(float(abs(m.transfer_function(1 / (2 * 3.141592653589793 * 0.1)))), 4)
        0.7071
        """
        f = np.asarray(f_hz, dtype=float)
        return np.asarray(self.cfg.gain * np.exp(-2j * math.pi * f * self.cfg.latency_s)
                          * self.dynamics_response(f), dtype=np.complex128)

    def cross_transfer_function(self, f_hz: ArrayLike, axis: str) -> NDArray[np.complex128]:
        """Response of ``axis``'s output to the *other* axis's angle: ``k · H(f)`` with k the
        coupling into ``axis`` (``cross_axis.roll_from_pitch`` for roll, ``pitch_from_roll``
        for pitch); zero without coupling. Exact without the static nonlinearity."""
        k = {"roll": self.cfg.cross_axis.roll_from_pitch,
             "pitch": self.cfg.cross_axis.pitch_from_roll}[axis]
        return np.asarray(k * self.transfer_function(f_hz), dtype=np.complex128)

    def expected_error_variance(
        self,
        amplitude_deg: ArrayLike,
        freq_hz: ArrayLike,
        *,
        duration_s: float | None = None,
        resolution_deg: float = 0.0,
    ) -> float:
        """Variance of the error ``ε = y − x`` about its mean for a harmonic stand motion.

        Parameters
        ----------
        amplitude_deg, freq_hz : array_like
            The motion of one axis, ``x(t) = Σ A_k cos(2π f_k t + φ_k)`` (deg, Hz; distinct
            frequencies, phases irrelevant).
        duration_s : float, optional
            Record length (s); with a drift, its ramp adds ``(drift · T)² / 12``.
        resolution_deg : float
            A further quantisation step on the wire (e.g. 0.01° for a CANopen slope at
            resolution 10); adds ``r² / 12``.

        Returns
        -------
        float
            ``Σ A_k² |H(f_k) − 1|² / 2 + σ² + q² / 12 + r² / 12 (+ (drift T)² / 12)`` in deg².

        Notes
        -----
        Steady state (transients decayed); the quantisation terms assume steps small against
        the signal's spread (uniform rounding error); the drift term neglects its small
        correlation with the harmonics over a finite record.
        """
        a = np.atleast_1d(np.asarray(amplitude_deg, dtype=float))
        f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
        if a.shape != f.shape:
            raise ValueError(f"amplitude_deg and freq_hz differ in shape: {a.shape} vs {f.shape}")
        dyn = float(np.sum(a * a * np.abs(self.transfer_function(f) - 1.0) ** 2) / 2.0)
        var = dyn + self.cfg.noise_deg**2 + self.cfg.quantisation_deg**2 / 12.0
        var += resolution_deg**2 / 12.0
        if duration_s is not None:
            var += (self.cfg.drift_deg_s * duration_s) ** 2 / 12.0
        return var

    # ------------------------------------------------------------------ time domain
    def _discrete(self, h: float) -> tuple[NDArray[np.float64], ...]:
        """(Φ, Γ0, Γ1) with x(h) = Φ x0 + Γ0 u0 + Γ1 (u1 − u0)/h, exact for linear u."""
        key = round(h, 12)
        got = self._cache.get(key)
        if got is not None:
            return got
        n = self._a.shape[0]
        m = np.zeros((n + 2, n + 2))
        m[:n, :n] = self._a
        m[:n, n:n + 1] = self._b
        m[n, n + 1] = 1.0
        e = expm(m * h)
        got = (e[:n, :n], e[:n, n:n + 1], e[:n, n + 1:n + 2])
        if len(self._cache) > 32:
            self._cache.clear()
        self._cache[key] = got
        return got

    def _collapsed(self, h: float, steps: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``steps`` sub-steps of ``h`` as one linear map: x_N = Pn x_0 + C [u_0 … u_N].

        Each sub-step is x_{i+1} = Φ x_i + B0 u_i + B1 u_{i+1} (B0 = Γ0 − Γ1/h, B1 = Γ1/h,
        the input linear between samples), so u_j enters x_N through C_0 = Φ^{N−1} B0,
        C_j = Φ^{N−1−j} B0 + Φ^{N−j} B1 (0 < j < N) and C_N = B1."""
        exact = (h, steps)
        got = self._collapsed_by_h.get(exact)  # what the lookup below gave this very h
        if got is not None:
            return got
        key = (round(h, 12), steps)
        got = self._collapsed_cache.get(key)
        if got is None:
            got = self._collapsed_new(h, steps)
            if len(self._collapsed_cache) > 32:
                self._collapsed_cache.clear()
                self._collapsed_by_h.clear()  # its entries are the cleared ones
            self._collapsed_cache[key] = got
        if len(self._collapsed_by_h) > 256:
            self._collapsed_by_h.clear()
        self._collapsed_by_h[exact] = got
        return got

    def _collapsed_new(self, h: float,
                       steps: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """``_collapsed``'s map, computed."""
        phi, g0, g1 = self._discrete(h)
        b0, b1 = g0 - g1 / h, g1 / h
        n = phi.shape[0]
        powers = [np.eye(n)]
        for _ in range(steps):
            powers.append(phi @ powers[-1])
        cols = [powers[steps - 1] @ b0]
        cols += [powers[steps - 1 - j] @ b0 + powers[steps - j] @ b1 for j in range(1, steps)]
        cols.append(b1)
        return powers[steps], np.hstack(cols)

    def _input(self, motion: MotionFn, t: float) -> NDArray[np.float64]:
        angles = motion(t)
        u = np.array([float(angles[a]) for a in self.axes])
        if self._coupling:
            u = u + np.array([self._coupling.get(a, 0.0) * float(angles.get(_OTHER[a], 0.0))
                              for a in self.axes])
        return self.static_curve(u) if self._static else u

    def _inputs(self, motion: MotionFn, ts: NDArray[np.float64],
                out: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
        """``_input`` at each of ``ts`` (rows): through ``motion.many`` in one call when the
        motion has it (the same numbers, element by element), else one call per instant.
        ``out`` (rows × axes), if given, receives them (and is returned)."""
        many = getattr(motion, "many", None)
        if many is None:
            got = np.array([self._input(motion, float(t)) for t in ts]).reshape(len(ts), -1)
            if out is None:
                return got
            out[...] = got
            return out
        angles = many(ts)
        plain = out is not None and not self._coupling and not self._static
        # np.stack(…, axis=1), without its overhead: into ``out`` itself when nothing follows
        u = out if plain else np.empty((len(ts), len(self.axes)))
        assert u is not None
        for i, a in enumerate(self.axes):
            u[:, i] = angles[a]
        if plain:
            return u
        if self._coupling:
            zero = np.zeros(len(ts))
            u = u + np.stack(
                [self._coupling.get(a, 0.0) * np.asarray(angles.get(_OTHER[a], zero), dtype=float)
                 for a in self.axes], axis=1)
        u = self.static_curve(u) if self._static else u
        if out is None:
            return u
        out[...] = u
        return out

    def static_curve(self, u: ArrayLike) -> NDArray[np.float64]:
        """The static nonlinearity on an input angle (deg): ``u + c·u³``, then clipped at
        ``±saturation_deg`` (the identity when neither is set)."""
        v = np.asarray(u, dtype=float)
        c = self.cfg.cubic_per_deg2
        if c:
            v = v + c * v**3
        if self.cfg.saturation_deg is not None:
            v = np.clip(v, -self.cfg.saturation_deg, self.cfg.saturation_deg)
        return np.asarray(v, dtype=float)

    def true_output(self, t: float, motion: MotionFn) -> NDArray[np.float64]:
        """Noise-free ``gain · (h * x)(t − L)`` per axis (deg), advancing the dynamics to ``t``."""
        tm = t - self.cfg.latency_s
        n_states = self._a.shape[0]
        if self._tm is None:
            u = self._input(motion, tm)
            self._u = u
            self._tm = tm
            self._t0 = t
            # at rest at the input's value: x = −A⁻¹ B u
            self._x = (-np.linalg.solve(self._a, self._b) @ u[None, :]) if n_states else None
            return self.cfg.gain * u
        if tm < self._tm:
            last = self._tm + self.cfg.latency_s
            raise ValueError(f"output instants must increase: t={t} s after t={last} s")
        if n_states == 0:
            self._tm = tm
            return self.cfg.gain * self._input(motion, tm)
        assert self._x is not None and self._u is not None
        span = tm - self._tm
        steps = max(1, math.ceil(span / self._h_max - 1e-9))
        h = span / steps
        if h <= 0:
            return self.cfg.gain * (self._c @ self._x)[0]
        pn, cm = self._collapsed(h, steps)
        ramp = self._ramps.get(steps)
        if ramp is None:
            ramp = self._ramps[steps] = np.arange(1, steps + 1, dtype=np.float64)
        stacked = np.empty((steps + 1, len(self.axes)))  # [u, the sub-steps' inputs]
        stacked[0] = self._u
        self._inputs(motion, self._tm + ramp * h, out=stacked[1:])
        if n_states == 1:  # 1×1 factors: their products, exactly what ``@`` gives, cheaper
            x = pn[0, 0] * self._x + cm @ stacked
            self._x, self._u, self._tm = x, stacked[-1], tm
            return self.cfg.gain * (self._c[0, 0] * x[0])
        x = pn @ self._x + cm @ stacked
        self._x, self._u, self._tm = x, stacked[-1], tm
        return self.cfg.gain * (self._c @ x)[0]

    def output(self, t: float, motion: MotionFn) -> dict[str, float]:
        """The instrument's output at its output instant ``t`` (deg by axis), all effects on.

        Per axis, in float64 as the arrays had it (the same operations in the same order, on
        Python floats: cheaper for a few axes): ``(y + bias) + drift · (t − t0)``, then
        ``+ noise``, then the quantisation (by numpy: its rounding and signed zeros)."""
        cfg = self.cfg
        y0 = self.true_output(t, motion)
        assert self._t0 is not None
        bias, shift = cfg.bias_deg, cfg.drift_deg_s * (t - self._t0)
        y = [v + bias + shift for v in y0.tolist()]
        if cfg.noise_deg > 0:
            y = [v + n for v, n in zip(y, self._next_noise(), strict=True)]
        q = cfg.quantisation_deg
        if q > 0:
            y = (q * np.round(np.array(y) / q)).tolist()
        return dict(zip(self.axes, y, strict=True))

    def _next_noise(self) -> list[float]:
        """This output sample's noise by axis: the next row of ``normal(0, σ)`` draws."""
        i = self._noise_i
        if i == len(self._noise):
            self._noise = self._rng.normal(0.0, self.cfg.noise_deg,
                                           size=(_NOISE_BATCH, len(self.axes))).tolist()
            i = 0
        self._noise_i = i + 1
        return self._noise[i]
