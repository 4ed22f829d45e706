"""The stand driver over Modbus TCP/RTU: ``ModbusStand`` implements ``devices.base.Stand``.

The register map (``drivers/*.yaml``) says where everything lives; the link (``link.py``) says
how bytes travel; ``StandIO`` (``stand_io.py``) reads and writes the registers and decodes the
feedback block; ``SetpointStand`` (``setpoints.py``) keeps the setpoint history and checks every
setpoint. This module is the driver built on them: tables, stops and the ramp to zero, the
buffered trajectory, and ``open_stand``.
Public methods hold the safety checks: every setpoint is checked against the angle, rate and
acceleration limits at the point of sending and a bad one raises ``LimitError`` before anything
is written; every table is checked over its whole duration before upload (``table_limits``).
Device-reported faults and E-stops raise ``StandFault`` with the stand's fault code.

Thread safety: one streaming thread and one supervisor/heartbeat thread may share a driver;
each request holds the link's lock, the setpoint history holds the driver's lock.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from benchctl.clock import REAL, Clock
from benchctl.config import StandConfig
from benchctl.devices.base import StandLimitsView, StandSample
from benchctl.devices.modbus.link import ModbusLink, rtu_link, tcp_link
from benchctl.devices.modbus.regmap import Field, RegisterMap, pdu_address, span
from benchctl.devices.modbus.regmap_load import load_register_map
from benchctl.devices.modbus.setpoints import SetpointStand
from benchctl.devices.modbus.stand_io import register_runs
from benchctl.devices.modbus.table_limits import check_table
from benchctl.errors import DeviceError, LimitError, ProtocolError
from benchctl.harmonics import HarmonicTable
from benchctl.kinematics import AxisCommand, StaleSetpoint, check_step, plan_ramp_to_zero

log = logging.getLogger(__name__)

RAMP_MARGIN = 0.8  # ramps use this fraction of the rate and acceleration limits
REST_HOLD_S = 0.1  # "at rest" must hold this long


class ModbusStand(SetpointStand):
    """A two-axis stand on a Modbus link, described by a register map: the register side
    (connecting, the feedback block, register writes) is :class:`StandIO`'s, the setpoint
    history and its checks :class:`SetpointStand`'s.

    Parameters
    ----------
    link
        A :class:`ModbusLink` (not yet connected); the driver never opens a transport itself.
    regmap
        The validated register map.
    limits
        Per-axis angle (deg), rate (deg/s) and acceleration (deg/s²) limits enforced here.
    axes
        The axes driven (a subset of the map's axes).
    setpoint_period_s
        The period T at which the stand plays setpoints (and trajectory points). Setpoints are
        judged as the sequence the stand plays (``benchctl.kinematics``): rate = step / T,
        acceleration = change of rate / T, whatever the host's send intervals; after more than
        1.5·T without a setpoint the stand has held, and the next step is judged from rest.
    zero_tolerance_deg
        "At zero" means every axis within this of 0 and at rest.
    clock
        The run's clock (``benchctl.clock``): its ``monotonic`` (seconds) stamps the samples
        and setpoints, its ``sleep`` paces the waits; the real one by default.
    """

    def __init__(
        self,
        link: ModbusLink,
        regmap: RegisterMap,
        *,
        limits: StandLimitsView,
        axes: tuple[str, ...] = ("roll", "pitch"),
        setpoint_period_s: float = 0.01,
        zero_tolerance_deg: float = 0.05,
        heartbeat_period_s: float = 0.1,
        clock: Clock = REAL,
    ) -> None:
        super().__init__(
            link, regmap, limits=limits, axes=axes, setpoint_period_s=setpoint_period_s,
            clock=clock,
        )
        self.zero_tolerance_deg = zero_tolerance_deg
        self.heartbeat_period_s = heartbeat_period_s
        #: a stop was commanded and the stand may still be braking (``ramp_to_zero`` waits)
        self._stopping = False
        self._traj_last: dict[str, AxisCommand] | None = None  # the last point queued
        self._traj_next = 0  # the index the stand's queue expects next
        self._table_axes: tuple[str, ...] = ()

    # -- tables -----------------------------------------------------------------------------
    def upload_table(self, tables: Mapping[str, HarmonicTable]) -> None:
        """Check the tables against the limits over their whole duration, write and verify them.

        Axes of this stand without a table get an empty one (they hold zero while it runs).
        """
        for a, tab in tables.items():
            if a not in self.axes:
                raise LimitError(f"table for axis {a!r}: this stand drives {list(self.axes)}")
            check_table(tab, self.limits, axis=a, max_lines=self.map.axes[a].table_max_lines)
        if not tables:
            raise LimitError("upload_table: no table given")
        words: dict[int, int] = {}
        for a in self.axes:
            words.update(self._table_words(a, tables.get(a)))
        self._write_words(words)
        for addr, count in register_runs(words, self.map.max_read):
            got = self._read(addr, count)
            want = [words[addr + i] for i in range(count)]
            if got != want:
                bad = next(i for i in range(count) if got[i] != want[i])
                raise ProtocolError(
                    f"{self.link.endpoint}: table read-back differs at address {addr + bad}: "
                    f"wrote {want[bad]}, read {got[bad]}"
                )
        self._table_axes = tuple(tables)

    def _table_words(self, axis: str, tab: HarmonicTable | None) -> dict[int, int]:
        m = self.map
        out: dict[int, int] = {}

        def put(f: Field, v: float) -> None:
            for i, w in enumerate(m.encode(f, v)):
                out[f.address + i] = w

        n = 0 if tab is None else tab.n_lines
        put(m.table_field(axis, "n_lines"), n)
        put(m.table_field(axis, "duration_s"), 0.0 if tab is None else tab.duration_s)
        put(m.table_field(axis, "fade_in_s"), 0.0 if tab is None else tab.fade_in_s)
        put(m.table_field(axis, "fade_out_s"), 0.0 if tab is None else tab.fade_out_s)
        if tab is not None:
            for k in range(n):
                put(m.table_field(axis, "freq_hz", k), float(tab.freq_hz[k]))
                put(m.table_field(axis, "amp_deg", k), float(tab.amp_deg[k]))
                put(m.table_field(axis, "phase_rad", k), float(tab.phase_rad[k]))
        return out

    def start_table(self) -> float:
        """Start the uploaded table; returns the host time of the start command (request/reply mid).

        The stand must be enabled, at rest and at zero (within ``zero_tolerance_deg``).
        """
        if not self._table_axes:
            raise DeviceError(f"{self.link.endpoint}: start_table without an uploaded table")
        s = self.read_sample()
        off = {
            a: s.angle_deg[a] for a in self.axes if abs(s.angle_deg[a]) > self.zero_tolerance_deg
        }
        if off or s.status.moving or not s.status.enabled:
            raise LimitError(
                f"start_table: the stand must be enabled and at rest at zero, got angles "
                f"{s.angle_deg}, moving={s.status.moving}, enabled={s.status.enabled}"
            )
        t0 = self._clock()
        self._control("enable", "start_table")
        t1 = self._clock()
        with self._lock:
            self._last = None
            self._t_last = -math.inf
        self._raise_fault(self.read_status())
        return 0.5 * (t0 + t1)

    def stop_table(self) -> None:
        """Stop a running table: the stand decelerates within its limits and holds."""
        self.stop()

    def stop(self) -> None:
        """Stop any motion: the stand decelerates within its limits and holds, still enabled.
        Until it is at rest it takes no setpoint (``ramp_to_zero`` waits for that)."""
        self._control("enable", "stop")
        with self._lock:
            self._last = None
            self._t_last = -math.inf
            self._stopping = True

    def estop(self) -> None:
        """Emergency stop (latched in the stand until ``reset_fault``)."""
        self._control("estop")
        with self._lock:
            self._last = None
            self._t_last = -math.inf

    def reset_fault(self, timeout_s: float = 1.0) -> None:
        """Clear a latched fault or E-stop, waiting until the stand reports it cleared.

        A stand acts on the reset at its next scan (a few ms after the write), so the status is
        polled every 10 ms; ``StandFault`` (with the code) only if a fault or E-stop is still
        reported ``timeout_s`` after the reset was written.
        """
        self._control("fault_reset")
        deadline = self._clock() + timeout_s
        while True:
            st = self.read_status()
            if not (st.fault or st.estop):
                return
            if self._clock() >= deadline:
                self._raise_fault(st)
            self._sleep(0.01)

    def go_to_zero(self, timeout_s: float = 30.0) -> None:
        """Bring the stand to rest at zero within the limits (same path as :meth:`ramp_to_zero`)."""
        self.ramp_to_zero(timeout_s)

    def ramp_to_zero(self, timeout_s: float = 30.0) -> None:
        """From wherever the stand is, moving or not, ramp to zero within the limits; wait at rest.

        A running table or trajectory is stopped first (the stand decelerates within its own
        limits). The ramp is planned from the stand's **measured** angle and rate at that
        moment (not from what was commanded before), with ``RAMP_MARGIN`` of the rate and
        acceleration limits, and streamed at the setpoint period while keeping the heartbeat.
        If a send comes so late that the stand has held its last setpoint, the rest of the
        ramp is planned afresh from the measured state: the driver's own checks therefore
        accept every step whatever happened before (``benchctl.kinematics``). Each setpoint
        is sent with a read of the stand's feedback (:meth:`send_setpoint_and_read`), so its
        samples reach ``on_sample`` all through the ramp (a fault met there raises at once).
        It ends when
        every axis has been within ``zero_tolerance_deg`` of zero and at rest for
        ``REST_HOLD_S``.

        Raises
        ------
        StandFault
            The stand is faulted or E-stopped (it cannot be moved).
        DeviceTimeout
            Not at rest at zero within ``timeout_s``.
        """
        deadline = self._clock() + timeout_s
        s = self.read_sample()
        if s.status.table_running or s.status.trajectory_running or self._stopping:
            # a stop decelerates within the stand's limits and takes no setpoint until it
            # is at rest: a ramp planned while it brakes would be a step when it has stopped
            if not self._stopping:
                self.stop()
            while True:
                s = self.read_sample()
                running = s.status.table_running or s.status.trajectory_running
                if not running and not s.status.moving:
                    break
                if not s.status.enabled:
                    break  # a fault or E-stop braked it: nothing left to wait for
                self._check_deadline(deadline, "stopping the table or trajectory")
                self._sleep(0.01)
        self._stopping = False
        if not s.status.enabled:
            self.enable()
        while True:
            self._stream_ramp(deadline)
            if self._wait_at_zero(deadline):
                return
            # not at rest at zero after the ramp (e.g. an overshoot): plan again from here

    def _stream_ramp(self, deadline: float) -> None:
        """Stream one ramp planned from the measured state; re-plan after a held setpoint."""
        lim = self.limits
        T = self.setpoint_period_s
        t_hb = -math.inf
        while True:
            s = self.read_sample()
            self._reset_history(s, measured=True)
            plans = {}
            for a in self.axes:
                # RAMP_MARGIN of the limits; the full limits where the margin would carry the
                # stand past its angle limit before it stops
                for margin in (RAMP_MARGIN, 1.0):
                    p = plan_ramp_to_zero(
                        s.angle_deg[a],
                        s.rate_deg_s[a],
                        lim.rate_deg_s * margin,
                        lim.accel_deg_s2 * margin,
                        T,
                    )
                    if np.max(np.abs(p)) <= max(lim.angle_deg, abs(s.angle_deg[a])):
                        break
                plans[a] = p
            n = max(len(p) for p in plans.values())
            t_next = self._clock()
            try:
                for k in range(n):
                    t_next += T
                    pause = t_next - self._clock()
                    if pause > 0:
                        self._sleep(pause)
                    else:
                        t_next = self._clock()  # late: carry on from now, never catch up
                    # each setpoint with the stand's feedback (one FC23 transaction where the
                    # map allows it): the ramp's samples reach the listener (the recording)
                    # as the motion's do, with no hole while it lasts
                    self.send_setpoint_and_read(
                        {a: float(p[min(k, len(p) - 1)]) for a, p in plans.items()})
                    if self._clock() - t_hb >= self.heartbeat_period_s:
                        self.heartbeat()
                        t_hb = self._clock()
                    self._check_deadline(deadline, "ramping to zero")
                return
            except StaleSetpoint as e:  # the host stalled: the stand held; plan from where it is
                log.info("ramp to zero: re-planned from the measured state (%s)", e)
                self._check_deadline(deadline, "ramping to zero")

    def _wait_at_zero(self, deadline: float) -> bool:
        """Keep the heartbeat until every axis rests at zero for REST_HOLD_S (True), or until
        an axis is off zero and no longer moving (False: ramp again)."""
        tol = self.zero_tolerance_deg
        rest_since: float | None = None
        t_hb = -math.inf
        while True:
            s = self.read_sample()
            at_zero = all(abs(s.angle_deg[a]) <= tol for a in self.axes)
            if at_zero and not s.status.moving:
                rest_since = s.t_host if rest_since is None else rest_since
                if s.t_host - rest_since >= REST_HOLD_S:  # an overshoot's turning point is no rest
                    return True
            else:
                rest_since = None
                if not at_zero and all(abs(v) < 1e-3 for v in s.rate_deg_s.values()):
                    target_off = any(abs(s.setpoint_deg[a]) > tol for a in self.axes)
                    if target_off:
                        return False
            if self._clock() - t_hb >= self.heartbeat_period_s:
                self.heartbeat()
                t_hb = self._clock()
            self._check_deadline(deadline, f"waiting at rest at zero (angles {s.angle_deg})")
            self._sleep(0.01)

    # -- buffered trajectory (PT mode) ----------------------------------------------------
    @property
    def has_trajectory(self) -> bool:
        """True when the register map describes a trajectory queue."""
        return self.map.trajectory is not None

    def _traj(self) -> Any:
        tr = self.map.trajectory
        if tr is None:
            raise DeviceError(
                f"{self.map.source}: this stand's register map has no trajectory queue "
                "(stand.mode buffered needs a `trajectory:` section)"
            )
        return tr

    def begin_trajectory(self) -> None:
        """Prepare a new trajectory: the stand must be enabled and holding; the commanded
        sequence starts from its measured state at rest, and the point period is written."""
        tr = self._traj()
        s = self.read_sample()
        if not s.status.enabled or s.status.table_running or s.status.trajectory_running:
            raise DeviceError(
                f"{self.link.endpoint}: begin_trajectory needs the stand enabled and holding "
                f"(enabled={s.status.enabled}, table={s.status.table_running}, "
                f"trajectory={s.status.trajectory_running})"
            )
        self._write_field(tr.period_s, self.setpoint_period_s)
        with self._lock:
            self._last = {a: AxisCommand(s.setpoint_deg[a], 0.0) for a in self.axes}
            self._traj_last = dict(self._last)
            self._traj_next = 0  # a push from index 0 while idle starts a new queue

    @property
    def trajectory_limits(self) -> tuple[int, int]:
        """(capacity, max points per push) of the stand's trajectory queue."""
        tr = self._traj()
        return int(tr.capacity), int(tr.max_points_per_push)

    def push_points(
        self, first_index: int, points: Mapping[str, NDArray[np.float64]], *, read: bool = True
    ) -> StandSample | None:
        """Queue points ``first_index …`` (one period apart) in the stand; with ``read`` the
        feedback block comes back in the same transaction (FC23 where the map allows it).

        Every point is judged against the limits as the stand plays it — consecutive points one
        period apart, continuing from the last point queued — before anything is written
        (``LimitError``, nothing sent). Axes of the stand not in ``points`` hold their last
        point. At most ``max_points_per_push`` points.
        """
        tr = self._traj()
        n = max((len(p) for p in points.values()), default=0)
        if not 1 <= n <= tr.max_points_per_push:
            raise LimitError(
                f"push_points: {n} points, expected 1..{tr.max_points_per_push} per push"
            )
        for a in points:
            if a not in self.axes:
                raise LimitError(f"push_points: axis {a!r}: this stand drives {list(self.axes)}")
        with self._lock:
            if self._traj_last is None:
                raise DeviceError("push_points before begin_trajectory")
            if first_index != self._traj_next:
                raise DeviceError(
                    f"push_points: first_index {first_index}, the queue expects {self._traj_next}"
                )
            prev = dict(self._traj_last)
            rows: list[list[float]] = []
            for i in range(n):
                row = []
                for a in self.map.axes:
                    if a in points:
                        x = float(points[a][i])
                        prev[a] = check_step(
                            a, prev[a], x, self._kin_limits, self.setpoint_period_s
                        )
                    else:
                        x = prev[a].angle_deg if a in prev else 0.0
                        if a in prev:
                            prev[a] = AxisCommand(x, 0.0)
                    row.append(x)
                rows.append(row)
            m = self.map
            base = tr.push_address
            words = {base + i: w for i, w in enumerate(m.encode(_U32(base), first_index))}
            words[base + 2] = n
            addr = base + 3
            point = _F32(addr)  # encode reads the field's type, scale, offset and name only
            for row in rows:
                for x in row:
                    w0, w1 = m.encode(point, x)
                    words[addr], words[addr + 1] = w0, w1
                    addr += 2
            runs = register_runs(words, self.map.max_write)
            if read and self.map.read_write_multiple and len(runs) == 1:
                t0 = self._clock()
                regs = self.link.read_write_registers(
                    pdu_address(self._fb_addr),
                    self._fb_count,
                    pdu_address(base),
                    [words[base + i] for i in range(len(words))],
                )
                t1 = self._clock()
                sample: StandSample | None = None
                self._traj_last, self._traj_next = prev, first_index + n
                self._last = dict(prev)
            else:
                self._write_words(words)
                self._traj_last, self._traj_next = prev, first_index + n
                self._last = dict(prev)
                regs = []
        if regs:
            sample = self._decode_feedback(regs, t0, t1)
            self._raise_fault(sample.status)
            return sample
        return self.read_sample() if read else None

    def start_trajectory(self) -> float:
        """Start playing the queue (point 0 now); returns the host time of the start command."""
        self._traj()
        t0 = self._clock()
        self._control("enable", "start_trajectory")
        t1 = self._clock()
        self._raise_fault(self.read_status())
        return 0.5 * (t0 + t1)


def _U32(address: int) -> Field:
    return Field("trajectory.push.first_index", address, "uint32")


def _F32(address: int) -> Field:
    return Field("trajectory.push.point", address, "float32")


def open_stand(cfg: StandConfig, *, clock: Clock = REAL) -> ModbusStand:
    """Build a (not yet connected) ``ModbusStand`` from the bench config's ``stand`` section,
    on ``clock`` (the run's; the real one by default)."""
    regmap = load_register_map(cfg.register_map)
    link: ModbusLink
    if cfg.driver == "modbus-tcp":
        link = tcp_link(
            cfg.host,
            cfg.port,
            device_id=cfg.device_id,
            timeout_s=cfg.timeout_s,
            retries=cfg.retries,
            wire_trace=cfg.wire_trace,
            clock=clock,
        )
    else:
        assert cfg.serial_port is not None
        link = rtu_link(
            cfg.serial_port,
            baudrate=cfg.baudrate,
            parity=cfg.parity,
            stopbits=cfg.stopbits,
            device_id=cfg.device_id,
            timeout_s=cfg.timeout_s,
            retries=cfg.retries,
            wire_trace=cfg.wire_trace,
            clock=clock,
        )
    lim = cfg.limits
    return ModbusStand(
        link,
        regmap,
        limits=StandLimitsView(lim.angle_deg, lim.rate_deg_s, lim.accel_deg_s2),
        axes=cfg.axes,
        setpoint_period_s=1.0 / cfg.setpoint_rate_hz,
        zero_tolerance_deg=cfg.zero_tolerance_deg,
        heartbeat_period_s=cfg.heartbeat_period_s,
        clock=clock,
    )


__all__ = [
    "ModbusStand",
    "open_stand",
    "plan_ramp_to_zero",
    "span",
]
