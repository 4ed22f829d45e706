"""The stand's commanded sequence: the setpoint history, and every setpoint judged against it.

``SetpointStand`` (on :class:`StandIO`) keeps the last commanded point per axis and when it was
sent, and judges each new setpoint as the stand plays it — one period T after the last, from rest
when the stand has held (``benchctl.kinematics.check_step``) — before anything is written: a
breach raises ``LimitError`` (or ``StaleSetpoint``). It enables and disables the servo, keeps the
heartbeat, and sends setpoints alone or with a read of the feedback block in one transaction.
``ModbusStand`` (``stand.py``) builds the tables, stops and trajectories on it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from benchctl.clock import REAL, Clock
from benchctl.devices.base import StandLimitsView, StandSample
from benchctl.devices.modbus.link import ModbusLink
from benchctl.devices.modbus.regmap import RegisterMap, pdu_address
from benchctl.devices.modbus.stand_io import StandIO, register_runs
from benchctl.errors import DeviceTimeout, LimitError
from benchctl.kinematics import HELD_AFTER_PERIODS, AxisCommand, Limits, check_step


class SetpointStand(StandIO):
    """The register side (:class:`StandIO`) with the setpoint history and its checks.

    Parameters
    ----------
    link, regmap, axes, clock
        As :class:`StandIO`.
    limits
        Per-axis angle (deg), rate (deg/s) and acceleration (deg/s²) limits enforced here.
    setpoint_period_s
        The period T at which the stand plays setpoints (and trajectory points). Setpoints are
        judged as the sequence the stand plays (``benchctl.kinematics``): rate = step / T,
        acceleration = change of rate / T, whatever the host's send intervals; after more than
        1.5·T without a setpoint the stand has held, and the next step is judged from rest.
    """

    def __init__(
        self,
        link: ModbusLink,
        regmap: RegisterMap,
        *,
        limits: StandLimitsView,
        axes: tuple[str, ...] = ("roll", "pitch"),
        setpoint_period_s: float = 0.01,
        clock: Clock = REAL,
    ) -> None:
        super().__init__(link, regmap, axes=axes, clock=clock)
        self.limits = limits
        self.setpoint_period_s = setpoint_period_s
        self._lock = clock.rlock()
        self._last: dict[str, AxisCommand] | None = None  # the last commanded point per axis
        self._t_last = -math.inf  # when it was sent
        self._hb = 0

    # -- commands ---------------------------------------------------------------------------
    def enable(self, timeout_s: float = 2.0) -> None:
        """Switch the servo on; the stand then holds where it is. Raises StandFault if faulted."""
        self._raise_fault(self.read_status())
        self._control("enable")
        deadline = self._clock() + timeout_s
        while True:
            sample = self.read_sample()
            if sample.status.enabled:
                break
            if self._clock() > deadline:
                raise DeviceTimeout(f"{self.link.endpoint}: not enabled within {timeout_s} s")
            self._sleep(0.01)
        self._reset_history(sample)

    def disable(self) -> None:
        """Switch the servo off (the stand brakes to rest)."""
        self._control()
        with self._lock:
            self._last = None
            self._t_last = -math.inf

    def heartbeat(self) -> None:
        """Write the next heartbeat counter value; the stand's watchdog stops it if this stops."""
        with self._lock:
            self._hb = (self._hb + 1) & 0xFFFF
            hb = self._hb
        self._write_field(self.map.heartbeat, hb)

    def send_setpoint(
        self, angle_deg: Mapping[str, float], *, t_slot: float | None = None
    ) -> float:
        """Check one position setpoint against the limits, then write it; returns the send time.

        The angle, the rate of the step from the previous setpoint (one period T earlier as the
        stand plays it) and the change of that rate are all checked first; any breach raises
        ``LimitError`` (needed vs allowed) and nothing is written — ``StaleSetpoint`` when the
        breach is only because the stand has held (no setpoint for more than 1.5·T). Axes left
        out hold. ``t_slot`` (the slot the setpoint belongs to) goes to the listener.
        """
        with self._lock:
            words, new, now = self._prepare_setpoint(angle_deg)
            t_send = self._clock()
            self._write_words(words)
            self._commit(new, now)
        self._notify_setpoint(t_send, angle_deg, t_slot)
        return t_send

    def _commit(self, new: Mapping[str, AxisCommand], now: float) -> None:
        """Take ``new`` as the last commanded points, sent at ``now`` (lock held)."""
        assert self._last is not None
        held = now - self._t_last > HELD_AFTER_PERIODS * self.setpoint_period_s
        for a in self.axes:
            if a in new:
                self._last[a] = new[a]
            elif held:  # an axis left out holds: its rate is 0
                self._last[a] = AxisCommand(self._last[a].angle_deg, 0.0)
        self._t_last = now

    @property
    def commanded(self) -> dict[str, AxisCommand] | None:
        """The last commanded point per axis (angle, rate of its step), or None."""
        with self._lock:
            return None if self._last is None else dict(self._last)

    def send_setpoint_and_read(
        self, angle_deg: Mapping[str, float], *, t_slot: float | None = None
    ) -> tuple[float, StandSample]:
        """:meth:`send_setpoint` then :meth:`read_sample`, in ONE transaction where the stand can.

        With ``read_write_multiple: true`` in the register map the setpoint write and the
        feedback read travel as one FC23 request (one turnaround instead of two: on RTU at
        115200 baud that is what makes 100 Hz fit); otherwise two requests. Same checks and
        errors as the two methods; returns (send time, sample).
        """
        with self._lock:
            words, new, now = self._prepare_setpoint(angle_deg)
            runs = register_runs(words, self.map.max_write)
            if not (self.map.read_write_multiple and len(runs) == 1):
                t_send = self._clock()
                self._write_words(words)
                self._commit(new, now)
                self._notify_setpoint(t_send, angle_deg, t_slot)
                return t_send, self.read_sample()
            addr, count = runs[0]
            t0 = self._clock()
            regs = self.link.read_write_registers(
                pdu_address(self._fb_addr),
                self._fb_count,
                pdu_address(addr),
                [words[addr + i] for i in range(count)],
            )
            t1 = self._clock()
            self._commit(new, now)
        self._notify_setpoint(t0, angle_deg, t_slot)
        sample = self._decode_feedback(regs, t0, t1)
        self._raise_fault(sample.status)
        return t0, sample

    def _prepare_setpoint(
        self, angle_deg: Mapping[str, float]
    ) -> tuple[dict[int, int], dict[str, AxisCommand], float]:
        """Check the setpoint (lock held) and encode it: (address → word, new points, now)."""
        if self._last is None:
            self._reset_history(self._read_feedback()[1])
        now = self._clock()
        new = self._check_setpoint(angle_deg, now)
        words: dict[int, int] = {}
        for a in angle_deg:
            f = self.map.axes[a].command
            for i, w in enumerate(self.map.encode(f, float(angle_deg[a]))):
                words[f.address + i] = w
        return words, new, now

    @property
    def _kin_limits(self) -> Limits:
        lim = self.limits
        return Limits(lim.angle_deg, lim.rate_deg_s, lim.accel_deg_s2)

    def _check_setpoint(
        self, angle_deg: Mapping[str, float], now: float
    ) -> dict[str, AxisCommand]:
        """Judge the setpoint as the stand plays it (one period after the last; from rest when
        the stand has held): ``benchctl.kinematics.check_step`` per axis."""
        assert self._last is not None
        held = now - self._t_last > HELD_AFTER_PERIODS * self.setpoint_period_s
        new: dict[str, AxisCommand] = {}
        for a, x in angle_deg.items():
            if a not in self.axes:
                raise LimitError(f"setpoint for axis {a!r}: this stand drives {list(self.axes)}")
            new[a] = check_step(
                a, self._last[a], x, self._kin_limits, self.setpoint_period_s, held=held
            )
        return new

    def _reset_history(self, sample: StandSample, *, measured: bool = False) -> None:
        """Start the commanded sequence afresh: from the stand's active setpoint at rest, or
        (``measured``) from its measured angle and rate — the state a stop is planned from."""
        with self._lock:
            self._last = {
                a: AxisCommand(
                    sample.angle_deg[a]
                    if measured or not sample.status.enabled
                    else sample.setpoint_deg[a],
                    sample.rate_deg_s[a] if measured else 0.0,
                )
                for a in self.axes
            }
            # measured: the sequence continues from this moment; else it starts from rest
            self._t_last = self._clock() if measured else -math.inf


__all__ = ["SetpointStand"]
