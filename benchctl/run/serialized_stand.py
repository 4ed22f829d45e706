"""A stand shared by threads: every call to it serialised by one lock.

The stand loop and the run's main thread (and its supervisor) call the same driver; wrapped in
a ``SerializedStand`` each call holds the lock (the run's clock's, so simulated time sees it) for
its whole duration, whatever the driver's own locking.
"""

from __future__ import annotations

from typing import Any, cast

from benchctl.clock import REAL, Clock
from benchctl.devices.base import Stand


class SerializedStand:
    """The stand with every call serialised by one lock: the loop and the main thread share it."""

    def __init__(self, stand: Stand, *, clock: Clock = REAL) -> None:
        self._stand = stand
        self._lock = clock.rlock()
        self.axes = stand.axes
        self.limits = stand.limits

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._stand, name)
        if not callable(attr):
            return attr

        def call(*args: Any, **kwargs: Any) -> Any:
            with self._lock:
                return attr(*args, **kwargs)

        return call

    def as_stand(self) -> Stand:
        return cast(Stand, self)


__all__ = ["SerializedStand"]
