"""Seeded host and device behaviour for a simulated run on simulated time.

:class:`Disturbances` draws, from one seed, everything that goes wrong in a run: host stalls,
send jitter, slow and lost stand replies, lost and garbled instrument frames, stand and
instrument faults, an operator's Ctrl-C. Each kind has its own pseudo-random stream (seeded from
``"<seed>:<kind>"``), so a kind switched on or off leaves the others' draws as they were; the
draws happen in the order the run's frames are sent, which on simulated time is the same in
every run — a seed replays exactly.

What each disturbance does:

- a host stall stops the run's threads (every thread not named ``sim-…``) for its length, as
  SIGSTOP does (:meth:`benchctl.clock.virtual.VirtualClock.stall_host`): replies and frames
  arrive meanwhile and wait in their buffers, the stand plays on from its queue;
- send jitter delays each frame the host sends to the stand by up to ``send_jitter_s``;
- a slow reply reaches the host late by its drawn delay; a lost reply never does;
- a lost instrument frame never reaches the host; a garbled one has one byte changed;
- a fault is injected at its drawn moment of the motion through the simulators' own schedule
  (``sim.faults``): the same path a configured fault takes;
- the operator's stop is the run's SIGINT path, taken at its drawn moment
  (:attr:`Disturbances.operator_stop_s`, for the caller to act on).

Stalls, jitter and the links' disturbances act from ``from_s`` seconds after the simulators
start (:meth:`benchctl.sim.bench.SimBench.disturb`); the faults and the operator's stop are
timed from the motion's start.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from benchctl.config import BenchConfig, SimDisturbConfig, SimFault

#: fault kinds' parameters when drawn (a stall within the stand's reach, a short silence)
_FAULT_PARAMS: dict[str, Callable[[random.Random], dict[str, Any]]] = {
    "stand:stall": lambda r: {"duration_s": round(_log_uniform(r, 0.05, 2.0), 4)},
    "stand:drop_connection": lambda r: {"duration_s": round(_log_uniform(r, 0.05, 2.0), 4)},
    "stand:modbus_exception": lambda r: {"count": r.randint(1, 3)},
    "stand:stand_fault": lambda r: {"code": 10},
    "stand:estop": lambda r: {},
    "instrument:silent": lambda r: {},
    "instrument:garbled": lambda r: {"fraction": round(r.uniform(0.01, 0.2), 3)},
    "instrument:stuck": lambda r: {},
    "instrument:drop": lambda r: {},
}


def _log_uniform(rng: random.Random, lo: float, hi: float) -> float:
    return lo if hi <= lo else math.exp(rng.uniform(math.log(lo), math.log(hi)))


@dataclass
class Disturbances:
    """The seeded schedule for one run of ``horizon_s`` seconds (see the module's text)."""

    spec: SimDisturbConfig
    horizon_s: float
    #: (start, duration) of each host stall, seconds from the run's start
    stalls: list[tuple[float, float]] = field(default_factory=list)
    #: faults for the simulators' schedule (moments from the stand's first motion)
    faults: list[SimFault] = field(default_factory=list)
    #: seconds from the start of the motion at which the operator presses Ctrl-C, or None
    operator_stop_s: float | None = None

    def __post_init__(self) -> None:
        s = self.spec
        rng = self._rng("stalls")
        t = s.from_s
        if s.host_stalls_per_min > 0:
            rate = s.host_stalls_per_min / 60.0
            while True:
                t += rng.expovariate(rate)
                if t >= self.horizon_s:
                    break
                d = _log_uniform(rng, *s.host_stall_s)
                self.stalls.append((round(t, 6), round(d, 6)))
                t += d
        rng = self._rng("faults")
        for _ in range(s.faults):
            key = rng.choice(s.fault_kinds)
            target, _, kind = key.partition(":")
            after = round(rng.uniform(0.0, self.horizon_s), 3)
            params = _FAULT_PARAMS[key](rng) if key in _FAULT_PARAMS else {}
            self.faults.append(
                SimFault(target=target, kind=kind, after_motion_s=after, params=params)  # type: ignore[arg-type]
            )
        rng = self._rng("operator")
        if rng.random() < s.operator_stop_p:
            self.operator_stop_s = round(rng.uniform(0.0, self.horizon_s), 3)

    def with_faults(self, cfg: BenchConfig) -> BenchConfig:
        """``cfg`` with the drawn faults added to its simulators' schedule (``sim.faults``)."""
        assert cfg.sim is not None
        sim = cfg.sim.model_copy(update={"faults": (*cfg.sim.faults, *self.faults)})
        return cfg.model_copy(update={"sim": sim})

    def _rng(self, kind: str) -> random.Random:
        return random.Random(f"{self.spec.seed}:{kind}")

    # -- what the links do ------------------------------------------------------------------
    def send_delay(self) -> Callable[[bytes], float | None]:
        """Host → stand: each frame's extra delay (jitter)."""
        rng, jitter = self._rng("jitter"), self.spec.send_jitter_s

        def delay(data: bytes) -> float | None:
            return rng.uniform(0.0, jitter) if jitter > 0 else 0.0

        return delay

    def reply_delay(self) -> Callable[[bytes], float | None]:
        """Stand → host: each reply's extra delay, or None when it is lost."""
        rng, s = self._rng("replies"), self.spec

        def delay(data: bytes) -> float | None:
            if s.lost_reply_p > 0 and rng.random() < s.lost_reply_p:
                return None
            if s.slow_reply_p > 0 and rng.random() < s.slow_reply_p:
                return _log_uniform(rng, *s.slow_reply_s)
            return 0.0

        return delay

    def frame_damage(self) -> Callable[[bytes], bytes | None]:
        """Instrument → host: each frame as it arrives, or None when it is lost."""
        rng, s = self._rng("frames"), self.spec

        def damage(data: bytes) -> bytes | None:
            if s.lost_frame_p > 0 and rng.random() < s.lost_frame_p:
                return None
            if s.garbled_frame_p > 0 and rng.random() < s.garbled_frame_p and len(data) > 2:
                i = rng.randrange(0, len(data) - 1)  # never the line's end
                b = bytearray(data)
                b[i] = (b[i] + rng.randrange(1, 255)) & 0xFF
                if b[i] in (0x0D, 0x0A, 0x07):
                    b[i] = 0x80
                return bytes(b)
            return data

        return damage

    def describe(self) -> dict[str, Any]:
        """The schedule as recorded with the run (``events.jsonl`` / ``meta.json``)."""
        return {
            "seed": self.spec.seed,
            "from_s": self.spec.from_s,
            "host_stalls": [[t, d] for t, d in self.stalls],
            "faults": [
                {"target": f.target, "kind": f.kind, "after_motion_s": f.after_motion_s,
                 "params": dict(f.params)}
                for f in self.faults
            ],
            "operator_stop_s": self.operator_stop_s,
        }
