"""Live statistics of a run: timing histograms, the running σ, what the display shows, and the
kinematics of the commanded sequence. Written by the stand loop and the instrument reader,
read by the main thread; no I/O."""

from __future__ import annotations

import array
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from benchctl.clock import REAL, Clock
from benchctl.devices.base import InstrumentSample, StandSample


class Histogram:
    """Fixed-bin histogram of non-negative durations (s): p50/p99 in O(1) memory.

    Bins of ``resolution_s`` up to ``max_s``; larger values land in the last bin and ``max``
    keeps the true largest value.
    """

    def __init__(self, resolution_s: float = 1e-5, max_s: float = 0.5) -> None:
        self.resolution_s = resolution_s
        self._last = int(max_s / resolution_s)
        #: counts per bin (64-bit integers; a plain array: one add is no numpy scalar's work)
        self.counts = array.array("q", bytes(8 * (self._last + 1)))
        self.n = 0
        self.max = 0.0
        self.total = 0.0

    def add(self, x: float) -> None:
        x = x if x > 0.0 else 0.0  # max(0.0, x) and min(…, last), without the calls
        i = int(x / self.resolution_s)
        if self._last < i:
            i = self._last
        self.counts[i] += 1
        self.n += 1
        self.total += x
        if x > self.max:
            self.max = x

    def quantile(self, q: float) -> float:
        if self.n == 0:
            return math.nan
        c = np.cumsum(np.frombuffer(self.counts, dtype=np.int64))
        i = int(np.searchsorted(c, q * self.n, side="left"))
        return min((i + 0.5) * self.resolution_s, self.max)

    def summary(self) -> dict[str, float]:
        return {
            "n": self.n,
            "p50": self.quantile(0.5),
            "p99": self.quantile(0.99),
            "max": self.max if self.n else math.nan,
            "mean": self.total / self.n if self.n else math.nan,
        }


class RunningSigma:
    """Running σ of ε = y − x per axis (Welford), x linearly interpolated at the instrument's t.

    Only a live display estimate: the verdict comes from the full analysis. Instrument samples
    wait until a stand sample later than them has arrived; memory is bounded.
    """

    def __init__(self, axes: tuple[str, ...], *, clock: Clock = REAL) -> None:
        self.axes = axes
        self._lock = clock.lock()
        self._stand: deque[tuple[float, dict[str, float]]] = deque(maxlen=512)
        self._pending: deque[InstrumentSample] = deque(maxlen=4096)
        self.active = False
        self.n = dict.fromkeys(axes, 0)
        self._mean = dict.fromkeys(axes, 0.0)
        self._m2 = dict.fromkeys(axes, 0.0)

    def add_stand(self, t: float, angle: Mapping[str, float]) -> None:
        with self._lock:
            self._stand.append((t, dict(angle)))
            self._drain()

    def add_instrument(self, s: InstrumentSample) -> None:
        if not self.active:
            return
        with self._lock:
            self._pending.append(s)

    def _drain(self) -> None:
        if len(self._stand) < 2:
            return
        t_last = self._stand[-1][0]
        t_first = self._stand[0][0]
        while self._pending and self._pending[0].t_host <= t_last:
            s = self._pending.popleft()
            if s.t_host < t_first:
                continue
            x = self._interp(s.t_host)
            for a in self.axes:
                if a in s.angle_deg and a in x:
                    self._push(a, s.angle_deg[a] - x[a])

    def _interp(self, t: float) -> dict[str, float]:
        hist = self._stand
        for i in range(len(hist) - 1, 0, -1):
            t0, x0 = hist[i - 1]
            t1, x1 = hist[i]
            if t0 <= t <= t1:
                w = (t - t0) / (t1 - t0) if t1 > t0 else 0.0
                return {a: x0[a] + w * (x1[a] - x0[a]) for a in x0 if a in x1}
        return {}

    def _push(self, a: str, e: float) -> None:
        self.n[a] += 1
        d = e - self._mean[a]
        self._mean[a] += d / self.n[a]
        self._m2[a] += d * (e - self._mean[a])

    def sigma(self) -> dict[str, float]:
        with self._lock:
            return {
                a: math.sqrt(self._m2[a] / (self.n[a] - 1)) if self.n[a] > 1 else math.nan
                for a in self.axes
            }


@dataclass
class LiveView:
    """What the display shows; written by the loop and the reader, read by the main thread."""

    stand: StandSample | None = None
    instrument: InstrumentSample | None = None
    tracking_error_deg: dict[str, float] = field(default_factory=dict)
    departure_deg: dict[str, float] = field(default_factory=dict)
    t_motion_start: float | None = None


class CommandStats:
    """Largest |rate| and |acceleration| of the commanded sequence per axis, as the stand plays
    it (one period between points; from rest after the stand held), and the largest step."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self._last: dict[str, tuple[float, float]] = {}  # axis -> (angle, rate)
        self.max_rate_deg_s: dict[str, float] = {}
        self.max_accel_deg_s2: dict[str, float] = {}

    def add(self, angle_deg: Mapping[str, float], *, held: bool = False) -> None:
        T = self.period_s
        for a, x in angle_deg.items():
            prev = self._last.get(a)
            if prev is None:
                self._last[a] = (x, 0.0)
                continue
            v0 = 0.0 if held else prev[1]
            v = (x - prev[0]) / T
            acc = (v - v0) / T
            self.max_rate_deg_s[a] = max(self.max_rate_deg_s.get(a, 0.0), abs(v))
            self.max_accel_deg_s2[a] = max(self.max_accel_deg_s2.get(a, 0.0), abs(acc))
            self._last[a] = (x, v)

    def restart(self, angle_deg: Mapping[str, float]) -> None:
        """A new sequence from rest at ``angle_deg`` (a trajectory restarted after a stop)."""
        self._last = {a: (x, 0.0) for a, x in angle_deg.items()}

    def summary(self) -> dict[str, dict[str, float]]:
        return {
            "max_rate_deg_s": dict(self.max_rate_deg_s),
            "max_accel_deg_s2": dict(self.max_accel_deg_s2),
        }
