"""The simulated stand's register firmware: what each Modbus request does to the stand."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pymodbus.constants import ExcCodes
from pymodbus.pdu import ModbusPDU
from pymodbus.simulator import SimData

from benchctl.clock import REAL, Clock
from benchctl.config import SimStandConfig, StandLimits
from benchctl.devices.modbus.regmap import Field, RegisterMap
from benchctl.harmonics import HarmonicTable
from benchctl.sim.servo import quantise
from benchctl.sim.stand_physics import (
    _MOVING_DEG_S,
    FAULT_TABLE,
    STREAM_INTERP_MAX_S,
    StandPhysics,
)
from benchctl.sim.stand_registers import Refused, register_blocks

IDENTITY = {
    "vendor": "benchctl",
    "model": "SimStand 2-axis",
    "serial": "SIM-0001",
    "firmware": "1.0",
}


class StandFirmware(StandPhysics):
    """The simulated stand's register firmware: the register map's blocks, and each request's
    action on the physics state — feedback latched at the request's instant, setpoints,
    heartbeat, control word, trajectory pushes, tables. ``StandWire`` hands every request
    here (``simdata``, ``action``/``act``, ``trace``, ``trace_pdu``)."""

    def __init__(
        self,
        sim_cfg: SimStandConfig,
        *,
        limits: StandLimits,
        register_map: Path,
        clock: Clock = REAL,
        device_id: int = 1,
        transport: Literal["tcp", "rtu", "channel"] = "tcp",
    ) -> None:
        super().__init__(sim_cfg, limits=limits, register_map=register_map, clock=clock)
        self.device_id = device_id
        self.transport = transport
        self._fb_span = self.map.feedback_span()
        #: (register block start, the feedback fields' encoder for it): _fill_feedback's
        self._fb_encode: tuple[int, Callable[[list[int], Sequence[float | int]], None]] | None
        self._fb_encode = None
        self.requests = 0  # requests served (for tests and figures)
        self.enables = 0  # times the servo was switched on (for tests: was the stand touched?)
        self._regs: list[int] | None = None
        self._regs_start = 0

    def simdata(self) -> list[SimData]:
        m = self.map
        blocks: list[SimData] = []
        ident_words: dict[int, int] = {}
        values: dict[str, str | int] = {**IDENTITY, "map_version": 1}
        for name, f in m.identity.items():
            for i, w in enumerate(m.encode(f, values.get(name, 0))):
                ident_words[f.address + i] = w
        blocks += register_blocks(ident_words, readonly=True)
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
        blocks += register_blocks(rw_words, readonly=False)
        fb_addr, fb_count = self._fb_span
        blocks += register_blocks({fb_addr + i: 0 for i in range(fb_count)}, readonly=True)
        return blocks

    def trace(self, sending: bool, data: bytes) -> bytes:
        """Bytes in or out of the stand: a reply is lost while the stand is dropped or stalled."""
        if not sending:
            return data
        now = self.clock.monotonic()
        with self._lock:
            silent = self._comm.dropped(now) or self._comm.stalled(now)
        return b"" if silent else data

    def trace_pdu(self, sending: bool, pdu: ModbusPDU) -> ModbusPDU | None:
        """A request for another unit id: TCP exception 0x0B, RTU silence (broadcasts acted on).

        On TCP the stand stands where a gateway would: no device answers that unit id, so it
        answers 0x0B GATEWAY TARGET DEVICE FAILED TO RESPOND. On RS-485 a slave ignores frames
        for other addresses; unit id 0 is broadcast, a write (FC6/FC16) every slave acts on and
        none answers (pymodbus's ``broadcast_enable``), any other broadcast request is ignored.
        """
        if sending or pdu.dev_id == self.device_id:
            return pdu
        if self.transport == "tcp":
            refused = Refused(pdu.function_code, ExcCodes.GATEWAY_NO_RESPONSE)
            refused.dev_id, refused.transaction_id = pdu.dev_id, pdu.transaction_id
            return refused
        if pdu.dev_id == 0 and pdu.function_code in (6, 16):
            return pdu
        return None

    async def action(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        regs: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        return self.act(fc, start, address, count, regs, values)

    def act(
        self,
        fc: int,
        start: int,
        address: int,
        count: int,
        regs: list[int],
        values: list[int] | list[bool] | None,
    ) -> ExcCodes | None:
        """A request's action on the registers (``action``, the register model's hook)."""
        now = self.clock.monotonic()
        self._regs, self._regs_start = regs, start
        with self._lock:
            self.requests += 1
            if self._comm.dropped(now) or self._comm.stalled(now):
                return None  # neither acted on nor answered (the reply is dropped in trace)
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
        put: list[float | int] = [word, self._fault_code, self._hb_value]
        st = m.sample_time
        if st is not None:  # the stand's clock at the latch (wrapping)
            ticks = round((now - self._t0) / st.scale) % (1 << (16 * st.n_registers))
            put.append(ticks * st.scale)
        resolution = self.cfg.encoder_resolution_deg
        for a in m.axes:
            s = self._state[a]
            angle = s.angle_deg + s.rate_deg_s * since
            put += [quantise(angle, resolution), s.rate_deg_s, self._target[a],
                    self._axis_fault[a]]
        tr = m.trajectory
        if tr is not None:
            q = self._traj
            u = self._traj_u(now)
            put += [q.level(u), q.next_index, q.played(u), q.underruns & 0xFFFF]
        if self._fb_encode is None or self._fb_encode[0] != start:
            self._fb_encode = (start, m.block_encoder(_feedback_put_order(m), start))
        self._fb_encode[1](regs, put)

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


def _feedback_put_order(m: RegisterMap) -> list[Field]:
    """The feedback fields in the order ``_fill_feedback`` puts their values: status word,
    fault code, heartbeat echo, [sample time], per axis angle, rate, setpoint and fault code,
    [the trajectory queue's level, next index, played and underruns]."""
    out = [m.status_word, m.fault_code, m.heartbeat_echo]
    out += [m.sample_time] if m.sample_time is not None else []
    for ax in m.axes.values():
        out += [ax.angle, ax.rate, ax.setpoint, ax.fault_code]
    tr = m.trajectory
    out += [tr.level, tr.next_index, tr.played, tr.underruns] if tr is not None else []
    return out
