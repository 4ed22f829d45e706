"""The simulated stand's servo physics: its state as a function of time, its modes, watchdog,
soft limits and faults (no transport, no registers)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from benchctl.clock import REAL, Clock
from benchctl.config import SimStandConfig, StandLimits
from benchctl.devices.modbus.regmap import RegisterMap
from benchctl.devices.modbus.regmap_load import load_register_map
from benchctl.harmonics import HarmonicTable
from benchctl.sim.servo import AxisState, ServoModel, brake_step
from benchctl.sim.trajectory_queue import TrajectoryQueue

FAULT_SOFT_LIMIT = 1
FAULT_WATCHDOG = 2
FAULT_ESTOP = 3
FAULT_TABLE = 4
FAULT_KINDS = ("drop_connection", "stall", "modbus_exception", "stand_fault", "estop")

IDENTITY = {
    "vendor": "benchctl",
    "model": "SimStand 2-axis",
    "serial": "SIM-0001",
    "firmware": "1.0",
}
_HISTORY_S = 4.0
_MOVING_DEG_S = 1e-3
_MAX_CATCHUP_TICKS = 1000
#: an underrun's stop: the share of the acceleration limit its target decelerates at
TRAJ_STOP_SHARE = 0.9
#: stream interpolation: a setpoint after a longer pause than this is reached over this long
STREAM_INTERP_MAX_S = 0.1
#: the physics not advanced for longer than this: nothing of the simulator ran (held up)
SIM_HOLDUP_S = 0.1


@dataclass
@dataclass
class CommFaults:
    drop_until: float | None = None  # math.inf = until cleared
    stall_until: float | None = None
    exc_code: int | None = None
    exc_until: float | None = None
    exc_count: int | None = None

    def dropped(self, now: float) -> bool:
        return self.drop_until is not None and now < self.drop_until

    def stalled(self, now: float) -> bool:
        return self.stall_until is not None and now < self.stall_until

    def take_exception(self, now: float) -> int | None:
        if self.exc_code is None:
            return None
        if self.exc_until is not None and now >= self.exc_until:
            self.exc_code = None
            return None
        code = self.exc_code
        if self.exc_count is not None:
            self.exc_count -= 1
            if self.exc_count <= 0:
                self.exc_code = None
        return code


class StandPhysics:
    """The simulated stand's servo physics and its state: every axis's angle and rate ticked at
    ``tick_hz`` on absolute times of ``clock``, the modes (streamed setpoints, a queued
    trajectory, a table, a stop), the watchdog, the soft limits and the faults. The register
    firmware (``StandFirmware``) acts on this state; ``SimStand`` adds the transports."""

    def __init__(
        self,
        sim_cfg: SimStandConfig,
        *,
        limits: StandLimits,
        register_map: Path,
        clock: Clock = REAL,
    ) -> None:
        self.clock = clock
        self.cfg = sim_cfg
        self.limits = limits
        self.map: RegisterMap = load_register_map(register_map)
        self.axes: tuple[str, ...] = tuple(self.map.axes)
        self.model = ServoModel(
            sim_cfg.bandwidth_hz,
            sim_cfg.damping,
            sim_cfg.rate_limit_deg_s,
            sim_cfg.accel_limit_deg_s2,
            1.0 / sim_cfg.tick_hz,
        )
        m = self.model  # servo_step's terms, as it computes them
        self._servo_terms = (
            m.omega_n * m.omega_n,
            2.0 * m.damping * m.omega_n,
            m.accel_limit_deg_s2,
            m.rate_limit_deg_s,
            m.tick_s,
        )
        self._soft_limit_deg = sim_cfg.soft_limit_deg
        self._watchdog_s = sim_cfg.watchdog_s

        self._lock = clock.lock()
        self._state = {a: AxisState() for a in self.axes}
        self._target = dict.fromkeys(self.axes, 0.0)  # the servo's active position setpoint
        self._stream_target = dict.fromkeys(self.axes, 0.0)
        #: stream setpoints interpolated (sim.stand.stream_interpolation): the target moves
        #: linearly from _stream_from (at _stream_t) to _stream_target over _stream_T
        self._stream_from: dict[str, float] | None = None
        self._stream_t = 0.0
        self._stream_T = 0.0
        self._mode: Literal["stream", "table", "stopping", "trajectory", "traj_stop"] = "stream"
        self._enabled = False
        self._fault_code = 0
        self._axis_fault = dict.fromkeys(self.axes, 0)
        self._estop = False
        self._limit = False
        self._tables: dict[str, HarmonicTable | None] = {}
        self._table_start = 0.0
        self._table_end = 0.0
        self._hb_value = 0
        self._hb_time = 0.0
        self._held_s = 0.0  # this simulator's own hold-ups since the last heartbeat
        self._comm = CommFaults()
        self._traj = TrajectoryQueue(len(self.axes))
        # |rate|, |accel| while following: its own queue or table ("profile"), or setpoints
        # streamed by the host ("stream", whose timing is the host's)
        self._peaks = {a: [0.0, 0.0] for a in self.axes}
        self._peaks_stream = {a: [0.0, 0.0] for a in self.axes}
        self._traj_period = 0.0  # the period register as last written
        self._traj_stop: dict[str, tuple[float, float]] = {}  # axis -> (angle, rate) of a stop
        self._pending_faults = sorted(sim_cfg.faults, key=lambda f: f.after_s)

        n_hist = int(_HISTORY_S * sim_cfg.tick_hz) + 2
        self._hist = np.zeros((n_hist, len(self.axes)))
        self._t0 = 0.0
        self._start_time = 0.0
        self._tick_s = 1.0 / sim_cfg.tick_hz
        self._k = 0  # ticks done: the state is at time t0 + k * tick
        self._clock_on = False  # t0 set: the physics runs (lazily too, see _advance)
        self._stop_evt = clock.event()

    def dropped(self) -> bool:
        """Is the ``drop_connection`` fault on now?"""
        with self._lock:
            return self._comm.dropped(self.clock.monotonic())

    def _links_dropped(self) -> None:
        """A ``drop_connection`` fault began (lock held): the transport closes its links (a
        TCP server its connections); nothing here."""

    # -- physics ------------------------------------------------------------------------
    def _physics_loop(self, every: int = 1) -> None:
        """Tick the physics on time; ``every`` ticks at a time (on simulated time the state is
        the same whichever way: a request advances it to its own instant first)."""
        tick = self._tick_s
        clock = self.clock
        while True:
            next_t = self._t0 + (self._k + every) * tick
            if self._stop_evt.wait(max(0.0, next_t - clock.monotonic())):
                return
            with self._lock:
                self._advance(clock.monotonic())

    def _advance(self, now: float) -> None:
        """Run the physics up to ``now`` (lock held): the state is a function of time, whoever
        looks at it first — the physics thread, a reply's feedback or the instrument — so a
        late physics thread never hands out an old state as the present one."""
        if not self._clock_on:
            return
        tick = self._tick_s
        behind = now - (self._t0 + self._k * tick)
        if behind > SIM_HOLDUP_S:  # the simulator itself was held up: not the host's silence
            self._held_s += behind
        k_target = int((now - self._t0) / tick)
        if k_target - self._k > _MAX_CATCHUP_TICKS:
            self._k = k_target - _MAX_CATCHUP_TICKS  # a very late thread: skip, never burst
        if self._k >= k_target:
            return
        hist = self._hist
        n = hist.shape[0]
        states = [self._state[a] for a in self.axes]
        idx = range(len(states))
        t0 = self._t0
        k = self._k
        two = len(states) == 2
        while k < k_target:
            if two and self._mode == "trajectory" and self._enabled:
                done = self._follow2(k, k_target, states)
                if done > k:
                    k = done
                    continue
            k += 1
            self._k = k
            t = t0 + k * tick
            if not (self._mode == "trajectory" and self._enabled and self._follow(t, states)):
                self._tick(t)
            r = k % n
            for j in idx:
                hist[r, j] = states[j].angle_deg

    def _follow2(self, k: int, k_target: int, states: list[AxisState]) -> int:
        """:meth:`_follow` for a two-axis stand, tick after tick from tick ``k + 1`` up to
        ``k_target`` in one call (the state in local variables, written back once): the same
        arithmetic in the same order. Stops before the first tick ``_follow`` would not take;
        returns the last tick done (``k``: none)."""
        pending = self._pending_faults
        fault_after = pending[0].after_s if pending else None
        start = self._start_time
        hb, held, wd = self._hb_time, self._held_s, self._watchdog_s
        q = self._traj
        base, t_start, period, points, first = q.base, q.t_start, q.period_s, q.points, q.first
        wn2, c2, a_max, v_max, dt = self._servo_terms
        soft = self._soft_limit_deg
        t0, tick_s, hist = self._t0, self._tick_s, self._hist
        n = hist.shape[0]
        s0, s1 = states
        x0, v0, x1, v1 = s0.angle_deg, s0.rate_deg_s, s1.angle_deg, s1.rate_deg_s
        a0, a1 = self.axes
        pk0, pk1 = self._peaks[a0], self._peaks[a1]
        r0_max, acc0_max, r1_max, acc1_max = pk0[0], pk0[1], pk1[0], pk1[1]
        tg0 = tg1 = 0.0
        done = k
        while done < k_target:
            kk = done + 1
            t = t0 + kk * tick_s
            if fault_after is not None and t - start >= fault_after:
                break
            if t - hb - held > wd:
                break
            u = base + (t - t_start) / period
            i = math.floor(u) - first
            if i < 0 or i + 1 >= len(points):
                break
            if i > 0:  # as q.at(u) does: the points before the one being played are dropped
                del points[:i]
                first += i
            w = u - first
            w0 = 1.0 - w
            pa, pb = points[0], points[1]
            t0_ = w0 * pa[0] + w * pb[0]
            acc = wn2 * (t0_ - x0) - c2 * v0
            if -a_max > acc:  # min(max(acc, -a_max), a_max), without the two calls
                acc = -a_max
            if a_max < acc:
                acc = a_max
            rate0 = v0 + acc * dt
            if -v_max > rate0:
                rate0 = -v_max
            if v_max < rate0:
                rate0 = v_max
            y0 = x0 + rate0 * dt
            if (y0 > soft or -y0 > soft) and y0 * rate0 > 0:
                break  # a soft limit: _tick faults the stand
            t1_ = w0 * pa[1] + w * pb[1]
            acc = wn2 * (t1_ - x1) - c2 * v1
            if -a_max > acc:  # min(max(acc, -a_max), a_max), without the two calls
                acc = -a_max
            if a_max < acc:
                acc = a_max
            rate1 = v1 + acc * dt
            if -v_max > rate1:
                rate1 = -v_max
            if v_max < rate1:
                rate1 = v_max
            y1 = x1 + rate1 * dt
            if (y1 > soft or -y1 > soft) and y1 * rate1 > 0:
                break
            accel = (rate0 - v0) / tick_s
            if rate0 > r0_max or -rate0 > r0_max:
                r0_max = abs(rate0)
            if accel > acc0_max or -accel > acc0_max:
                acc0_max = abs(accel)
            accel = (rate1 - v1) / tick_s
            if rate1 > r1_max or -rate1 > r1_max:
                r1_max = abs(rate1)
            if accel > acc1_max or -accel > acc1_max:
                acc1_max = abs(accel)
            x0, v0, x1, v1 = y0, rate0, y1, rate1
            tg0, tg1 = t0_, t1_
            r = kk % n
            hist[r, 0] = x0
            hist[r, 1] = x1
            done = kk
        q.first = first
        if done > k:
            s0.angle_deg, s0.rate_deg_s, s1.angle_deg, s1.rate_deg_s = x0, v0, x1, v1
            self._target[a0], self._target[a1] = tg0, tg1
            pk0[0], pk0[1], pk1[0], pk1[1] = r0_max, acc0_max, r1_max, acc1_max
            self._k = done
        return done

    def _follow(self, t: float, states: list[AxisState]) -> bool:
        """``_tick(t)`` of a stand following its trajectory queue, when nothing else happens
        on it (no fault due, the watchdog fed, the queue not run dry, no soft limit reached):
        the same arithmetic, in one piece (this is most ticks of a run). False, with nothing
        changed: ``_tick`` takes it."""
        pending = self._pending_faults
        if pending and t - self._start_time >= pending[0].after_s:
            return False
        if t - self._hb_time - self._held_s > self._watchdog_s:
            return False
        q = self._traj
        u = q.base + (t - q.t_start) / q.period_s
        points = q.points
        i = math.floor(u) - q.first
        if i < 0 or i + 1 >= len(points):
            return False
        if i > 0:  # as q.at(u) does: the points before the one being played are dropped
            del points[:i]
            q.first += i
        w = u - q.first
        w0 = 1.0 - w
        p0, p1 = points[0], points[1]
        wn2, c2, a_max, v_max, dt = self._servo_terms
        soft = self._soft_limit_deg
        new = []
        for j, s in enumerate(states):
            tgt = w0 * p0[j] + w * p1[j]
            v_before = s.rate_deg_s
            acc = wn2 * (tgt - s.angle_deg) - c2 * v_before
            if -a_max > acc:  # min(max(acc, -a_max), a_max), without the two calls
                acc = -a_max
            if a_max < acc:
                acc = a_max
            rate = v_before + acc * dt
            if -v_max > rate:
                rate = -v_max
            if v_max < rate:
                rate = v_max
            angle = s.angle_deg + rate * dt
            if (angle > soft or -angle > soft) and angle * rate > 0:
                return False  # a soft limit: _tick faults the stand
            new.append((tgt, v_before, rate, angle))
        target, peaks, tick = self._target, self._peaks, self._tick_s
        for (tgt, v_before, rate, angle), s, a in zip(new, states, self.axes, strict=True):
            target[a] = tgt
            s.rate_deg_s = rate
            s.angle_deg = angle
            p = peaks[a]
            accel = (rate - v_before) / tick
            if rate > p[0] or -rate > p[0]:
                p[0] = abs(rate)
            if accel > p[1] or -accel > p[1]:
                p[1] = abs(accel)
        return True

    def _tick(self, t: float) -> None:
        """One physics tick at time ``t`` (lock held)."""
        pending = self._pending_faults
        while pending and t - self._start_time >= pending[0].after_s:
            f = pending.pop(0)
            self._apply(f.kind, t, f.duration_s, f.code)
        if self._enabled and t - self._hb_time - self._held_s > self._watchdog_s:
            self._fault(FAULT_WATCHDOG)
        if self._mode == "table" and t - self._table_start > self._table_end:
            self._mode = "stream"
            self._stream_from = None
            self._stream_target = {a: self._table_value(a, self._table_end) for a in self.axes}
        # one step of the queue or of the stop after it per tick (the tick the queue runs dry
        # on has taken the stop's first step already)
        traj_target = None
        if self._mode == "trajectory":
            traj_target = self._trajectory_tick(t)
        elif self._mode == "traj_stop":
            traj_target = self._traj_stop_tick()
        at_rest = True
        # servo_step's terms, as it computes them (this runs 1000 times a second)
        wn2, c2, a_max, v_max, dt = self._servo_terms
        soft = self._soft_limit_deg
        state, target = self._state, self._target
        for i, a in enumerate(self.axes):
            s = state[a]
            if not self._enabled:
                brake_step(self.model, s)  # servo off, fault or E-stop: the brakes' own limit
                target[a] = s.angle_deg
            elif self._mode == "stopping":
                # a commanded stop: decelerate within the stand's acceleration limit
                brake_step(self.model, s, min(self.model.accel_limit_deg_s2, self._stop_accel))
                target[a] = s.angle_deg
            else:
                streamed = False
                mode = self._mode
                if mode == "table":
                    tgt = target[a] = self._table_value(a, t - self._table_start)
                elif traj_target is not None:
                    tgt = target[a] = float(traj_target[i])
                elif self._stream_from is not None:
                    streamed = True
                    frac = min(1.0, (t - self._stream_t) / self._stream_T)
                    x0 = self._stream_from[a]
                    tgt = target[a] = x0 + (self._stream_target[a] - x0) * frac
                else:
                    streamed = True
                    tgt = target[a] = self._stream_target[a]
                v_before = s.rate_deg_s
                # servo_step, inline
                acc = wn2 * (tgt - s.angle_deg) - c2 * v_before
                if -a_max > acc:  # min(max(acc, -a_max), a_max), without the two calls
                    acc = -a_max
                if a_max < acc:
                    acc = a_max
                rate = v_before + acc * dt
                if -v_max > rate:
                    rate = -v_max
                if v_max < rate:
                    rate = v_max
                s.rate_deg_s = rate
                s.angle_deg += rate * dt
                # the largest |rate| and |accel| while following
                p = self._peaks_stream[a] if streamed else self._peaks[a]
                accel = (rate - v_before) / self._tick_s
                if rate > p[0] or -rate > p[0]:
                    p[0] = abs(rate)
                if accel > p[1] or -accel > p[1]:
                    p[1] = abs(accel)
            rate = s.rate_deg_s
            if rate > _MOVING_DEG_S or -rate > _MOVING_DEG_S:
                at_rest = False
            angle = s.angle_deg
            if (angle > soft or -angle > soft) and angle * rate > 0:
                self._axis_fault[a] = FAULT_SOFT_LIMIT
                self._limit = True
                self._fault(FAULT_SOFT_LIMIT)
        if self._mode == "stopping" and at_rest:
            self._mode = "stream"
            self._stream_from = None
            self._stream_target = {a: self._state[a].angle_deg for a in self.axes}

    def peaks(
        self, reset: bool = False, following: str = "any"
    ) -> dict[str, dict[str, float]]:
        """The largest |rate| (deg/s) and |acceleration| (deg/s²) each axis made while the servo
        followed its target (servo on, not braking), since the start or the last reset.
        ``following``: ``"any"`` target; ``"profile"``, its own queue or table only (the motion
        the stand plays by itself); ``"stream"``, setpoints streamed by the host only (whose
        timing is the host's: a late or jittered setpoint moves the servo too)."""
        with self._lock:
            out = {}
            for a in self.axes:
                own, st = self._peaks[a], self._peaks_stream[a]
                p = {"any": [max(own[0], st[0]), max(own[1], st[1])], "profile": own,
                     "stream": st}[following]
                out[a] = {"rate_deg_s": p[0], "accel_deg_s2": p[1]}
            if reset:
                self._peaks = {a: [0.0, 0.0] for a in self.axes}
                self._peaks_stream = {a: [0.0, 0.0] for a in self.axes}
        return out

    @property
    def _stop_accel(self) -> float:
        return float(self.limits.accel_deg_s2)

    def _trajectory_tick(self, t: float) -> Sequence[float] | None:
        """The queue's target at ``t`` (lock held); running dry: the normal end or an underrun."""
        q = self._traj
        u = q.base + (t - q.t_start) / q.period_s
        target = q.at(u)
        if target is not None:
            return target
        last, before = q.last_two()
        self._mode = "stream"
        self._stream_from = None
        self._stream_target = {a: float(last[i]) for i, a in enumerate(self.axes)}
        rate = [(x1 - x0) / q.period_s for x1, x0 in zip(last, before, strict=True)]
        # ran dry before its end: an underrun, a controlled stop. The normal end of a queue is
        # its last point repeated (the motion at rest): nothing left to stop.
        if last != before:
            q.underruns += 1
            # the stop continues the path the queue was playing: at this tick the queue's line
            # through its last two points has gone ``past`` beyond the last one; the stop's
            # state is that line one tick back, so its first step lands on it (a step in the
            # target would be a jump of the servo's acceleration: ωn² times the step)
            past = (u - (q.next_index - 1)) * q.period_s - self._tick_s
            self._traj_stop = {a: (float(last[i]) + rate[i] * past, float(rate[i]))
                               for i, a in enumerate(self.axes)}
            self._mode = "traj_stop"
            q.clear()
            return self._traj_stop_tick()
        q.clear()
        return last

    def _traj_stop_tick(self) -> list[float]:
        """After an underrun: go on from the last point at its rate, decelerating within the
        stand's acceleration limit, then hold (lock held). The servo follows this target, and
        a second-order servo following a deceleration overshoots it by a few per cent at its
        start: the target decelerates at ``TRAJ_STOP_SHARE`` of the limit, so the stand's own
        motion stays within it."""
        dv = TRAJ_STOP_SHARE * self._stop_accel * self._tick_s
        out = []
        moving = False
        for a in self.axes:
            x, v = self._traj_stop[a]
            v = 0.0 if abs(v) <= dv else v - math.copysign(dv, v)
            x += v * self._tick_s
            self._traj_stop[a] = (x, v)
            moving = moving or v != 0.0
            out.append(x)
        if not moving:
            self._mode = "stream"
            self._stream_from = None
            self._stream_target = {a: self._traj_stop[a][0] for a in self.axes}
        return out

    def _table_value(self, axis: str, t_rel: float) -> float:
        table = self._tables.get(axis)
        return 0.0 if table is None else table.at(t_rel)

    def _traj_u(self, now: float) -> float | None:
        """The queue position being played (point index, fractional) or None when idle."""
        if self._mode != "trajectory":
            return None
        q = self._traj
        return q.base + (now - q.t_start) / q.period_s

    def _fault(self, code: int) -> None:
        if self._fault_code == 0:
            self._fault_code = code
        self._enabled = False
        if self._mode in ("table", "trajectory", "traj_stop"):
            self._mode = "stream"
            self._traj.clear()

    def _do_estop(self) -> None:
        self._estop = True
        self._fault(FAULT_ESTOP)

    def _apply(
        self,
        kind: str,
        now: float,
        duration_s: float | None = None,
        code: int | None = None,
        count: int | None = None,
    ) -> None:
        """Start a fault (lock held): the one path for ``inject`` and the scheduled faults."""
        until = math.inf if duration_s is None else now + duration_s
        if kind == "drop_connection":
            self._comm.drop_until = until
            self._links_dropped()
        elif kind == "stall":
            self._comm.stall_until = now + (1.0 if duration_s is None else duration_s)
        elif kind == "modbus_exception":
            self._comm.exc_code = code or 4
            self._comm.exc_until = None if duration_s is None else until
            self._comm.exc_count = count
        elif kind == "stand_fault":
            self._fault(code or 10)
        else:
            self._do_estop()
