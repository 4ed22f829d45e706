"""Simulated roll/pitch stand: a real Modbus server (TCP, or RTU on a pty) with servo physics.

The register map is the same YAML file the driver reads (``drivers/stand_generic.yaml``), so the
driver cannot tell this stand from hardware. Every request reaches the stand through one entry
point, ``benchctl.sim.stand_wire.StandWire`` (pymodbus's framing, the stand's own request
decoder, pymodbus's register model), fed by a TCP socket, a pty or an in-process link
(``benchctl.sim.stand_servers``, ``transport="channel"``).

The stand is built in layers, one idea each: ``stand_physics.StandPhysics`` (the servo
physics and its state: modes, watchdog, soft limits, faults), ``stand_firmware.StandFirmware``
(what each Modbus request does to that state), ``stand_registers`` (the register model and
request decoder pymodbus runs), ``trajectory_queue`` (the buffered mode's queue), and this
module's ``SimStand`` (the transports, the threads, the public API). Threads:

- ``sim-stand-modbus``: the server (socket, pty or link). Reads of the feedback block
  are filled from the latest physics state; writes of the control word, heartbeat, setpoints
  and table area act on the physics state at once. Requests outside the map are refused as the
  Modbus specification says (``MapDecoder``); other unit ids: TCP exception 0x0B, RTU silence.
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
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np

from benchctl.channels import Endpoint
from benchctl.channels import link as channel_link
from benchctl.clock import REAL, Clock
from benchctl.config import SimStandConfig, StandLimits
from benchctl.errors import ConfigError, DeviceError
from benchctl.faultspec import FaultSpecError, check_params
from benchctl.sim.servo import AxisState
from benchctl.sim.stand_firmware import IDENTITY, StandFirmware
from benchctl.sim.stand_physics import (
    FAULT_ESTOP,
    FAULT_KINDS,
    FAULT_SOFT_LIMIT,
    FAULT_TABLE,
    FAULT_WATCHDOG,
    SIM_HOLDUP_S,
    STREAM_INTERP_MAX_S,
    TRAJ_STOP_SHARE,
    CommFaults,
)
from benchctl.sim.stand_servers import RtuStandServer, TcpStandServer
from benchctl.sim.stand_wire import StandWire, serve_endpoint, serve_on_arrival

__all__ = [
    "FAULT_ESTOP",
    "FAULT_KINDS",
    "FAULT_SOFT_LIMIT",
    "FAULT_TABLE",
    "FAULT_WATCHDOG",
    "IDENTITY",
    "SIM_HOLDUP_S",
    "STREAM_INTERP_MAX_S",
    "TRAJ_STOP_SHARE",
    "SimStand",
]


class SimStand(StandFirmware):
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
        super().__init__(
            sim_cfg,
            limits=limits,
            register_map=register_map,
            clock=clock,
            device_id=device_id,
            transport=transport,
        )
        #: the frames on the wire: MBAP (tcp) or RTU; a channel carries either
        self.framing: Literal["tcp", "rtu"] = (
            framing if framing is not None else ("rtu" if transport == "rtu" else "tcp")
        )
        self.channel_latency_s = channel_latency_s
        #: the host end of the in-process link (transport "channel"), once started, and its
        #: device end (the stand's)
        self.client_endpoint: Endpoint | None = None
        self.device_endpoint: Endpoint | None = None
        self.host = host
        self.port = port
        self.link_path = link_path
        self.serial_port: str | None = None
        self._server: TcpStandServer | RtuStandServer | None = None
        self._threads: list[Any] = []
        self._started = False
        self._stopped = False

    def _links_dropped(self) -> None:
        if isinstance(self._server, TcpStandServer):
            self._server.drop_all()


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

        The history reaches back about 4 s; earlier times are clamped to its start. A time
        after the last physics tick (the present, between two ticks) is the last tick's angle
        carried on at its rate, as the encoder's feedback has it: never the last tick's angle
        itself, which would be up to a tick old (a delay the instrument does not have).
        """
        with self._lock:
            self._advance(min(t + self._tick_s, self.clock.monotonic()))  # a late physics thread
            k_end = self._k
            n = self._hist.shape[0]
            u = (t - self._t0) / self._tick_s
            if u > k_end:
                ahead = (u - k_end) * self._tick_s
                return {a: self._state[a].angle_deg + self._state[a].rate_deg_s * ahead
                        for a in self.axes}
            u = max(u, max(0, k_end - n + 2))
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
            u_all = (ts - self._t0) / self._tick_s
            u = np.minimum(np.maximum(u_all, max(0, k_end - n + 2)), k_end)
            k0 = np.floor(u).astype(np.int64)
            k1 = np.minimum(k0 + 1, k_end)
            w = (u - k0)[:, None]
            hist = self._hist  # rows k0 % n and k1 % n
            rows = (1.0 - w) * hist.take(k0, 0, mode="wrap") + w * hist.take(k1, 0, mode="wrap")
            later = u_all > k_end  # after the last tick: carried on at its rate (true_angles)
            if later.any():
                ahead = (u_all[later] - k_end) * self._tick_s
                for i, a in enumerate(self.axes):
                    st = self._state[a]
                    rows[later, i] = st.angle_deg + st.rate_deg_s * ahead
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
            self._comm = CommFaults()
