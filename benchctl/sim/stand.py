"""Simulated roll/pitch stand: a real Modbus server (TCP, or RTU on a pty) with servo physics.

The register map is the same YAML file the driver reads (``drivers/stand_generic.yaml``), so the
driver cannot tell this stand from hardware. Three kinds of threads:

- ``sim-stand-modbus``: an asyncio loop running the pymodbus server. Reads of the feedback block
  are filled from the latest physics state; writes of the control word, heartbeat, setpoints
  and table area act on the physics state at once.
- ``sim-stand-physics``: ticks the servo at ``tick_hz`` on absolute times (host monotonic
  clock), integrating missed ticks when the thread was late, and checks the watchdog, soft
  limits, table playback and scheduled faults.
- ``sim-stand-rtu-relay`` (RTU only): relays bytes between two pseudo-terminal pairs, the server
  on one slave end, the client on the other, delaying each chunk by its serial byte time.

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

import asyncio
import contextlib
import math
import os
import selectors
import threading
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Literal

import numpy as np
from pymodbus import FramerType
from pymodbus.constants import ExcCodes
from pymodbus.server import ModbusSerialServer, ModbusTcpServer
from pymodbus.simulator import DataType, SimData, SimDevice

from benchctl.config import SimStandConfig, StandLimits
from benchctl.devices.modbus.regmap import Field, RegisterMap, load_register_map
from benchctl.errors import ConfigError, DeviceError
from benchctl.harmonics import HarmonicTable
from benchctl.sim.faults import FaultSpecError, check_params
from benchctl.sim.servo import AxisState, ServoModel, brake_step, quantise, servo_step

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
        ``"tcp"`` (``host``, ``port``; port 0 picks a free port) or ``"rtu"`` (a pty pair;
        ``serial_port`` is the path for the client, also symlinked at ``link_path``).
    device_id
        The Modbus unit id this stand answers.
    """

    def __init__(
        self,
        sim_cfg: SimStandConfig,
        *,
        limits: StandLimits,
        register_map: Path,
        transport: Literal["tcp", "rtu"] = "tcp",
        host: str = "127.0.0.1",
        port: int = 0,
        link_path: Path | None = None,
        device_id: int = 1,
    ) -> None:
        if transport not in ("tcp", "rtu"):
            raise ConfigError(f"SimStand: transport {transport!r}: expected tcp or rtu")
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
        self.requests = 0  # requests served (for tests and figures)

        self._lock = threading.Lock()
        self._state = {a: AxisState() for a in self.axes}
        self._target = dict.fromkeys(self.axes, 0.0)  # the servo's active position setpoint
        self._stream_target = dict.fromkeys(self.axes, 0.0)
        self._mode: Literal["stream", "table", "stopping"] = "stream"
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
        self._comm = _CommFaults()
        self._pending_faults = sorted(sim_cfg.faults, key=lambda f: f.after_s)

        n_hist = int(_HISTORY_S * sim_cfg.tick_hz) + 2
        self._hist = np.zeros((n_hist, len(self.axes)))
        self._t0 = 0.0
        self._start_time = 0.0
        self._tick_s = 1.0 / sim_cfg.tick_hz
        self._k = 0  # ticks done: the state is at time t0 + k * tick

        self._regs: list[int] | None = None
        self._regs_start = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Any = None
        self._threads: list[threading.Thread] = []
        self._stop_evt = threading.Event()
        self._relay: _PtyRelay | None = None
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
        now = time.monotonic()
        self._t0 = now
        self._hb_time = now
        self._start_time = now
        if self.transport == "rtu":
            byte_time = 10.0 / self.cfg.baudrate if self.cfg.rtu_wire_delay else 0.0
            self._relay = _PtyRelay(
                byte_time, lambda: self._comm.dropped(time.monotonic()), self.link_path
            )
            self.serial_port = self._relay.client_path
        physics = threading.Thread(target=self._physics_loop, name="sim-stand-physics", daemon=True)
        self._threads.append(physics)
        physics.start()
        if self._relay is not None:
            self._relay.start()
        loop = asyncio.new_event_loop()
        self._loop = loop
        server_thread = threading.Thread(
            target=self._serve, args=(loop,), name="sim-stand-modbus", daemon=True
        )
        self._threads.append(server_thread)
        server_thread.start()
        asyncio.run_coroutine_threadsafe(self._start_server(), loop).result(timeout=10)

    def stop(self) -> None:
        """Stop the server, physics and relay; closes every port, thread and fd. Idempotent."""
        if self._stopped:
            return
        self._stopped = True
        self._stop_evt.set()
        loop = self._loop
        if loop is not None and loop.is_running():
            if self._server is not None:
                with contextlib.suppress(Exception):
                    asyncio.run_coroutine_threadsafe(self._server.shutdown(), loop).result(
                        timeout=5
                    )
            loop.call_soon_threadsafe(loop.stop)
        for t in self._threads:
            t.join(timeout=10)
        if self._relay is not None:
            self._relay.stop()

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
        if self.transport == "tcp":
            return f"modbus-tcp {self.host}:{self.port} (device id {self.device_id})"
        return f"modbus-rtu {self.serial_port} (device id {self.device_id})"

    # -- what tests and the simulated instrument see ---------------------------------------
    def true_angles(self, t: float) -> dict[str, float]:
        """True (unquantised) angles in degrees at host monotonic time ``t``, interpolated.

        The history reaches back about 4 s; earlier or later times are clamped to its ends.
        """
        with self._lock:
            k_end = self._k
            n = self._hist.shape[0]
            u = (t - self._t0) / self._tick_s
            u = min(max(u, max(0, k_end - n + 2)), k_end)
            k0 = math.floor(u)
            k1 = min(k0 + 1, k_end)
            w = u - k0
            row = (1.0 - w) * self._hist[k0 % n] + w * self._hist[k1 % n]
        return {a: float(row[i]) for i, a in enumerate(self.axes)}

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
                time.monotonic(),
                None if dur is None else float(dur),
                None if code is None else int(code),
                None if count is None else int(count),
            )

    def clear_faults(self) -> None:
        """End injected communication faults (a latched stand fault needs a Modbus fault reset)."""
        with self._lock:
            self._comm = _CommFaults()

    # -- physics ------------------------------------------------------------------------
    def _physics_loop(self) -> None:
        tick = self._tick_s
        while True:
            next_t = self._t0 + (self._k + 1) * tick
            if self._stop_evt.wait(max(0.0, next_t - time.monotonic())):
                return
            k_target = int((time.monotonic() - self._t0) / tick)
            with self._lock:
                if k_target - self._k > _MAX_CATCHUP_TICKS:
                    self._k = k_target - _MAX_CATCHUP_TICKS  # a very late thread: skip, never burst
                while self._k < k_target:
                    self._k += 1
                    self._tick(self._t0 + self._k * tick)
                    self._hist[self._k % self._hist.shape[0]] = [
                        self._state[a].angle_deg for a in self.axes
                    ]

    def _tick(self, t: float) -> None:
        """One physics tick at time ``t`` (lock held)."""
        while self._pending_faults and t - self._start_time >= self._pending_faults[0].after_s:
            f = self._pending_faults.pop(0)
            self._apply(f.kind, t, f.duration_s, f.code)
        if self._enabled and t - self._hb_time > self.cfg.watchdog_s:
            self._fault(FAULT_WATCHDOG)
        if self._mode == "table" and t - self._table_start > self._table_end:
            self._mode = "stream"
            self._stream_target = {a: self._table_value(a, self._table_end) for a in self.axes}
        at_rest = True
        for a in self.axes:
            s = self._state[a]
            if not self._enabled or self._mode == "stopping":
                brake_step(self.model, s)
                self._target[a] = s.angle_deg
            else:
                if self._mode == "table":
                    self._target[a] = self._table_value(a, t - self._table_start)
                else:
                    self._target[a] = self._stream_target[a]
                servo_step(self.model, s, self._target[a])
            if abs(s.rate_deg_s) > _MOVING_DEG_S:
                at_rest = False
            if abs(s.angle_deg) > self.cfg.soft_limit_deg and s.angle_deg * s.rate_deg_s > 0:
                self._axis_fault[a] = FAULT_SOFT_LIMIT
                self._limit = True
                self._fault(FAULT_SOFT_LIMIT)
        if self._mode == "stopping" and at_rest:
            self._mode = "stream"
            self._stream_target = {a: self._state[a].angle_deg for a in self.axes}

    def _table_value(self, axis: str, t_rel: float) -> float:
        table = self._tables.get(axis)
        return 0.0 if table is None else table.at(t_rel)

    def _fault(self, code: int) -> None:
        if self._fault_code == 0:
            self._fault_code = code
        self._enabled = False
        if self._mode == "table":
            self._mode = "stream"

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
            if self._loop is not None:
                self._loop.call_soon_threadsafe(self._close_clients)
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

    # -- Modbus server ------------------------------------------------------------------
    def _serve(self, loop: asyncio.AbstractEventLoop) -> None:
        asyncio.set_event_loop(loop)
        try:
            loop.run_forever()
        finally:
            tasks = asyncio.all_tasks(loop)
            for task in tasks:
                task.cancel()
            if tasks:
                loop.run_until_complete(asyncio.gather(*tasks, return_exceptions=True))
            loop.run_until_complete(loop.shutdown_asyncgens())
            loop.close()

    async def _start_server(self) -> None:
        device = SimDevice(self.device_id, simdata=self._simdata(), action=self._action)
        if self.transport == "tcp":
            self._server = ModbusTcpServer(
                device, address=(self.host, self.port), trace_packet=self._trace
            )
        else:
            assert self._relay is not None
            self._server = ModbusSerialServer(
                device,
                framer=FramerType.RTU,
                port=self._relay.server_path,
                baudrate=self.cfg.baudrate,
                trace_packet=self._trace,
            )
        await self._server.serve_forever(background=True)
        if self.transport == "tcp":
            self.port = int(self._server.transport.sockets[0].getsockname()[1])

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
        blocks += _blocks(rw_words, readonly=False)
        fb_addr, fb_count = m.feedback_span()
        blocks += _blocks({fb_addr + i: 0 for i in range(fb_count)}, readonly=True)
        return blocks

    def _trace(self, sending: bool, data: bytes) -> bytes:
        now = time.monotonic()
        with self._lock:
            dropped = self._comm.dropped(now)
            silent = dropped or self._comm.stalled(now)
        if not sending and dropped and self.transport == "tcp" and self._loop is not None:
            self._loop.call_soon(self._close_clients)
        return b"" if sending and silent else data

    def _close_clients(self) -> None:
        """TCP: close every client connection (on RTU the relay cuts the line instead)."""
        if self._server is None or self.transport != "tcp":
            return
        for conn in list(getattr(self._server, "active_connections", {}).values()):
            conn.close()

    async def _action(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        regs: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        now = time.monotonic()
        self._regs, self._regs_start = regs, start
        with self._lock:
            self.requests += 1
            if self._comm.dropped(now) or self._comm.stalled(now):
                return None  # neither acted on nor answered (the reply is dropped in _trace)
            code = self._comm.take_exception(now)
            if code is not None:
                return ExcCodes(code)
            if values is None:
                self._fill_feedback(address, count, regs, start)
                return None
            return self._write(address, values, regs, start, now)

    def _fill_feedback(self, address: int, count: int, regs: list[int], start: int) -> None:
        m = self.map
        fb_addr, fb_count = m.feedback_span()
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
        }
        word = m.word_from_bits(m.status_bits, [k for k, v in bits.items() if v])
        put: list[tuple[Field, float | int]] = [
            (m.status_word, word),
            (m.fault_code, self._fault_code),
            (m.heartbeat_echo, self._hb_value),
        ]
        for a, ax in m.axes.items():
            s = self._state[a]
            put += [
                (ax.angle, quantise(s.angle_deg, self.cfg.encoder_resolution_deg)),
                (ax.rate, s.rate_deg_s),
                (ax.setpoint, self._target[a]),
                (ax.fault_code, self._axis_fault[a]),
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
            if self._enabled and self._mode == "stream":
                self._stream_target.update(commands)
                self._target.update(commands)  # in effect from now on
        if touches(m.heartbeat):
            hb = int(value(m.heartbeat))
            if hb != self._hb_value:
                self._hb_value, self._hb_time = hb, now
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
                self._hb_time = now
                self._mode = "stream"
                self._stream_target = {a: s.angle_deg for a, s in self._state.items()}
        elif self._enabled:
            self._enabled = False
        if has("stop") and self._enabled:
            self._mode = "stopping"
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


class _PtyRelay:
    """Two pseudo-terminal pairs joined by a relay thread: an RS-485 line without hardware.

    The server opens ``server_path``, the client ``client_path``. Each chunk is delayed by its
    serial byte time (10 bits a byte) before it is passed on; while ``dead()`` is true every
    byte is discarded (a cut line).
    """

    def __init__(
        self, byte_time_s: float, dead: Callable[[], bool], link_path: Path | None
    ) -> None:
        self.byte_time_s = byte_time_s
        self._dead = dead
        self._fds: list[int] = []
        self._srv_master, srv_slave = self._pair()
        self._cli_master, cli_slave = self._pair()
        self.server_path = os.ttyname(srv_slave)
        self.client_path = os.ttyname(cli_slave)
        self._wake_r, self._wake_w = os.pipe()
        self._fds += [self._wake_r, self._wake_w]
        self.link_path = link_path
        if link_path is not None:
            link_path.parent.mkdir(parents=True, exist_ok=True)
            with contextlib.suppress(FileNotFoundError):
                link_path.unlink()
            link_path.symlink_to(self.client_path)
        self._thread = threading.Thread(target=self._run, name="sim-stand-rtu-relay", daemon=True)
        self._stopping = False

    def _pair(self) -> tuple[int, int]:
        master, slave = os.openpty()
        tty.setraw(slave)
        self._fds += [master, slave]  # the slave stays open here so the master never sees EIO
        return master, slave

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stopping = True
        if self._thread.is_alive():
            os.write(self._wake_w, b"x")
            self._thread.join(timeout=5)
        for fd in self._fds:
            with contextlib.suppress(OSError):
                os.close(fd)
        self._fds = []
        if self.link_path is not None and self.link_path.is_symlink():
            with contextlib.suppress(FileNotFoundError):
                self.link_path.unlink()

    def _run(self) -> None:
        other = {self._srv_master: self._cli_master, self._cli_master: self._srv_master}
        with selectors.DefaultSelector() as sel:
            for fd in (self._srv_master, self._cli_master, self._wake_r):
                sel.register(fd, selectors.EVENT_READ)
            while not self._stopping:
                for key, _ in sel.select():
                    fd = int(key.fd)
                    if fd == self._wake_r:
                        return
                    try:
                        data = os.read(fd, 4096)
                    except OSError:
                        continue
                    if not data or self._dead():
                        continue
                    if self.byte_time_s > 0:
                        time.sleep(len(data) * self.byte_time_s)
                    with contextlib.suppress(OSError):
                        os.write(other[fd], data)
