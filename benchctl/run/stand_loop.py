"""The stand loop: one thread owns the stand's cycle from connect to shutdown.

- **hold** — before and after the motion: read the stand at ``sample_rate_hz``, keep the
  heartbeat;
- **buffered** mode — the profile's points are queued in the stand's trajectory buffer
  ``buffer_s`` ahead (pushes and feedback reads in one Modbus transaction where the map allows
  it); the stand plays them on its own clock, so a host stall shorter than the buffer has no
  effect on the motion at all. The loop polls at ``sample_rate_hz``, tops the queue up, and
  counts underruns: a queue that ran dry while moving makes the stand stop itself within its
  limits; the loop then waits for it to rest and rejoins the profile from there (below);
- **stream** mode — setpoints at ``setpoint_rate_hz`` on ABSOLUTE deadlines
  ``t_start + k·period``; a setpoint goes out within ``SEND_WINDOW`` of a period after its slot,
  or its slot is missed (counted) and never sent late in a burst. After missed slots the stand
  has held its last setpoint, so the loop **rejoins** the profile along a path planned from that
  state within the limits (``benchctl.kinematics.plan_rejoin``): never a jump. A rejoin is an
  event in the recording and counted in the stats;
- **table** mode — the harmonic table is uploaded and started; the loop polls the stand.

Every stand sample reaches the recording through the driver's listener (``Recorder``). Checks on
every sample: fault / E-stop and angle limit (at once); tracking error (measured vs the stand's
own setpoint) and departure from the commanded motion (measured vs the profile as commanded: a
rejoin's path while it lasts, the last setpoint while the stand holds), each over its
tolerance for ``DEBOUNCE`` samples and ``BREACH_HOLD_S`` seconds; a silent instrument. A breach
raises inside the loop thread; the supervisor turns it into the run's fault at once.

Why this module stays whole (about 700 lines): it is one object, the loop thread, and its parts
are that thread's phases. Hold, the three modes and settle all read and write the same state —
the cycle and miss counters and the lateness histogram the run's stats report, the debounce
state of the checks, the reference the departure check follows (``_ref``), the early end asked
for by the main thread (``_end_request``, applied by whichever mode is running) and the rejoin
planning every mode falls back on. Split by mode, each module would reach into the others'
private state. What is not that thread's state lives elsewhere: the commanded points
(``point_source``), the stand shared between threads (``serialized_stand``).
"""

from __future__ import annotations

import bisect
import logging
import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from benchctl.clock import REAL, Clock, ThreadLike
from benchctl.devices.base import AngleSensor, Stand, StandSample, TrajectoryStand
from benchctl.errors import DeviceError, LimitError, SafetyAbort, StandFault
from benchctl.kinematics import (
    AxisCommand,
    Limits,
    Rejoin,
    StaleSetpoint,
    plan_rejoin,
    profile_peaks,
)
from benchctl.run.live import CommandStats, Histogram
from benchctl.run.plan import MotionPlan
from benchctl.run.point_source import PointSource
from benchctl.run.realtime import PrioritySetter, RealtimeResult, request_realtime
from benchctl.run.recorder import Recorder
from benchctl.run.state import RunState, StateMachine
from benchctl.run.supervisor import Supervisor

log = logging.getLogger(__name__)

SEND_WINDOW = 0.25  # a setpoint goes out within this fraction of a period after its slot, or not
DEBOUNCE = 3  # consecutive stand samples over a tolerance before the run aborts …
# … held for this long: a stand that really does not follow stays over for longer
BREACH_HOLD_S = 0.25
HOST_STALL_S = 0.1  # waking up later than this: the process itself was held up
SETTLE_TIMEOUT_S = 10.0  # after the profile: wait this long at most for the stand to come to rest
REST_RATE_DEG_S = 0.5  # "at rest": |rate| below this on every axis
UNDERRUN_STOP_S = 10.0  # after an underrun the stand must be at rest within this


@dataclass
class LoopLimits:
    angle_deg: float
    tracking_tolerance_deg: float
    profile_tolerance_deg: float
    silence_timeout_s: float
    heartbeat_period_s: float
    sample_rate_hz: float
    zero_tolerance_deg: float
    rate_deg_s: float = math.inf
    accel_deg_s2: float = math.inf
    buffer_s: float = 1.0  # buffered mode: how far ahead the queue is kept
    following_lag_s: float = 0.0  # the stand trails its setpoint by this × its rate

    @property
    def kinematic(self) -> Limits:
        return Limits(self.angle_deg, self.rate_deg_s, self.accel_deg_s2)


class StandLoop:
    """The thread that owns the stand's cycle (hold → motion → settle → hold)."""

    def __init__(
        self,
        stand: Stand,
        recorder: Recorder,
        supervisor: Supervisor,
        machine: StateMachine,
        plan: MotionPlan,
        limits: LoopLimits,
        *,
        clock: Clock = REAL,
        host_cost_s: float = 0.0,
        realtime_priority: int | None = None,
        priority_setter: PrioritySetter | None = None,
    ) -> None:
        #: SCHED_FIFO priority this thread asks for first (``run.realtime_priority``; never on
        #: simulated time); ``priority_setter``: the OS's by default (``benchctl.run.realtime``)
        self.realtime_priority = None if clock.virtual else realtime_priority
        self._priority_setter = priority_setter
        #: what the request got (None: not asked), set once ``realtime_known`` is
        self.realtime: RealtimeResult | None = None
        self.realtime_known = clock.event()
        #: the host computation each cycle is charged on simulated time (``clock.compute``; the
        #: real clock charges nothing: the computation itself takes the time)
        self.host_cost_s = host_cost_s
        self.stand = stand
        self.rec = recorder
        self.sup = supervisor
        self.machine = machine
        self.plan = plan
        self.lim = limits
        self.clock = clock
        self._stop = clock.event()
        self._go = clock.event()
        self.motion_done = clock.event()
        self.lateness = Histogram()
        self.cmd = CommandStats(plan.period_s)
        self.rejoins = 0
        self.stale_setpoints = 0
        self.underruns = 0
        self.missed_cycles = 0
        self.cycles = 0
        self.setpoints_sent = 0
        self.t_motion_start: float | None = None
        self.t_motion_end: float | None = None
        self.t_last_cycle: float | None = None
        self.t_resumed = -math.inf  # when this process last resumed after a stall
        self._t_heartbeat = -math.inf
        self._over: dict[str, tuple[int, float]] = {}
        # the commanded motion at profile time t, for the departure check (None: the profile)
        self._ref: Callable[[float], dict[str, float]] | None = None
        self._sent: list[tuple[int, dict[str, float]]] = []  # stream: recent (slot, setpoint)
        self._thread: ThreadLike | None = None
        self._ident: int | None = None  # the loop thread's, once it runs
        # an early end asked for by the main thread (request_end); applied by this thread at
        # the next slot not yet sent or queued
        self._end_request: dict[str, Any] | None = None
        self.ended_early: dict[str, Any] | None = None  # where the early fade-out began
        # the event marking the motion's start (the equalisation pre-test names its own, so
        # the recording's motion_start stays the profile's)
        self.motion_event = "motion_start"

    # control from the main thread
    def start(self) -> None:
        self._thread = self.sup.thread("stand loop", self._run)
        self._thread.start()

    def begin_motion(self) -> None:
        self._go.set()

    def request_end(self, **fields: Any) -> None:
        """End the motion early (stream and buffered modes): from the next slot not yet sent
        or queued, the profile fades out over its own ``fade_out_s`` (lengthened when needed to
        stay within the rate and acceleration limits) and the run goes on as at a normal end
        (fade-out, settle, analysis). ``fields`` go into the ``early_stop`` event. Ignored
        once the profile's own fade-out has begun, or when asked for again."""
        if self._end_request is None:
            self._end_request = dict(fields)

    def _apply_end(self, k: int) -> MotionPlan:
        """In this thread: the plan ended early from slot ``k`` (see ``request_end``); the
        plan unchanged when its own fade-out is already on or no fade fits the limits."""
        req, plan = self._end_request, self.plan
        if req is None or self.ended_early is not None:
            return plan
        self._end_request = {}  # handled: once only
        steady_end = round((plan.duration_s - plan.fade_out_s) / plan.period_s)
        if k >= steady_end or plan.mode == "table":
            self.rec.event("early_stop_skipped", slot=k, reason="the profile's fade-out has begun")
            return plan
        fade = max(plan.fade_out_s, 2 * plan.period_s)
        lim = self.lim
        for factor in (1.0, 1.5, 2.0, 3.0, 4.0):
            new = plan.ending_at(k, fade * factor)
            lo = max(0, k - 2)
            ok = all(
                r <= lim.rate_deg_s * (1 + 1e-9) and acc <= lim.accel_deg_s2 * (1 + 1e-9)
                for r, acc in (profile_peaks(v[lo:], plan.period_s) for v in new.values.values())
            )
            if ok:
                break
        else:
            self.rec.event("early_stop_skipped", slot=k,
                           reason="no fade-out from here within the rate/acceleration limits")
            return plan
        self.ended_early = {"slot": k, "t_profile_s": k * plan.period_s,
                            "fade_out_s": new.fade_out_s}
        self.rec.event("early_stop", **req, **self.ended_early)
        self.plan = new
        return new

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        t = self._thread
        if t is not None and threading.get_ident() != self._ident:
            t.join(timeout_s)
            if t.is_alive():
                log.error("stand loop did not stop within %.1f s", timeout_s)

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _stopping(self) -> bool:
        return self._stop.is_set() or self.sup.stop_event.is_set()

    def _wait_until(self, deadline: float) -> bool:
        """Sleep until ``deadline``; False when the loop must stop. Waking up more than
        ``HOST_STALL_S`` late means this process was held up: that moment is noted
        (``t_resumed``), so silence is not counted across the host's own stall."""
        while True:
            now = self.clock.monotonic()
            if now >= deadline:
                if now - deadline > HOST_STALL_S:
                    self.t_resumed = now
                return not self._stopping()
            if self._stop.wait(min(deadline - now, 0.05)) or self.sup.stop_event.is_set():
                return False

    # the thread
    def _run(self) -> None:
        self._ident = threading.get_ident()
        if self.realtime_priority is not None:  # for this thread (pid 0: the calling thread)
            self.realtime = request_realtime(self.realtime_priority, self._priority_setter)
            (log.info if self.realtime.granted else log.warning)("stand loop: %s",
                                                                 self.realtime.detail)
        self.realtime_known.set()
        self._hold(until_go=True)
        if self._stopping():
            return
        if self.plan.mode == "table":
            self._table()
        elif self.plan.mode == "buffered":
            self._buffered()
        else:
            self._stream()
        if self._stopping():
            return
        self.t_motion_end = self.clock.monotonic()
        self._settle()
        if self._stopping():
            return
        self.motion_done.set()
        self._hold(until_go=False)

    def _heartbeat(self, now: float) -> None:
        if now - self._t_heartbeat >= self.lim.heartbeat_period_s:
            self.stand.heartbeat()
            self._t_heartbeat = now

    def instrument_silence(self, now: float) -> float:
        """How long the instrument has been silent, counted from its last sample or from the
        end of the last stall of this process, whichever is later (a stalled host reads no
        frames; the reader needs a moment after it to catch up)."""
        t = self.rec.t_last_instrument
        since = self.rec.t_last_instrument_ref if t is None else t
        if since is None:
            return 0.0
        return now - max(since, self.t_resumed)

    def _check_instrument(self, now: float) -> None:
        silent = self.instrument_silence(now)
        if silent > self.lim.silence_timeout_s:
            raise SafetyAbort(
                f"instrument silent: no sample for {silent:.2f} s "
                f"(silence_timeout_s = {self.lim.silence_timeout_s} s)"
            )

    def _sample(self, profile_t: float | None) -> StandSample:
        s = self.stand.read_sample()  # recorded by the driver's listener, fault bits included
        self._check_sample(s, profile_t)
        return s

    def _over_tol(self, key: str, over: bool, t: float) -> bool:
        """True once ``over`` has held for ``DEBOUNCE`` samples and ``BREACH_HOLD_S`` seconds."""
        if not over:
            self._over.pop(key, None)
            return False
        n, t0 = self._over.get(key, (0, t))
        self._over[key] = (n + 1, t0)
        return n + 1 >= DEBOUNCE and t - t0 >= BREACH_HOLD_S

    def _check_sample(self, s: StandSample, profile_t: float | None) -> None:
        st = s.status
        if st.estop:
            raise StandFault("stand reports E-stop", st.fault_code)
        if st.fault:
            raise StandFault(f"stand reports fault code {st.fault_code}", st.fault_code)
        for a, v in s.angle_deg.items():
            if abs(v) > self.lim.angle_deg:
                raise SafetyAbort(f"limit breach: {a} angle {v:.3f}° beyond ±{self.lim.angle_deg}°")
        if profile_t is None:
            return
        ref = self._ref(profile_t) if self._ref is not None else self.plan.at(profile_t)
        # a servo trails its setpoint by its following lag × its rate: that is following, not
        # a stand that does not follow (stand.following_lag_s)
        lag = self.lim.following_lag_s
        track = {
            a: s.angle_deg[a] - s.setpoint_deg[a] + lag * s.rate_deg_s.get(a, 0.0)
            for a in self.plan.axes if a in s.setpoint_deg
        }
        dep = {a: s.angle_deg[a] - ref[a] for a in self.plan.axes}
        self.rec.live.tracking_error_deg = track
        self.rec.live.departure_deg = dep
        for a, e in track.items():
            if self._over_tol("track " + a, abs(e) > self.lim.tracking_tolerance_deg, s.t_host):
                lagged = (f", its following lag {lag:g} s × rate allowed" if lag > 0 else "")
                raise SafetyAbort(
                    f"tracking error on {a}: {e:+.3f}° (measured − stand setpoint{lagged}) "
                    f"beyond ±{self.lim.tracking_tolerance_deg}° (stand.tracking_tolerance_deg)"
                )
        for a, e in dep.items():
            over = abs(e) > self.lim.profile_tolerance_deg
            if self._over_tol("depart " + a, over, s.t_host):
                raise SafetyAbort(
                    f"stand departs from the profile on {a}: {e:+.3f}° at t = {profile_t:.2f} s "
                    f"beyond ±{self.lim.profile_tolerance_deg}° (run.profile_tolerance_deg)"
                )

    def _hold(self, until_go: bool) -> None:
        period = 1.0 / self.lim.sample_rate_hz
        t0 = self.clock.monotonic()
        k = 0
        while not self._stopping():
            if until_go and self._go.is_set():
                return
            if not self._wait_until(t0 + k * period):
                return
            now = self.clock.monotonic()
            k = max(k + 1, int((now - t0) / period) + 1)
            self._heartbeat(now)
            self._sample(None)
            self._check_instrument(now)
            self.t_last_cycle = now

    def _advance_state(self, t_profile: float) -> None:
        target = self.plan.state_at(t_profile)
        if self.machine.state is not target:
            self.machine.advance_to(target)
            # the running σ shown live covers the steady part, like the verdict
            self.rec.sigma.active = target is RunState.RUNNING

    def _start_motion(self, t_start: float) -> None:
        self.t_motion_start = t_start
        self.rec.live.t_motion_start = t_start
        self.rec.event(self.motion_event, t_host=t_start, mode=self.plan.mode)
        self._advance_state(0.0)

    def _stream(self) -> None:
        plan = self.plan
        period = plan.period_s
        t_start = self.clock.monotonic() + period  # first slot one period ahead
        self._start_motion(t_start)
        k = 0
        rejoin: Rejoin | None = None
        last: dict[str, AxisCommand] | None = None  # the last setpoint sent and its step's rate
        self._ref = self._commanded_stream
        held = False  # slots were missed since: the stand has held `last`
        while True:
            deadline = t_start + k * period
            if not self._wait_until(deadline):
                return
            now = self.clock.monotonic()
            late = now - deadline
            if late >= SEND_WINDOW * period:
                # stalled: no burst. A slot whose moment has passed by more than the send window
                # is missed (counted); the stand holds its last setpoint, and the loop rejoins
                # the profile from there at the next slot, within the limits.
                skip = int(late / period) + 1
                self.missed_cycles += skip
                k += skip
                held = True
                continue
            if self._end_request and (rejoin is None or k >= rejoin.first_slot + rejoin.n):
                plan = self._apply_end(k)  # an early end: fade out from this slot
            src = PointSource(plan, k, rejoin)
            if k >= src._end():
                break
            if held and last is not None:
                at_rest = {a: AxisCommand(c.angle_deg, 0.0) for a, c in last.items()}
                rejoin = self._plan_rejoin(k, at_rest, deadline)
                src = PointSource(plan, k, rejoin)
            self.lateness.add(late)
            sp = src.value(k)
            try:
                # one transaction where the stand takes it (Modbus FC23): write, then read back
                _t_send, s = self.stand.send_setpoint_and_read(sp, t_slot=deadline)
            except StaleSetpoint as e:
                # sent so late that the stand held its last setpoint: nothing was sent; rejoin
                self.stale_setpoints += 1
                log.info("stale setpoint at slot %d: %s", k, e)
                held = True
                k += 1
                continue
            self.cmd.add(sp, held=held)
            self._sent.append((k, sp))
            if len(self._sent) > 512:
                del self._sent[:256]
            prev = last
            last = {
                a: AxisCommand(x, 0.0 if prev is None else (x - prev[a].angle_deg) / period)
                for a, x in sp.items()
            }
            held = False
            self.setpoints_sent += 1
            self._heartbeat(now)
            self._check_sample(s, s.t_host - t_start)
            self._check_instrument(now)
            self._advance_state(min(k * period, plan.duration_s))
            self._cycle_done(now)
            k += 1

    def _commanded_stream(self, t: float) -> dict[str, float]:
        """Stream mode: the setpoint in force at profile time ``t`` — linear between two
        consecutive slots sent, the last one held across missed slots."""
        sent = self._sent
        x = t / self.plan.period_s
        i = bisect.bisect_right(sent, x, key=lambda e: e[0]) - 1
        if i < 0:
            return self.plan.at(t)
        k0, v0 = sent[i]
        if i + 1 < len(sent) and sent[i + 1][0] == k0 + 1:
            v1, w = sent[i + 1][1], x - k0
            return {a: v0[a] + w * (v1[a] - v0[a]) for a in v0}
        return dict(v0)

    def _plan_rejoin(
        self, slot: int, last: Mapping[str, AxisCommand], t_slot: float
    ) -> Rejoin:
        """Plan the way back onto the profile at ``slot`` from ``last`` (the stand at rest there
        after holding, or stopped after an underrun); record it; suspend the departure check
        while it lasts."""
        plan = self.plan
        try:
            rej = plan_rejoin(
                plan.values, slot, last, self.lim.kinematic, plan.period_s, plan.peaks
            )
        except LimitError as e:
            raise SafetyAbort(f"cannot rejoin the profile within the stand limits: {e}") from None
        self.rejoins += 1
        dur = rej.n * plan.period_s
        k_prev = max(0, min(slot, plan.n_slots - 1) - 1)
        dev = {a: last[a].angle_deg - float(plan.values[a][k_prev]) for a in last}
        self.rec.event(
            "rejoin", t_slot=t_slot, slot=slot, points=rej.n, duration_s=dur, deviation_deg=dev
        )
        return rej

    # -- buffered trajectory -------------------------------------------------------------
    def _traj_stand(self) -> TrajectoryStand:
        st = self.stand
        if not isinstance(st, TrajectoryStand):
            raise DeviceError(
                "stand.mode buffered: the stand's driver has no trajectory queue (expected "
                "trajectory_limits, begin_trajectory, push_points and start_trajectory)"
            )
        return st

    def _buffered(self) -> None:
        plan = self.plan
        T = plan.period_s
        st = self._traj_stand()
        capacity, per_push = st.trajectory_limits
        lead = int(min(max(2 * per_push, round(self.lim.buffer_s / T)), capacity - per_push))
        poll = 1.0 / self.lim.sample_rate_hz
        src = PointSource(plan, 0)
        base = 0  # the queue's point j is the profile's slot base + j
        first = True
        while True:
            self._ref = src.at
            t0, j_next = self._traj_start(st, src, base, lead, per_push, first)
            first = False
            stop = self._traj_poll(st, src, base, t0, j_next, lead, per_push, poll)
            if stop is None:
                return
            if stop == "done":
                break
            # an underrun: the stand stopped itself; rejoin the profile from where it rests
            s = self._await_rest_after_underrun()
            k_now = base + round((self.clock.monotonic() - t0) / T)
            held = {a: AxisCommand(s.setpoint_deg[a], 0.0) for a in plan.axes}
            rejoin = self._plan_rejoin(k_now, held, self.clock.monotonic())
            src = PointSource(self.plan, rejoin.first_slot, rejoin)
            base = rejoin.first_slot

    def _traj_start(
        self, st: Any, src: PointSource, base: int, lead: int, per_push: int, first: bool
    ) -> tuple[float, int]:
        """Queue ``lead`` points and start the trajectory; returns (start time, next index)."""
        st.begin_trajectory()
        s = self.rec.last_stand
        if s is not None:
            self.cmd.restart({a: s.setpoint_deg.get(a, 0.0) for a in self.plan.axes})
        j_next = 0
        pending: list[tuple[int, dict[str, float]]] = []
        while j_next < lead and not src.done:
            pts = src.take(per_push)
            if not pts:
                break
            st.push_points(j_next, self._arrays(pts), read=False)
            j_next += len(pts)
            pending += pts
        t0 = float(st.start_trajectory())
        if first:
            self._start_motion(t0)
        self._record_points(t0, base, pending)
        return t0, j_next

    def _arrays(self, pts: list[tuple[int, dict[str, float]]]) -> dict[str, np.ndarray]:
        for _, v in pts:
            self.cmd.add(v)
        return {a: np.array([v[a] for _, v in pts]) for a in self.plan.axes}

    def _record_points(
        self, t0: float, base: int, pts: list[tuple[int, dict[str, float]]]
    ) -> None:
        T = self.plan.period_s
        now = self.clock.monotonic()
        self.rec.points(now, [(t0 + (k - base) * T, v) for k, v in pts])
        self.setpoints_sent += len(pts)

    def _traj_poll(
        self,
        st: Any,
        src: PointSource,
        base: int,
        t0: float,
        j_next: int,
        lead: int,
        per_push: int,
        poll: float,
    ) -> str | None:
        """Poll the stand and top the queue up until the end ("done"), an underrun
        ("underrun") or a stop (None)."""
        plan = self.plan
        T = plan.period_s
        played = 0
        underruns: int | None = None
        i = 1
        while True:
            nxt = self._next_poll(t0, i, poll)
            if nxt is None:
                return None
            i, now = nxt
            if self._end_request and not src.done and (
                src.rejoin is None or src.k >= src.rejoin.first_slot + src.rejoin.n
            ):
                plan = src.plan = self._apply_end(src.k)  # an early end: fade out from here
            if not src.done and j_next - played < lead:
                pts = src.take(per_push)
                s = st.push_points(j_next, self._arrays(pts), read=True)
                j_next += len(pts)
                self._record_points(t0, base, pts)
            else:
                s = st.read_sample()
            tr = s.trajectory
            if tr is None:
                raise SafetyAbort("buffered mode: the stand reports no trajectory queue")
            played = tr.played
            stopped_early = not s.status.trajectory_running and not src.done and j_next > played
            if (underruns is not None and tr.underruns != underruns) or stopped_early:
                # the queue ran dry (a host stall longer than the buffer): the stand is stopping
                # itself within its limits, so this sample is not judged against the profile
                self.underruns += max(1, (tr.underruns - (underruns or 0)) & 0xFFFF)
                self.rec.event("underrun", t_host=s.t_host, played=tr.played, queued=j_next)
                self._check_sample(s, None)
                return "underrun"
            underruns = tr.underruns
            slot_t = (base + (s.t_host - t0) / T) * T
            in_profile = slot_t <= plan.duration_s and s.status.trajectory_running
            self._check_sample(s, slot_t if in_profile else None)
            self._check_instrument(now)
            self._advance_state(min(max(slot_t, 0.0), plan.duration_s))
            self._cycle_done(now)
            i += 1
            if src.done and not s.status.trajectory_running:
                return "done"

    def _next_poll(self, t0: float, i: int, period: float) -> tuple[int, float] | None:
        """Wait for poll ``i`` of a fixed-rate poll from ``t0`` and keep the heartbeat; after a
        stall the missed polls are skipped (counted), never made up in a burst. Returns
        (i, now), or None when the loop must stop."""
        deadline = t0 + i * period
        if not self._wait_until(deadline):
            return None
        now = self.clock.monotonic()
        late = now - deadline
        if late >= period:
            skip = int(late / period)
            self.missed_cycles += skip
            i += skip
            late = now - (t0 + i * period)
        self.lateness.add(late)
        self._heartbeat(now)
        return i, now

    def _cycle_done(self, now: float) -> None:
        self.cycles += 1
        self.t_last_cycle = now
        if self.host_cost_s:
            self.clock.compute(self.host_cost_s)

    def _await_rest_after_underrun(self) -> StandSample:
        period = 1.0 / self.lim.sample_rate_hz
        t_end = self.clock.monotonic() + UNDERRUN_STOP_S
        while True:
            now = self.clock.monotonic()
            self._heartbeat(now)
            s = self._sample(None)
            self.t_last_cycle = now
            if not s.status.trajectory_running and not s.status.moving:
                return s
            if now > t_end:
                raise SafetyAbort(
                    f"stand not at rest {UNDERRUN_STOP_S:.0f} s after a trajectory underrun"
                )
            if not self._wait_until(now + period):
                raise SafetyAbort("stopped while waiting for the stand after an underrun")

    def _table(self) -> None:
        plan = self.plan
        assert plan.tables is not None
        period = 1.0 / self.lim.sample_rate_hz
        t_start = self.stand.start_table()
        self._start_motion(t_start)
        k = 1
        while True:
            nxt = self._next_poll(t_start, k, period)
            if nxt is None:
                return
            k, now = nxt
            s = self.stand.read_sample()
            t_prof = s.t_host - t_start
            self._check_sample(s, t_prof if t_prof <= plan.duration_s else None)
            self._check_instrument(now)
            self._advance_state(min(t_prof, plan.duration_s))
            self._cycle_done(now)
            if t_prof > plan.duration_s:
                break
            k += 1
        self.stand.stop_table()

    def _settle(self) -> None:
        """After the profile: keep recording until the stand is at rest near zero."""
        period = 1.0 / self.lim.sample_rate_hz
        t0 = self.clock.monotonic()
        k = 1
        while self.clock.monotonic() - t0 < SETTLE_TIMEOUT_S:
            if not self._wait_until(t0 + k * period):
                return
            now = self.clock.monotonic()
            k = max(k + 1, int((now - t0) / period) + 1)
            self._heartbeat(now)
            s = self._sample(None)
            self._check_instrument(now)
            if all(abs(v) <= self.lim.zero_tolerance_deg for v in s.angle_deg.values()) and all(
                abs(v) <= REST_RATE_DEG_S for v in s.rate_deg_s.values()
            ):
                return
        raise SafetyAbort(
            f"stand not at rest {SETTLE_TIMEOUT_S:.0f} s after the profile ended "
            f"(zero_tolerance_deg = {self.lim.zero_tolerance_deg}°)"
        )

    def stats(self) -> dict[str, Any]:
        lat = self.lateness.summary()
        return {
            "cycles": self.cycles,
            "setpoints_sent": self.setpoints_sent,
            "missed_cycles": self.missed_cycles,
            "rejoins": self.rejoins,
            "stale_setpoints": self.stale_setpoints,
            "underruns": self.underruns,
            "commanded": self.cmd.summary(),
            "cycle_lateness_s": lat,
            "stand_rtt_s": self.rec.rtt.summary(),
            "instrument_samples": self.rec.n_instrument,
            "instrument_lost": self.rec.instrument_lost,
            "motion_start": self.t_motion_start,
            "motion_end": self.t_motion_end,
        }


def start_instrument(sensor: AngleSensor, recorder: Recorder) -> None:
    """Start the instrument's reader wired straight into the recording and the supervisor."""
    recorder.t_last_instrument_ref = recorder.clock.monotonic()
    sensor.start(recorder.on_sample, recorder.on_error)
