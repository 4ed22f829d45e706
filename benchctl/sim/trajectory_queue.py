"""The simulated stand's trajectory queue (buffered mode): the points the host pushed, played
one per period by the stand's physics."""

from __future__ import annotations

import math

import numpy as np


class TrajectoryQueue:
    """The stand's trajectory queue: points k = first … next_index−1, one per period (each a
    tuple of the axes' angles: the physics reads two of them on every tick)."""

    def __init__(self, n_axes: int) -> None:
        self.n_axes = n_axes
        self.period_s = 0.01
        self.points: list[tuple[float, ...]] = []
        self.first = 0  # index of points[0]
        self.base = 0  # index played at t_start
        self.t_start = 0.0
        self.running = False
        self.underruns = 0

    @property
    def next_index(self) -> int:
        return self.first + len(self.points)

    @property
    def queued(self) -> bool:
        return len(self.points) > 0

    def reset(self, period_s: float) -> None:
        self.period_s = period_s
        self.points = []
        self.first = 0
        self.running = False

    def clear(self) -> None:
        self.first = self.next_index
        self.points = []
        self.running = False

    def append(self, pts: np.ndarray) -> None:
        self.points.extend(tuple(float(v) for v in row) for row in pts)

    def start(self, now: float) -> None:
        self.base = self.first
        self.t_start = now
        self.running = True

    def at(self, u: float) -> tuple[float, ...] | None:
        """Linear interpolation at queue position ``u``; None when u is past the last point.
        Points before the one being played are dropped."""
        points = self.points
        i = math.floor(u) - self.first
        if i < 0:
            return points[0] if points else None
        if i + 1 >= len(points):
            return None
        if i > 0:
            del points[:i]
            self.first += i
        w = u - self.first
        w0 = 1.0 - w
        return tuple([w0 * x0 + w * x1 for x0, x1 in zip(points[0], points[1], strict=True)])

    def last_two(self) -> tuple[tuple[float, ...], tuple[float, ...]]:
        last = self.points[-1]
        before = self.points[-2] if len(self.points) > 1 else last
        return last, before

    def level(self, u: float | None) -> int:
        if u is None:
            return len(self.points)
        return max(0, self.next_index - 1 - math.floor(u))

    def played(self, u: float | None) -> int:
        return self.first if u is None else max(self.first, math.floor(u))
