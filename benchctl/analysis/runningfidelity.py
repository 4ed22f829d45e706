"""The excitation fidelity's running estimate during the run: each band's error from the
stand's samples so far, and the abort level confirmed.

Before whole periods are in, the line-wise fit cannot separate lines ``1/T_p`` apart in a
shorter record, so each band's *complex gain* ``G_b`` is fitted instead,
``x(t) ≈ m + Σ_b Re(G_b · z_b(t))`` with ``z_b`` the target's lines in band b
(``Σ_{k∈b} A_k e^{j(2πf_k(t−t₀)+φ_k)}``) — a few unknowns, well determined after a few cycles,
accumulated sample by sample (normal equations). ``20·log10|G_b|`` is the band's error (the
response averaged over its lines, weighted by their power). A band is at the abort level when,
for ``ABORT_CONFIRM`` consecutive estimates, its whole 95 % interval lies beyond
±``abort_db``, the half-width is below ``max_ci_db`` and the steady motion has lasted
``RUNNING_MIN_CYCLES`` cycles of the band's lowest line (and ``RUNNING_MIN_S``). Bands too
weak or unreachable are not judged, as after the run.

The fidelity over whole periods, after the run: :mod:`benchctl.analysis.excitation`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis.fidelitylimits import FidelityLimits, StandReach, bands_of

FloatArray = NDArray[np.float64]

Z95 = 1.959963984540054
RUNNING_MIN_CYCLES = 4.0  # the running estimate: cycles of a band's lowest line first …
RUNNING_MIN_S = 5.0  # … and seconds of steady motion
ABORT_CONFIRM = 3  # consecutive running estimates at the abort level before it counts


class RunningFidelity:
    """The running estimate of one axis's band errors during the motion (module notes).

    ``add`` (any thread; one list append) takes the stand's samples; ``update`` (one thread)
    folds the new ones inside the steady window into the normal equations and estimates;
    ``abort_reason`` says why the run must stop, once the abort level is confirmed.
    """

    def __init__(
        self,
        table: Any,
        window: tuple[float, float],
        t_start: float,
        *,
        scale: float = 1.0,
        limits: FidelityLimits | None = None,
        reach: StandReach | None = None,
        axis: str = "",
    ) -> None:
        self.limits = lim = limits or FidelityLimits()
        self.axis = axis
        self.window = (float(window[0]), float(window[1]))
        self.t_start = float(t_start)
        f = np.asarray(table.freq_hz, dtype=float)
        a = np.asarray(table.amp_deg, dtype=float) * scale
        ph = np.asarray(table.phase_rad, dtype=float)
        use = a > 0
        f, a, ph = f[use], a[use], ph[use]
        if reach is not None:
            ok = ~reach.unreachable(f, a)
            f, a, ph = f[ok], a[ok], ph[ok]
        self.bands: list[tuple[float, float, float]] = []
        self.members: list[NDArray[np.int64]] = []
        if f.size:
            specs = bands_of(lim, f)
            power = [float(np.sum(a[(f >= lo) & (f < hi)] ** 2) / 2.0) for lo, _c, hi in specs]
            floor = max(power) * 10.0 ** (lim.weak_band_db / 10.0)
            for (lo, c, hi), pw in zip(specs, power, strict=True):
                idx = np.flatnonzero((f >= lo) & (f < hi))
                if idx.size and pw >= floor and pw > 0:
                    self.bands.append((lo, c, hi))
                    self.members.append(idx.astype(np.int64))
        self._omega = 2.0 * np.pi * f
        self._coef = a * np.exp(1j * ph)
        # the bands' signals are told apart only over a record that resolves their lines: one
        # whole period of the line grid (1 / the closest spacing); before it, neighbouring
        # bands' lines are nearly the same column and a band can read dB off without any fault
        fs = np.sort(np.unique(f))
        gaps = np.diff(fs)
        self.resolve_s = float(1.0 / gaps.min()) if gaps.size and gaps.min() > 0 else 0.0
        nb = len(self.bands)
        self._p = 1 + 2 * nb
        self._ata = np.zeros((self._p, self._p))
        self._atx = np.zeros(self._p)
        self._xx = 0.0
        self._n = 0
        self._t_first: float | None = None
        self._t_last: float | None = None
        self._buf: list[tuple[float, float]] = []
        self._streak = np.zeros(nb, dtype=np.int64)
        self.estimate: list[dict[str, Any]] = []

    def add(self, t: float, x: float) -> None:
        """One stand sample (host clock, deg); cheap, from the thread that reads the stand."""
        self._buf.append((t, x))

    def _columns(self, t: FloatArray) -> FloatArray:
        e = np.exp(1j * np.outer(t - self.t_start, self._omega)) * self._coef  # (n, K)
        cols = [np.ones(t.size)]
        for idx in self.members:
            z = e[:, idx].sum(axis=1)
            cols.extend((z.real, -z.imag))
        return np.column_stack(cols)

    def update(self) -> list[dict[str, Any]]:
        """Fold the samples added since the last call; the bands' running estimates
        (``centre_hz``, ``error_db``, ``half_width_db``, ``judged``, ``abort``)."""
        end = len(self._buf)
        new = self._buf[:end]
        del self._buf[:end]  # only what was taken: an append meanwhile stays (GIL-atomic)
        lo, hi = self.window
        rows = np.array([r for r in new if lo <= r[0] <= hi and math.isfinite(r[1])],
                        dtype=float).reshape(-1, 2)
        if rows.size:
            a = self._columns(rows[:, 0])
            self._ata += a.T @ a
            self._atx += a.T @ rows[:, 1]
            self._xx += float(rows[:, 1] @ rows[:, 1])
            self._n += rows.shape[0]
            self._t_first = float(rows[0, 0]) if self._t_first is None else self._t_first
            self._t_last = float(rows[-1, 0])
        self.estimate = self._estimate()
        return self.estimate

    def _estimate(self) -> list[dict[str, Any]]:
        if not self.bands or self._n <= 2 * self._p or self._t_first is None:
            return []
        try:
            inv = np.linalg.inv(self._ata)
        except np.linalg.LinAlgError:
            return []
        if not np.all(np.isfinite(inv)):
            return []
        theta = inv @ self._atx
        ss = self._xx - 2.0 * float(theta @ self._atx) + float(theta @ self._ata @ theta)
        var = max(ss, 0.0) / (self._n - self._p)
        span = (self._t_last or self._t_first) - self._t_first
        out = []
        lim = self.limits
        for b, ((lo, centre, hi), idx) in enumerate(zip(self.bands, self.members, strict=True)):
            g = complex(theta[1 + 2 * b], theta[2 + 2 * b])
            c = var * inv[1 + 2 * b: 3 + 2 * b, 1 + 2 * b: 3 + 2 * b]
            mag = abs(g)
            u = np.array([g.real, g.imag]) / mag if mag > 0 else np.array([1.0, 0.0])
            sd = math.sqrt(max(float(u @ c @ u), 0.0))
            err = 20.0 * math.log10(mag) if mag > 0 else -math.inf
            half = (20.0 * math.log10(1.0 + Z95 * sd / mag) if mag > 0 and
                    Z95 * sd < mag else math.inf)
            f_low = float(np.min(self._omega[idx])) / (2.0 * np.pi)
            judged = (span >= max(RUNNING_MIN_S, RUNNING_MIN_CYCLES / f_low,
                                  self.resolve_s * (1.0 - 1e-9))
                      and half <= lim.max_ci_db)
            beyond = judged and abs(err) - half > lim.abort_db
            self._streak[b] = self._streak[b] + 1 if beyond else 0
            out.append({"lo_hz": lo, "centre_hz": centre, "hi_hz": hi, "error_db": err,
                        "half_width_db": half, "judged": judged,
                        "abort": bool(self._streak[b] >= ABORT_CONFIRM), "span_s": span})
        return out

    def abort_reason(self) -> str | None:
        """Why the run must stop (the first band confirmed at the abort level), or None."""
        for b in self.estimate:
            if b["abort"]:
                return (f"excitation {self.axis}: the stand's motion in the band "
                        f"{b['lo_hz']:.3g} … {b['hi_hz']:.3g} Hz is {b['error_db']:+.2f} dB "
                        f"(± {b['half_width_db']:.2f}) off the profile, beyond the abort level "
                        f"±{self.limits.abort_db:g} dB (run.excitation.abort_db; running "
                        f"estimate over {b['span_s']:.1f} s)")
        return None
