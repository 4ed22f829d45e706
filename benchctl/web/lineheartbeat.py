"""One station's heartbeat kept going: ``HeartbeatPublisher`` publishes the station's state at
once on every change and every ``HEARTBEAT_EVERY_S`` between, from a thread of its own, so
that the station server never waits for the database and a database out of reach never
reaches the server (the failure is logged when it starts and when it ends, and the next beat
tries again).

::

    board = StationBoard(archive)
    with HeartbeatPublisher(board.publish, "bench-2") as beat:    # idle, published at once
        beat.set(StationState.RUNNING, serial="INC-0042", started_utc=start, phase="ramp-in")
        ...
        beat.set(StationState.IDLE, last_outcome="PASS", last_serial="INC-0042")

Every wait goes through the injected clock (``benchctl.clock``): on simulated time the beats
come on simulated seconds.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from types import TracebackType
from typing import Any

from benchctl.clock import REAL, Clock, EventLike, LockLike, ThreadLike
from benchctl.errors import ArchiveError, InputError
from benchctl.web.linestations import HEARTBEAT_EVERY_S, StationState

log = logging.getLogger(__name__)


class HeartbeatPublisher:
    """Publishes ``station``'s state through ``publish`` (``StationBoard.publish``, or any
    function taking the same arguments): ``start()`` (or ``with``) publishes ``state`` at
    once, ``set(state, **fields)`` replaces what is published and publishes it at once,
    and every ``every_s`` the last state is published again; ``stop()`` publishes the last
    state once more and ends the thread (waiting at most ``stop_timeout_s`` for it). Never raises a
    publishing failure: it is logged (once when it starts, once when it ends)."""

    def __init__(self, publish: Callable[..., None], station: str,
                 state: StationState | str = StationState.IDLE, *,
                 every_s: float = HEARTBEAT_EVERY_S, clock: Clock = REAL,
                 stop_timeout_s: float = 10.0, **fields: Any) -> None:
        if not every_s > 0:
            raise InputError(f"every_s = {every_s!r}: expected a positive number of seconds")
        self._publish = publish
        self.station = station
        self.every_s = every_s
        self._clock = clock
        self._stop_timeout_s = stop_timeout_s
        self._lock: LockLike = clock.lock()
        self._wake: EventLike = clock.event()
        self._stopping = False
        self._state: tuple[StationState, dict[str, Any]] = (_state(state), dict(fields))
        self._thread: ThreadLike | None = None
        self._failing: str | None = None  # the failure being logged, until a publish works
        self.published = 0  # how many publishes succeeded

    def start(self) -> None:
        if self._thread is not None:
            return
        self._thread = self._clock.thread(self._run, name=f"heartbeat-{self.station}")
        self._thread.start()

    def set(self, state: StationState | str, **fields: Any) -> None:
        """Publish ``state`` with ``fields`` (``StationBoard.publish``'s) from now on; the
        thread publishes it at once. Does not wait for the database."""
        with self._lock:
            self._state = (_state(state), dict(fields))
        self._wake.set()

    def stop(self) -> None:
        with self._lock:
            self._stopping = True
        self._wake.set()
        if self._thread is not None:
            self._thread.join(self._stop_timeout_s)
            self._thread = None

    def __enter__(self) -> HeartbeatPublisher:
        self.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    def _run(self) -> None:
        while True:
            with self._lock:
                state, fields = self._state
                stopping = self._stopping
            self._beat(state, fields)  # at least once, and the last state once more at stop
            if stopping:
                return
            self._wake.wait(self.every_s)
            self._wake.clear()

    def _beat(self, state: StationState, fields: dict[str, Any]) -> None:
        try:
            self._publish(self.station, state, **fields)
        except ArchiveError as e:
            self._failed(str(e))
            return
        except Exception as e:  # a bug or a bad field: said, and the beats go on
            self._failed(f"{type(e).__name__}: {e}", exc=e)
            return
        self.published += 1
        if self._failing is not None:
            log.warning("station %s: its heartbeat is published again", self.station)
            self._failing = None

    def _failed(self, why: str, exc: BaseException | None = None) -> None:
        if why != self._failing:
            log.warning("station %s: heartbeat not published (tried again every %g s): %s",
                        self.station, self.every_s, why, exc_info=exc)
            self._failing = why


def _state(state: StationState | str) -> StationState:
    try:
        return StationState(state)
    except ValueError:
        raise InputError(f"state = {state!r}: expected one of "
                         f"{', '.join(s.value for s in StationState)}") from None


__all__ = ["HeartbeatPublisher"]
