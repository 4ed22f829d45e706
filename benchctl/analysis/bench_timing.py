"""The bench's own stream-to-stream delay, measured against a reference of known latency.

A timing calibration records a reference instrument whose response is a pure delay ``L``
(certified; a flat gain) on the stand, through the same acquisition as an instrument under
test. Each excited line ``f_k`` of the motion is fitted in each stream at its own instants
(one least-squares fit of all lines together, so a record of whole periods or not gives the
same lines), and the reference's measured response ``H_k = Y_k / X_k`` is a delay ``τ`` when
its phase is ``−2π f_k τ``. The bench's offset is what the acquisition adds: ``τ − L``.

The delay is the weighted least-squares slope of the lines' phases against ``−2π f_k``, each
line weighted by ``|X_k|²`` (a phase's noise is inversely proportional to its amplitude):
``τ = Σ w_k f_k φ̃_k / Σ w_k f_k²`` with ``φ̃_k = −φ_k / 2π``. Its standard uncertainty is the
scatter of the lines about the fitted slope (weighted), ``s / √(Σ w_k f_k²)``, with a floor
from the instants' own resolution when the lines agree exactly.

Pure computation: arrays in, numbers out (seconds, Hz, degrees).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

#: lines weaker than this share of the strongest line's amplitude are left out of the fit
MIN_LINE_SHARE = 1e-3


@dataclass(frozen=True)
class DelayFit:
    """A measured delay between two streams (the second later than the first).

    ``delay_s``: the fitted delay (s); ``uncertainty_s``: its standard uncertainty (s);
    ``gain``: the mean gain over the lines (weighted); ``n_lines``: lines fitted;
    ``phase_rms_rad``: the rms of the lines' phases about the fitted delay (rad).
    """

    delay_s: float
    uncertainty_s: float
    gain: float
    n_lines: int
    phase_rms_rad: float


def line_amplitudes(t: ArrayLike, x: ArrayLike, freq_hz: ArrayLike) -> NDArray[np.complex128]:
    """Complex amplitudes ``X_k`` of ``x(t) ≈ c + Re Σ X_k e^{j2πf_k t}`` (one joint least-squares
    fit of every line and a constant, at the samples' own instants ``t``, s).

    Examples
    --------
    >>> t = np.arange(0, 60, 0.01)
    >>> a = line_amplitudes(t, 2 * np.cos(2 * np.pi * 0.25 * t - 0.3), [0.25])
    >>> round(float(abs(a[0])), 9), round(float(np.angle(a[0])), 9)
    (2.0, -0.3)
    """
    ta = np.asarray(t, dtype=float)
    xa = np.asarray(x, dtype=float)
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if ta.shape != xa.shape or ta.ndim != 1:
        raise ValueError(f"t and x must be 1-D of one length, got {ta.shape} and {xa.shape}")
    if ta.size < 2 * f.size + 1:
        raise ValueError(f"{ta.size} samples cannot fit {f.size} lines (need {2 * f.size + 1})")
    tc = ta - ta[0]  # a local origin keeps the columns well conditioned; phase moved back below
    w = 2.0 * np.pi * np.outer(tc, f)
    a = np.empty((ta.size, 2 * f.size + 1))
    a[:, 0] = 1.0
    a[:, 1::2] = np.cos(w)
    a[:, 2::2] = np.sin(w)
    c, *_ = np.linalg.lstsq(a, xa, rcond=None)
    amp = c[1::2] - 1j * c[2::2]  # a cos(ωt) + b sin(ωt) = Re((a − jb) e^{jωt})
    return np.asarray(amp * np.exp(-2j * np.pi * f * ta[0]), dtype=np.complex128)


def measure_delay(
    t_ref: ArrayLike,
    x_ref: ArrayLike,
    t_dev: ArrayLike,
    y_dev: ArrayLike,
    freq_hz: ArrayLike,
    *,
    resolution_s: float = 0.0,
) -> DelayFit:
    """The delay of the device's stream behind the reference's, from the excited lines.

    Parameters
    ----------
    t_ref, x_ref : array_like
        The reference (the stand's measured angle) at its instants (s, deg).
    t_dev, y_dev : array_like
        The device's output at its instants (s, deg), over the same span (each stream is
        cut to the span both cover).
    freq_hz : array_like
        The excited lines (Hz), e.g. a profile's ``harmonics / period_s``.
    resolution_s : float
        The instants' own resolution (s): a floor under the uncertainty, ``r / √12``.

    Returns
    -------
    DelayFit
        ``delay_s`` > 0 when the device's output comes later than the reference's.

    Examples
    --------
    A pure 1.5 ms delay seen by lines at 0.1 … 0.3 Hz:

    >>> t = np.arange(0, 120, 0.01)
    >>> f = np.array([0.1, 0.2, 0.3])
    >>> x = sum(np.cos(2 * np.pi * fk * t + k) for k, fk in enumerate(f))
    >>> y = sum(np.cos(2 * np.pi * fk * (t - 0.0015) + k) for k, fk in enumerate(f))
    >>> round(measure_delay(t, x, t, y, f).delay_s * 1e3, 9)
    1.5
    """
    f = np.atleast_1d(np.asarray(freq_hz, dtype=float))
    if f.size == 0 or np.any(f <= 0) or not np.all(np.isfinite(f)):
        raise ValueError("freq_hz: expected at least one finite line above 0 Hz")
    tr, xr = np.asarray(t_ref, dtype=float), np.asarray(x_ref, dtype=float)
    td, yd = np.asarray(t_dev, dtype=float), np.asarray(y_dev, dtype=float)
    # both streams over the same span: the lines of a motion that fades in or out elsewhere
    # are not the same lines
    lo, hi = max(tr[0], td[0]), min(tr[-1], td[-1])
    kr, kd = (tr >= lo) & (tr <= hi), (td >= lo) & (td <= hi)
    xk = line_amplitudes(tr[kr], xr[kr], f)
    yk = line_amplitudes(td[kd], yd[kd], f)
    ax = np.abs(xk)
    keep = ax >= MIN_LINE_SHARE * float(ax.max())
    f, xk, yk = f[keep], xk[keep], yk[keep]
    h = yk / xk
    lag = -np.angle(h) / (2.0 * np.pi)  # = f·τ for a delay τ (cycles)
    w = np.abs(xk) ** 2
    sff = float(np.sum(w * f * f))
    tau = float(np.sum(w * f * lag) / sff)
    resid = lag - f * tau  # cycles
    n = int(f.size)
    floor = resolution_s / math.sqrt(12.0)
    if n > 1:
        s2 = float(np.sum(w * resid**2) / np.sum(w)) * n / (n - 1)
        u = math.sqrt(s2 * float(np.sum(w)) / sff / n) if s2 > 0 else 0.0
    else:
        u = 0.0
    gain = float(np.sum(w * np.abs(h)) / np.sum(w))
    phase_rms = float(np.sqrt(np.sum(w * (2 * np.pi * resid) ** 2) / np.sum(w)))
    return DelayFit(tau, max(u, floor), gain, n, phase_rms)
