"""The run as an explicit state machine.

::

    idle → prechecks → [equalising →] fade-in → running → fade-out → analysing → done
      └──────┴──────────────┴────────────┴──────────┴──────────┴───────────┴──────→ aborted

``equalising`` (the low-level pre-test and the drive's correction, ``run.equalise``) is taken
only when asked for: ``advance_to`` steps over it.

Every transition is validated against ``TRANSITIONS`` (an illegal one is a bug and raises
``TransitionError``) and handed to the listeners, which log it as an event in the recording.
``done`` and ``aborted`` are final.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import StrEnum

from benchctl.clock import REAL, Clock
from benchctl.errors import BenchError


class RunState(StrEnum):
    IDLE = "idle"
    PRECHECKS = "prechecks"
    EQUALISING = "equalising"
    FADE_IN = "fade-in"
    RUNNING = "running"
    FADE_OUT = "fade-out"
    ANALYSING = "analysing"
    DONE = "done"
    ABORTED = "aborted"

    def __str__(self) -> str:
        return self.value


_ORDER = (
    RunState.IDLE,
    RunState.PRECHECKS,
    RunState.FADE_IN,
    RunState.RUNNING,
    RunState.FADE_OUT,
    RunState.ANALYSING,
    RunState.DONE,
)

#: state → the states it may move to. Any non-final state may abort.
TRANSITIONS: dict[RunState, frozenset[RunState]] = {
    s: frozenset({_ORDER[i + 1], RunState.ABORTED}) for i, s in enumerate(_ORDER[:-1])
}
TRANSITIONS[RunState.PRECHECKS] |= {RunState.EQUALISING}  # the optional pre-test
TRANSITIONS[RunState.EQUALISING] = frozenset({RunState.FADE_IN, RunState.ABORTED})
TRANSITIONS[RunState.DONE] = frozenset()
TRANSITIONS[RunState.ABORTED] = frozenset()

FINAL = frozenset({RunState.DONE, RunState.ABORTED})

#: the motion states, in order: the profile's time decides which one the run is in
MOTION_STATES = (RunState.FADE_IN, RunState.RUNNING, RunState.FADE_OUT)

Listener = Callable[[RunState, RunState, float, str], None]  # old, new, t_host, reason


class TransitionError(BenchError):
    """An illegal state transition was asked for: a bug in the run layer, never hidden."""


class StateMachine:
    """Thread-safe holder of the run's state; ``to`` validates and notifies listeners."""

    def __init__(self, clock: Clock = REAL) -> None:
        self._lock = clock.lock()
        self._state = RunState.IDLE
        self._clock = clock
        self._listeners: list[Listener] = []
        self.history: list[tuple[RunState, float]] = [(RunState.IDLE, clock.monotonic())]

    @property
    def state(self) -> RunState:
        return self._state

    @property
    def final(self) -> bool:
        return self._state in FINAL

    def subscribe(self, listener: Listener) -> None:
        self._listeners.append(listener)

    def entered(self, state: RunState) -> float | None:
        """Host time the run entered ``state`` (None if it never did)."""
        for s, t in self.history:
            if s is state:
                return t
        return None

    def to(self, new: RunState, reason: str = "") -> None:
        """Move to ``new``; raises ``TransitionError`` if the move is not allowed."""
        with self._lock:
            old = self._state
            if new not in TRANSITIONS[old]:
                raise TransitionError(f"run state {old} cannot move to {new}")
            self._state = new
            t = self._clock.monotonic()
            self.history.append((new, t))
        for listener in self._listeners:
            listener(old, new, t, reason)

    def advance_to(self, target: RunState) -> None:
        """Step forward along the normal order up to ``target`` (no-op if already there).

        Used by the motion loop: with a zero-length fade the run passes through fade-in in the
        same instant, and the recording still shows every state it went through.
        """
        if target is RunState.ABORTED:
            raise TransitionError("advance_to cannot abort; use to(RunState.ABORTED, reason)")
        while True:
            cur = self._state
            if cur is target:
                return
            here = _ORDER.index(RunState.PRECHECKS if cur is RunState.EQUALISING else cur)
            if cur in FINAL or target is RunState.EQUALISING or here >= _ORDER.index(target):
                raise TransitionError(f"run state {cur} cannot advance to {target}")
            self.to(_ORDER[here + 1])

    def abort(self, reason: str) -> bool:
        """Move to aborted unless already final; True if this call did it."""
        with self._lock:
            if self._state in FINAL:
                return False
        try:
            self.to(RunState.ABORTED, reason)
        except TransitionError:  # raced to a final state
            return False
        return True
