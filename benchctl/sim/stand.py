"""Simulated roll/pitch stand: a real Modbus server (TCP, or RTU on a pty) with servo physics.

The register map is the same YAML file the driver reads (``drivers/stand_generic.yaml``), so the
driver cannot tell this stand from hardware. Every request reaches the stand through one entry
point, ``benchctl.sim.stand_wire.StandWire`` (pymodbus's framing, the stand's own request
decoder, pymodbus's register model), fed by a TCP socket, a pty or an in-process link
(``benchctl.sim.stand_servers``, ``transport="channel"``). Threads:

- ``sim-stand-modbus``: the server (socket, pty or link). Reads of the feedback block
  are filled from the latest physics state; writes of the control word, heartbeat, setpoints
  and table area act on the physics state at once. Requests outside the map are refused as the
  Modbus specification says (``_MapDecoder``); other unit ids: TCP exception 0x0B, RTU silence.
- ``sim-stand-physics``: ticks the servo at ``tick_hz`` on absolute times (the stand's clock:
  the host's, or simulated time), integrating missed ticks when the thread was late, and checks
  the watchdog, soft limits, table playback and scheduled faults. The watchdog counts the
  host's heartbeat silence, not this simulator's own hold-ups: when nothing of the simulator ran
  for longer than ``SIM_HOLDUP_S`` (its physics had not been advanced — the process was not
  scheduled), the host's requests waited unread meanwhile, and that time is not the host's
  silence (a stand's controller is never held up by the host computer's scheduler).

On RTU each request is taken after its bytes' serial time on the line, and each reply is
written after its own (10 bits a byte at ``baudrate``), on the pty and the link alike.

Fault injection (:meth:`SimStand.inject`, or ``SimStandConfig.faults`` on a schedule):

================= ======================================================================
drop_connection   TCP: the server closes every client connection, and any new one as soon
                  as it sends a request; RTU: the line goes dead (no byte passes).
                  ``duration_s`` (default: until :meth:`clear_faults`).
stall             requests are neither acted on nor answered for ``duration_s`` (default 1).
modbus_exception  every request is answered with exception ``code`` (default 4) for
                  ``duration_s`` or the next ``count`` requests (default: until cleared).
stand_fault       the stand faults with ``code`` (default 10): brakes to rest, servo off,
                  latched until a fault reset over Modbus.
estop             the E-stop is pressed: as stand_fault with code 3 and the E-stop bit.
================= ======================================================================
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerRTU
from pymodbus.pdu import DecodePDU, ExceptionResponse, ModbusPDU
from pymodbus.simulator import DataType, SimData

from benchctl.channels import Endpoint
from benchctl.channels import link as channel_link
from benchctl.clock import REAL, Clock
from benchctl.config import SimStandConfig, StandLimits
from benchctl.devices.modbus.regmap import Field, RegisterMap, load_register_map
from benchctl.errors import ConfigError, DeviceError
from benchctl.faultspec import FaultSpecError, check_params
from benchctl.harmonics import HarmonicTable
from benchctl.sim.servo import AxisState, ServoModel, brake_step, quantise
from benchctl.sim.stand_servers import RtuStandServer, TcpStandServer

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
class _CommFaults:
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


class SimStand:
    """A simulated two-axis stand speaking Modbus over TCP on 127.0.0.1 or RTU over a pty.

    Parameters
    ----------
    sim_cfg
        Servo physics, watchdog, tick rate, scheduled faults.
    limits
        The bench's stand limits (documentation of the stand; the soft limit in ``sim_cfg``
        is what makes it fault).
    register_map
        Path of the register-map YAML shared with the driver.
    transport
        ``"tcp"`` (``host``, ``port``; port 0 picks a free port), ``"rtu"`` (a pty pair;
        ``serial_port`` is the path for the client, also symlinked at ``link_path``) or
        ``"channel"``: an in-process link on ``clock`` (:mod:`benchctl.channels`) carrying
        ``framing`` frames (``"tcp"`` MBAP or ``"rtu"``, whose bytes take their serial byte
        time), the host end in :attr:`client_endpoint` once started. Every transport hands
        request bytes to the stand's one entry point, :class:`benchctl.sim.stand_wire.StandWire`
        (the pymodbus server for tcp/rtu frames them the same way).
    clock
        Time for the physics, the watchdog and the channel (default: the real clock).
    device_id
        The Modbus unit id this stand answers.
    """

    def __init__(
        self,
        sim_cfg: SimStandConfig,
        *,
        limits: StandLimits,
        register_map: Path,
        transport: Literal["tcp", "rtu", "channel"] = "tcp",
        host: str = "127.0.0.1",
        port: int = 0,
        link_path: Path | None = None,
        device_id: int = 1,
        clock: Clock = REAL,
        framing: Literal["tcp", "rtu"] | None = None,
        channel_latency_s: float = 0.0005,
    ) -> None:
        if transport not in ("tcp", "rtu", "channel"):
            raise ConfigError(f"SimStand: transport {transport!r}: expected tcp, rtu or channel")
        self.clock = clock
        #: the frames on the wire: MBAP (tcp) or RTU; a channel carries either
        self.framing: Literal["tcp", "rtu"] = (
            framing if framing is not None else ("rtu" if transport == "rtu" else "tcp")
        )
        self.channel_latency_s = channel_latency_s
        #: the host end of the in-process link (transport "channel"), once started, and its
        #: device end (the stand's)
        self.client_endpoint: Endpoint | None = None
        self.device_endpoint: Endpoint | None = None
        self.cfg = sim_cfg
        self.limits = limits
        self.map: RegisterMap = load_register_map(register_map)
        self.transport = transport
        self.host = host
        self.port = port
        self.link_path = link_path
        self.device_id = device_id
        self.serial_port: str | None = None
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
        self._fb_span = self.map.feedback_span()
        self._watchdog_s = sim_cfg.watchdog_s
        self.requests = 0  # requests served (for tests and figures)
        self.enables = 0  # times the servo was switched on (for tests: was the stand touched?)

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
        self._comm = _CommFaults()
        self._traj = _TrajectoryQueue(len(self.axes))
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

        self._regs: list[int] | None = None
        self._regs_start = 0
        self._server: TcpStandServer | RtuStandServer | None = None
        self._threads: list[Any] = []
        self._stop_evt = clock.event()
        self._started = False
        self._stopped = False

    # -- life cycle ---------------------------------------------------------------------
    def start(self) -> SimStand:
        """Start physics and the Modbus server; returns once the server listens."""
        if self._started:
            raise DeviceError("SimStand already started")
        self._started = True
        try:
            self._start()
        except BaseException:
            self.stop()
            raise
        return self

    def _start(self) -> None:
        now = self.clock.monotonic()
        self._t0 = now
        self._clock_on = True
        self._hb_time = now
        self._start_time = now
        if self.transport == "channel":
            self._start_channel()
            return
        if self.clock.virtual:
            raise ConfigError("SimStand: simulated time needs transport 'channel' (a socket or a "
                              "pty runs on the host's time)")
        if self.transport == "rtu":
            byte_time = 10.0 / self.cfg.baudrate if self.cfg.rtu_wire_delay else 0.0
            rtu = RtuStandServer(
                self, byte_time, lambda: self._comm.dropped(self.clock.monotonic()), self.link_path
            )
            self._server = rtu
            self.serial_port = rtu.client_path
        else:
            tcp = TcpStandServer(self, self.host, self.port)
            self._server = tcp
            self.port = tcp.port
        physics = self.clock.thread(self._physics_loop, name="sim-stand-physics")
        self._threads.append(physics)
        physics.start()
        self._server.start()

    def _start_channel(self) -> None:
        """Transport "channel": the link, a server thread and a physics thread on the clock."""
        from benchctl.sim.stand_wire import StandWire, serve_endpoint, serve_on_arrival

        byte_time = 0.0
        if self.framing == "rtu" and self.cfg.rtu_wire_delay:
            byte_time = 10.0 / self.cfg.baudrate
        host, device = channel_link(
            self.clock, "sim-stand", byte_time_s=byte_time, latency_s=self.channel_latency_s
        )
        self.client_endpoint = host
        self.device_endpoint = device
        wire = StandWire(self, self.framing)
        # on simulated time the physics thread wakes every 50 ticks (each request brings the
        # state to its own instant first): the same states, far fewer hand-overs
        physics = self.clock.thread(
            self._physics_loop, name="sim-stand-physics", args=(50 if self.clock.virtual else 1,)
        )
        self._threads.append(physics)
        physics.start()
        if self.clock.virtual:  # the server's loop run by the clock at each request's arrival
            serve_on_arrival(wire, device, self._stop_evt, "sim-stand-modbus")
            return
        server = self.clock.thread(
            serve_endpoint, name="sim-stand-modbus", args=(wire, device, self._stop_evt)
        )
        self._threads.append(server)
        server.start()

    def stop(self) -> None:
        """Stop the server, physics and relay; closes every port, thread and fd. Idempotent."""
        if self._stopped:
            return
        self._stopped = True
        self._stop_evt.set()
        if self.transport == "channel" and self.client_endpoint is not None:
            self.client_endpoint.close()
        if self._server is not None:
            self._server.stop()
        for t in self._threads:
            t.join(timeout=10)

    def __enter__(self) -> SimStand:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()

    @property
    def endpoint(self) -> str:
        if self.transport == "channel":
            return f"modbus-{self.framing} in-process channel (device id {self.device_id})"
        if self.transport == "tcp":
            return f"modbus-tcp {self.host}:{self.port} (device id {self.device_id})"
        return f"modbus-rtu {self.serial_port} (device id {self.device_id})"

    # -- what tests and the simulated instrument see ---------------------------------------
    def true_angles(self, t: float) -> dict[str, float]:
        """True (unquantised) angles in degrees at host monotonic time ``t``, interpolated.

        The history reaches back about 4 s; earlier or later times are clamped to its ends.
        """
        with self._lock:
            self._advance(min(t + self._tick_s, self.clock.monotonic()))  # a late physics thread
            k_end = self._k
            n = self._hist.shape[0]
            u = (t - self._t0) / self._tick_s
            u = min(max(u, max(0, k_end - n + 2)), k_end)
            k0 = math.floor(u)
            k1 = min(k0 + 1, k_end)
            w = u - k0
            row = (1.0 - w) * self._hist[k0 % n] + w * self._hist[k1 % n]
        return {a: float(row[i]) for i, a in enumerate(self.axes)}

    def true_angles_many(self, ts: np.ndarray) -> dict[str, np.ndarray]:
        """``true_angles`` at each of ``ts`` (increasing), in one call: the same numbers."""
        ts = np.asarray(ts, dtype=float)
        with self._lock:
            self._advance(min(float(ts[-1]) + self._tick_s, self.clock.monotonic()))
            k_end = self._k
            n = self._hist.shape[0]
            u = (ts - self._t0) / self._tick_s
            u = np.minimum(np.maximum(u, max(0, k_end - n + 2)), k_end)
            k0 = np.floor(u).astype(np.int64)
            k1 = np.minimum(k0 + 1, k_end)
            w = (u - k0)[:, None]
            hist = self._hist  # rows k0 % n and k1 % n
            rows = (1.0 - w) * hist.take(k0, 0, mode="wrap") + w * hist.take(k1, 0, mode="wrap")
        return {a: rows[:, i] for i, a in enumerate(self.axes)}

    def servo_response(self, f_hz: float) -> complex:
        """Small-signal angle/setpoint response at ``f_hz`` (see ``ServoModel.response``)."""
        return complex(self.model.response(f_hz))

    # -- fault injection ----------------------------------------------------------------
    def inject(self, kind: str, **params: Any) -> None:
        """Inject a fault now (kinds and parameters in the module docstring)."""
        try:  # the one table of kinds and parameters, shared with the config validator
            params = check_params("stand", kind, params)
        except FaultSpecError as e:
            raise ConfigError(f"SimStand.inject({kind}): {e}") from None
        code = params.get("code")
        dur = params.get("duration_s")
        count = params.get("count")
        with self._lock:
            self._apply(
                kind,
                self.clock.monotonic(),
                None if dur is None else float(dur),
                None if code is None else int(code),
                None if count is None else int(count),
            )

    def place(self, angle_deg: dict[str, float]) -> None:
        """Leave the stand at rest at ``angle_deg`` (axes left out: where they are), servo off
        — a stand an earlier session left off zero. Refused while the servo is on."""
        unknown = sorted(set(angle_deg) - set(self.axes))
        if unknown:
            raise ConfigError(f"SimStand.place: no axis {unknown} (axes: {list(self.axes)})")
        with self._lock:
            if self._enabled:
                raise DeviceError("SimStand.place: the servo is on (disable it first)")
            self._advance(self.clock.monotonic())
            for a, v in angle_deg.items():
                self._state[a] = AxisState(float(v), 0.0)
                self._target[a] = self._stream_target[a] = float(v)
            self._stream_from = None
            row = [self._state[a].angle_deg for a in self.axes]
            self._hist[:] = row  # the true angle's recent history too

    def clear_faults(self) -> None:
        """End injected communication faults (a latched stand fault needs a Modbus fault reset)."""
        with self._lock:
            self._comm = _CommFaults()

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
            acc = min(max(acc, -a_max), a_max)
            rate0 = min(max(v0 + acc * dt, -v_max), v_max)
            y0 = x0 + rate0 * dt
            if (y0 > soft or -y0 > soft) and y0 * rate0 > 0:
                break  # a soft limit: _tick faults the stand
            t1_ = w0 * pa[1] + w * pb[1]
            acc = wn2 * (t1_ - x1) - c2 * v1
            acc = min(max(acc, -a_max), a_max)
            rate1 = min(max(v1 + acc * dt, -v_max), v_max)
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
            acc = min(max(acc, -a_max), a_max)
            rate = min(max(v_before + acc * dt, -v_max), v_max)
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
                acc = min(max(acc, -a_max), a_max)
                rate = min(max(v_before + acc * dt, -v_max), v_max)
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
            if isinstance(self._server, TcpStandServer):
                self._server.drop_all()
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

    # -- Modbus ---------------------------------------------------------------------------
    def dropped(self) -> bool:
        """Is the ``drop_connection`` fault on now?"""
        with self._lock:
            return self._comm.dropped(self.clock.monotonic())

    def _simdata(self) -> list[SimData]:
        m = self.map
        blocks: list[SimData] = []
        ident_words: dict[int, int] = {}
        values: dict[str, str | int] = {**IDENTITY, "map_version": 1}
        for name, f in m.identity.items():
            for i, w in enumerate(m.encode(f, values.get(name, 0))):
                ident_words[f.address + i] = w
        blocks += _blocks(ident_words, readonly=True)
        rw_words: dict[int, int] = {}
        for f in (m.control_word, m.heartbeat, *(ax.command for ax in m.axes.values())):
            for i in range(f.n_registers):
                rw_words[f.address + i] = 0
        for ax in m.axes.values():
            for i in range(m.table.size(ax.table_max_lines)):
                rw_words[ax.table_address + i] = 0
        tr = m.trajectory
        if tr is not None:
            for i in range(tr.period_s.n_registers):
                rw_words[tr.period_s.address + i] = 0
            for i in range(tr.push_size(len(m.axes), tr.max_points_per_push)):
                rw_words[tr.push_address + i] = 0
        blocks += _blocks(rw_words, readonly=False)
        fb_addr, fb_count = self._fb_span
        blocks += _blocks({fb_addr + i: 0 for i in range(fb_count)}, readonly=True)
        return blocks

    def _trace(self, sending: bool, data: bytes) -> bytes:
        """Bytes in or out of the stand: a reply is lost while the stand is dropped or stalled."""
        if not sending:
            return data
        now = self.clock.monotonic()
        with self._lock:
            silent = self._comm.dropped(now) or self._comm.stalled(now)
        return b"" if silent else data

    def _trace_pdu(self, sending: bool, pdu: ModbusPDU) -> ModbusPDU | None:
        """A request for another unit id: TCP exception 0x0B, RTU silence (broadcasts acted on).

        On TCP the stand stands where a gateway would: no device answers that unit id, so it
        answers 0x0B GATEWAY TARGET DEVICE FAILED TO RESPOND. On RS-485 a slave ignores frames
        for other addresses; unit id 0 is broadcast, a write (FC6/FC16) every slave acts on and
        none answers (pymodbus's ``broadcast_enable``), any other broadcast request is ignored.
        """
        if sending or pdu.dev_id == self.device_id:
            return pdu
        if self.transport == "tcp":
            refused = _Refused(pdu.function_code, ExcCodes.GATEWAY_NO_RESPONSE)
            refused.dev_id, refused.transaction_id = pdu.dev_id, pdu.transaction_id
            return refused
        if pdu.dev_id == 0 and pdu.function_code in (6, 16):
            return pdu
        return None

    async def _action(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        regs: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        return self._act(fc, start, address, count, regs, values)

    def _act(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        regs: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        """A request's action on the registers (``_action``, the register model's hook)."""
        now = self.clock.monotonic()
        self._regs, self._regs_start = regs, start
        with self._lock:
            self.requests += 1
            if self._comm.dropped(now) or self._comm.stalled(now):
                return None  # neither acted on nor answered (the reply is dropped in _trace)
            code = self._comm.take_exception(now)
            if code is not None:
                return ExcCodes(code)
            self._advance(now)  # the state as it is now, however late the physics thread is
            if values is None:
                self._fill_feedback(address, count, regs, start, now)
                return None
            return self._write(address, values, regs, start, now)

    def _fill_feedback(
        self, address: int, count: int, regs: list[int], start: int, now: float
    ) -> None:
        """The feedback registers as the stand latches them on this request, at ``now``: the
        encoder read between two physics ticks (the last tick's angle carried on at its rate)
        and, where the map has ``sample_time``, the stand's clock then (lock held)."""
        m = self.map
        since = max(0.0, now - (self._t0 + self._k * self._tick_s)) if self._clock_on else 0.0
        fb_addr, fb_count = self._fb_span
        if address >= fb_addr + fb_count or address + count <= fb_addr:
            return
        bits = {
            "ready": not (self._fault_code or self._estop),
            "enabled": self._enabled,
            "moving": any(abs(s.rate_deg_s) > _MOVING_DEG_S for s in self._state.values()),
            "fault": bool(self._fault_code),
            "estop": self._estop,
            "limit": self._limit,
            "table_running": self._mode == "table",
            "trajectory_running": self._mode in ("trajectory", "traj_stop"),
        }
        word = m.word_from_bits(m.status_bits, [k for k, v in bits.items() if v])
        put: list[tuple[Field, float | int]] = [
            (m.status_word, word),
            (m.fault_code, self._fault_code),
            (m.heartbeat_echo, self._hb_value),
        ]
        st = m.sample_time
        if st is not None:  # the stand's clock at the latch (wrapping)
            ticks = round((now - self._t0) / st.scale) % (1 << (16 * st.n_registers))
            put.append((st, ticks * st.scale))
        for a, ax in m.axes.items():
            s = self._state[a]
            angle = s.angle_deg + s.rate_deg_s * since
            put += [
                (ax.angle, quantise(angle, self.cfg.encoder_resolution_deg)),
                (ax.rate, s.rate_deg_s),
                (ax.setpoint, self._target[a]),
                (ax.fault_code, self._axis_fault[a]),
            ]
        tr = m.trajectory
        if tr is not None:
            q = self._traj
            put += [
                (tr.level, q.level(self._traj_u(now))),
                (tr.next_index, q.next_index),
                (tr.played, q.played(self._traj_u(now))),
                (tr.underruns, q.underruns & 0xFFFF),
            ]
        for f, v in put:
            i = f.address - start
            regs[i : i + f.n_registers] = m.encode(f, v)

    def _write(
        self, address: int, values: list[int] | list[bool], regs: list[int], start: int, now: float
    ) -> ExcCodes | None:
        m = self.map
        written = {address + i: int(v) for i, v in enumerate(values)}

        def touches(f: Field) -> bool:
            return any(f.address + i in written for i in range(f.n_registers))

        def value(f: Field) -> Any:
            words = [
                written.get(f.address + i, regs[f.address + i - start])
                for i in range(f.n_registers)
            ]
            return m.decode(f, words)

        table_running = self._mode == "table"
        tr = m.trajectory
        if tr is not None and touches(tr.period_s):
            self._traj_period = float(value(tr.period_s))
        if tr is not None and tr.push_address in written:
            result = self._push(tr, written, now)
            if result is not None:
                return result
        for ax in m.axes.values():
            t0, t1 = ax.table_address, ax.table_address + m.table.size(ax.table_max_lines)
            if table_running and any(t0 <= a < t1 for a in written):
                return ExcCodes.DEVICE_BUSY
        commands = {a: value(ax.command) for a, ax in m.axes.items() if touches(ax.command)}
        if commands:
            if table_running:
                return ExcCodes.DEVICE_BUSY
            for v in commands.values():
                if not math.isfinite(v) or abs(v) > self.cfg.soft_limit_deg:
                    return ExcCodes.ILLEGAL_VALUE
            if self._enabled and self._mode == "stream" and not self._traj.queued:
                if self.cfg.stream_interpolation:
                    # the drive moves from where its target is now to the new setpoint over
                    # the interval since the last one (cyclic synchronous position)
                    last, self._stream_t = self._stream_t, now
                    self._stream_T = min(max(now - last, self._tick_s), STREAM_INTERP_MAX_S)
                    self._stream_from = dict(self._target)
                    self._stream_target.update(commands)
                else:
                    self._stream_target.update(commands)
                    self._target.update(commands)  # in effect from now on
        if touches(m.heartbeat):
            hb = int(value(m.heartbeat))
            if hb != self._hb_value:
                self._hb_value, self._hb_time, self._held_s = hb, now, 0.0
        if touches(m.control_word):
            result = self._control(int(value(m.control_word)), regs, start, now)
            if result is not None:
                return result
            i = m.control_word.address - address
            if 0 <= i < len(values):  # commands are acted on and cleared; ENABLE stays as written
                values[i] = int(values[i]) & (1 << m.control_bits["enable"])  # type: ignore[call-overload]
        return None

    def _control(self, word: int, regs: list[int], start: int, now: float) -> ExcCodes | None:
        bits = self.map.control_bits

        def has(name: str) -> bool:
            return bool(word >> bits[name] & 1)

        if has("estop"):
            self._do_estop()
            return None
        if has("fault_reset"):
            self._fault_code = 0
            self._estop = False
            self._limit = False
            self._axis_fault = dict.fromkeys(self.axes, 0)
        if has("enable"):
            if not self._enabled and not (self._fault_code or self._estop):
                self._enabled = True
                self.enables += 1
                self._hb_time, self._held_s = now, 0.0
                self._mode = "stream"
                self._stream_from = None
                self._stream_target = {a: s.angle_deg for a, s in self._state.items()}
        elif self._enabled:
            self._enabled = False
        if has("stop") and self._enabled:
            self._mode = "stopping"
            self._traj.clear()
        if "start_trajectory" in bits and has("start_trajectory"):
            if not self._enabled or self._mode != "stream" or not self._traj.queued:
                return ExcCodes.ILLEGAL_VALUE
            self._traj.start(now)
            self._mode = "trajectory"
        if has("start_table"):
            if not self._enabled:
                return ExcCodes.ILLEGAL_VALUE
            tables = self._read_tables(regs, start)
            if tables is None:
                self._fault(FAULT_TABLE)
                return None
            self._tables = tables
            self._table_start = now
            self._table_end = max(t.duration_s for t in tables.values() if t is not None)
            self._mode = "table"
        return None

    def _traj_u(self, now: float) -> float | None:
        """The queue position being played (point index, fractional) or None when idle."""
        if self._mode != "trajectory":
            return None
        q = self._traj
        return q.base + (now - q.t_start) / q.period_s

    def _push(self, tr: Any, written: dict[int, int], now: float) -> ExcCodes | None:
        """A push block written (lock held): append its points to the queue, or refuse it."""
        m = self.map
        base = tr.push_address
        n_axes = len(self.axes)
        try:
            head = [written[base], written[base + 1]]
            first = int(m.decode(Field("first", base, "uint32"), head))
            count = written[base + 2]
            words = [written[base + 3 + i] for i in range(2 * n_axes * count)]
        except KeyError:
            return ExcCodes.ILLEGAL_VALUE  # a push block cut short
        if not 1 <= count <= tr.max_points_per_push:
            return ExcCodes.ILLEGAL_VALUE
        period = self._traj_period
        pts = np.array(
            [
                m.decode(Field("p", 0, "float32"), words[2 * j : 2 * j + 2])
                for j in range(n_axes * count)
            ]
        ).reshape(count, n_axes)
        if not np.all(np.isfinite(pts)) or np.any(np.abs(pts) > self.cfg.soft_limit_deg):
            return ExcCodes.ILLEGAL_VALUE
        idle = self._mode not in ("trajectory", "traj_stop")
        if idle and first == 0:  # a new trajectory
            if not (math.isfinite(period) and 1e-4 <= period <= 1.0):
                return ExcCodes.ILLEGAL_VALUE
            self._traj.reset(period)
        nxt = self._traj.next_index
        if first < nxt <= first + count:
            # a push sent again (the master's retry after a reply it did not wait for): the
            # points the queue has are kept as they are, only the new ones appended
            pts = pts[nxt - first:]
            first = nxt
            if not len(pts):
                return None
        if first != nxt:
            return ExcCodes.ILLEGAL_VALUE
        if self._traj.level(self._traj_u(now)) + len(pts) > tr.capacity:
            return ExcCodes.DEVICE_BUSY
        self._traj.append(pts)
        return None

    def _read_tables(self, regs: list[int], start: int) -> dict[str, HarmonicTable | None] | None:
        """The uploaded tables from the register memory, or None when they are not valid."""
        m = self.map

        def get(f: Field) -> Any:
            i = f.address - start
            return m.decode(f, regs[i : i + f.n_registers])

        out: dict[str, HarmonicTable | None] = {}
        for a, ax in m.axes.items():
            n = int(get(m.table_field(a, "n_lines")))
            if n > ax.table_max_lines:
                return None
            if n == 0:
                out[a] = None
                continue
            lines = np.array(
                [
                    [get(m.table_field(a, p, k)) for p in ("freq_hz", "amp_deg", "phase_rad")]
                    for k in range(n)
                ]
            )
            try:
                out[a] = HarmonicTable(
                    lines[:, 0],
                    lines[:, 1],
                    lines[:, 2],
                    duration_s=float(get(m.table_field(a, "duration_s"))),
                    fade_in_s=float(get(m.table_field(a, "fade_in_s"))),
                    fade_out_s=float(get(m.table_field(a, "fade_out_s"))),
                )
            except ValueError:
                return None
            if not (np.all(np.isfinite(lines)) and out[a].duration_s > 0):  # type: ignore[union-attr]
                return None
        if all(t is None for t in out.values()):
            return None
        return out


class _TrajectoryQueue:
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


def _blocks(words: dict[int, int], *, readonly: bool) -> list[SimData]:
    """Contiguous SimData register blocks holding ``words`` (address → value)."""
    out: list[SimData] = []
    addrs = sorted(words)
    i = 0
    while i < len(addrs):
        j = i
        while j + 1 < len(addrs) and addrs[j + 1] == addrs[j] + 1:
            j += 1
        vals = [words[a] for a in addrs[i : j + 1]]
        out.append(SimData(addrs[i], values=vals, datatype=DataType.REGISTERS, readonly=readonly))
        i = j + 1
    return out


def _register_addresses(simdata: list[SimData]) -> frozenset[int]:
    """Every register address the SimData blocks give the stand (blocks marked invalid aside)."""
    return frozenset(
        d.address + i
        for d in simdata
        if d.datatype != DataType.INVALID
        for i in range(len(d.build_registers(False)) * d.count)
    )


class _Refused(ModbusPDU):
    """A request the stand refuses: handling it yields the exception response (FC | 0x80, code)."""

    def __init__(self, function_code: int, code: ExcCodes) -> None:
        super().__init__()
        self.function_code = function_code
        self.code = code

    async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
        return ExceptionResponse(self.function_code, self.code)


class _WholeFrame(ModbusPDU):
    """RTU framing of a function code pymodbus has no layout for: the CRC-checked bytes so far."""

    @classmethod
    def calculateRtuFrameSize(cls, data: bytes) -> int:
        return len(data)


class _MapDecoder(DecodePDU):
    """The simulated stand's request decoder: it refuses requests the way the specification says.

    pymodbus alone decodes every function code it knows (coils, input registers, diagnostics…)
    and answers a request it cannot decode with function byte 0x80 whatever the request's. This
    decoder replaces the server's (each connection's framer decodes with ``server.decoder``) and
    checks a request in the order of the specification's state diagrams (Modbus Application
    Protocol V1.1b3, 6.x); a refused request becomes a :class:`_Refused`, answered ``FC | 0x80``:

    1. a function code outside the register map — holding registers: 3, 6, 16, and 23 when the
       map says ``read_write_multiple`` — → 01 ILLEGAL FUNCTION (serial-only 7, 8, 11, 12, 17 too);
    2. a quantity or byte count out of range — FC3 1..``max_read_registers``, FC16
       1..``max_write_registers`` with byte count 2·N, FC23 both (write ≤ 121) — or a PDU of
       the wrong length → 03 ILLEGAL DATA VALUE;
    3. addresses outside the map are the SimDevice model's → 02 ILLEGAL DATA ADDRESS — but
       for FC23 the read span is checked here: pymodbus would write first and then refuse the
       read, where the specification checks both spans before anything is written.
    """

    def __init__(self, m: RegisterMap, addresses: frozenset[int]) -> None:
        super().__init__(True)
        self.addresses = addresses  # every register the stand has
        self.function_codes = {3, 6, 16} | ({23} if m.read_write_multiple else set())
        self.max_read = m.max_read
        self.max_write = m.max_write

    def lookupPduClass(self, data: bytes) -> type[ModbusPDU] | None:
        # RTU: pymodbus finds where a frame ends from its function code's layout (a real slave
        # from the 3.5-character silence, which a pty does not carry). For a function code it
        # has no layout for, the bytes received so far are the frame if they end in a valid CRC
        # — so such a request is answered too; otherwise pymodbus hunts on, as it always did.
        cls = super().lookupPduClass(data)
        if (
            cls is None
            and len(data) >= 4
            and FramerRTU.check_CRC(data[:-2], int.from_bytes(data[-2:], "big"))
        ):
            return _WholeFrame
        return cls

    def decode(self, frame: bytes) -> ModbusPDU | None:
        fc = frame[0]
        if fc not in self.function_codes:
            return _Refused(fc, ExcCodes.ILLEGAL_FUNCTION)
        if not self._quantity_ok(fc, frame):
            return _Refused(fc, ExcCodes.ILLEGAL_VALUE)
        if fc == 23:
            start, count = int.from_bytes(frame[1:3], "big"), int.from_bytes(frame[3:5], "big")
            if not all(a in self.addresses for a in range(start, start + count)):
                return _Refused(fc, ExcCodes.ILLEGAL_ADDRESS)
        pdu = super().decode(frame)
        return pdu if pdu is not None else _Refused(fc, ExcCodes.ILLEGAL_VALUE)

    def _quantity_ok(self, fc: int, pdu: bytes) -> bool:
        n = len(pdu)

        def u16(i: int) -> int:
            return int.from_bytes(pdu[i : i + 2], "big")

        if fc == 3:
            return n == 5 and 1 <= u16(3) <= self.max_read
        if fc == 6:
            return n == 5
        if fc == 16:
            return n >= 6 and 1 <= u16(3) <= self.max_write and pdu[5] == 2 * u16(3) == n - 6
        return (  # 23: read address, read count, write address, write count, byte count, values
            n >= 10
            and 1 <= u16(3) <= self.max_read
            and 1 <= u16(7) <= min(self.max_write, 121)
            and pdu[9] == 2 * u16(7) == n - 10
        )


