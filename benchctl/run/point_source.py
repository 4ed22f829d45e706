"""The commanded points of a motion in order: a rejoin path first, then the profile's slots.

A ``PointSource`` walks a ``MotionPlan``'s slots from a starting slot, with a rejoin's planned
path (``benchctl.kinematics.Rejoin``) in place of the profile's points while it lasts, and ends
with two copies of the last value so the sequence ends at rest. The stand loop takes its
setpoints (stream mode) and the points it queues (buffered mode) from one.
"""

from __future__ import annotations

import math

from benchctl.kinematics import Rejoin
from benchctl.run.plan import MotionPlan


class PointSource:
    """The commanded points in order: a rejoin path first (if any), then the profile's slots,
    then two copies of the last value (the sequence ends at rest)."""

    def __init__(self, plan: MotionPlan, k0: int, rejoin: Rejoin | None = None) -> None:
        self.plan = plan
        self.k = k0
        self.rejoin = rejoin
        self.tail = 2

    @property
    def done(self) -> bool:
        return self.k >= self._end() and self.tail == 0

    def _end(self) -> int:
        end = self.plan.n_slots
        if self.rejoin is not None:
            end = max(end, self.rejoin.first_slot + self.rejoin.n)
        return end

    def value(self, k: int) -> dict[str, float]:
        p = self.plan
        rej = self.rejoin
        out = {}
        for a in p.axes:
            if rej is not None and 0 <= k - rej.first_slot < rej.points[a].size:
                out[a] = float(rej.points[a][k - rej.first_slot])
            else:
                out[a] = float(p.values[a][min(k, p.n_slots - 1)])
        return out

    def at(self, t: float) -> dict[str, float]:
        """The commanded motion at profile time ``t``, linear between the points."""
        x = max(0.0, t / self.plan.period_s)
        k = math.floor(x)
        v0, v1 = self.value(k), self.value(k + 1)
        w = x - k
        return {a: v0[a] + w * (v1[a] - v0[a]) for a in v0}

    def take(self, n: int) -> list[tuple[int, dict[str, float]]]:
        out: list[tuple[int, dict[str, float]]] = []
        while len(out) < n:
            if self.k < self._end():
                out.append((self.k, self.value(self.k)))
            elif self.tail > 0:
                out.append((self.k, self.value(self._end() - 1)))
                self.tail -= 1
            else:
                break
            self.k += 1
        return out


__all__ = ["PointSource"]
