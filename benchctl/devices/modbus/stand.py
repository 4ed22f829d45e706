"""The stand driver over Modbus TCP/RTU: ``ModbusStand`` implements ``devices.base.Stand``.

The register map (``drivers/*.yaml``) says where everything lives; the link (``link.py``) says
how bytes travel. Public methods hold the safety checks: every setpoint is checked against the
angle, rate and acceleration limits at the point of sending and a bad one raises ``LimitError``
before anything is written; every table is checked over its whole duration before upload.
Device-reported faults and E-stops raise ``StandFault`` with the stand's fault code.

Thread safety: one streaming thread and one supervisor/heartbeat thread may share a driver;
each request holds the link's lock, the setpoint history holds the driver's lock.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from benchctl.config import StandConfig
from benchctl.devices.base import DeviceIdentity, StandLimitsView, StandSample, StandStatus
from benchctl.devices.modbus.link import ModbusLink, rtu_link, tcp_link
from benchctl.devices.modbus.regmap import Field, RegisterMap, load_register_map, pdu_address, span
from benchctl.errors import (
    ConfigError,
    DeviceError,
    DeviceTimeout,
    LimitError,
    ProtocolError,
    StandFault,
)
from benchctl.harmonics import HarmonicTable

RAMP_MARGIN = 0.8  # ramps use this fraction of the rate and acceleration limits
REST_HOLD_S = 0.1  # "at rest" must hold this long
_REL_TOL = 1e-9


@dataclass
class _Last:
    """The last setpoint sent on one axis: angle, implied rate, time, and the step used."""

    angle_deg: float
    rate_deg_s: float
    t: float
    dt: float


class ModbusStand:
    """A two-axis stand on a Modbus link, described by a register map.

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
        Nominal streaming period T. The rate implied by a setpoint is its step over dt = the
        time since the previous setpoint in whole periods, T·max(1, round(Δt/T)) (the stand
        plays setpoints on its own period, so host jitter below T/2 does not change dt); the
        acceleration is the change of that rate over the longer of the two steps' dt, so a
        host stall between two setpoints never shows up as a false acceleration.
    zero_tolerance_deg
        "At zero" means every axis within this of 0 and at rest.
    clock
        Host monotonic clock (seconds); injectable for tests.
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
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        for a in axes:
            if a not in regmap.axes:
                raise ConfigError(
                    f"{regmap.source}: axes: axis {a!r} is driven but not in the map "
                    f"(map has {list(regmap.axes)})"
                )
        self.link = link
        self.map = regmap
        self.limits = limits
        self.axes = tuple(axes)
        self.setpoint_period_s = setpoint_period_s
        self.zero_tolerance_deg = zero_tolerance_deg
        self.heartbeat_period_s = heartbeat_period_s
        self.identity: DeviceIdentity | None = None
        self.last_sample: StandSample | None = None
        self._clock = clock
        self._lock = threading.RLock()
        self._last: dict[str, _Last] | None = None
        self._hb = 0
        self._table_axes: tuple[str, ...] = ()
        self._closed = False
        self._fb_addr, self._fb_count = regmap.feedback_span()

    # -- connection -----------------------------------------------------------------------
    def connect(self) -> DeviceIdentity:
        """Open the link and read the identity registers."""
        self.link.connect()
        self._closed = False
        values: dict[str, str] = {}
        for name, f in self.map.identity.items():
            values[name] = str(self.map.decode(f, self._read(f.address, f.n_registers)))
        extra = {
            k: v for k, v in values.items() if k not in ("vendor", "model", "serial", "firmware")
        }
        extra["register_map"] = self.map.name
        self.identity = DeviceIdentity(
            vendor=values["vendor"],
            model=values["model"],
            serial=values.get("serial", ""),
            firmware=values.get("firmware", ""),
            protocol=self.link.endpoint,
            extra=extra,
        )
        return self.identity

    def close(self) -> None:
        """Close the link. Idempotent; does not move or disable the stand."""
        if not self._closed:
            self._closed = True
            self.link.close()

    # -- reading --------------------------------------------------------------------------
    def read_status(self) -> StandStatus:
        """The decoded status word, fault code and heartbeat echo. Never raises on a fault."""
        return self._read_feedback()[1].status

    def read_sample(self) -> StandSample:
        """Encoder angles, rates and active setpoints, stamped at the request/reply midpoint.

        Raises
        ------
        StandFault
            When the stand reports a fault or an E-stop (``code`` is its fault code).
        """
        _, sample = self._read_feedback()
        self._raise_fault(sample.status)
        return sample

    def _read_feedback(self) -> tuple[list[int], StandSample]:
        t0 = self._clock()
        regs = self._read(self._fb_addr, self._fb_count)
        t1 = self._clock()
        return regs, self._decode_feedback(regs, t0, t1)

    def _decode_feedback(self, regs: list[int], t0: float, t1: float) -> StandSample:
        m = self.map

        def get(f: Field) -> float:
            return float(m.decode_in(f, self._fb_addr, regs))

        bits = m.status_from_word(int(get(m.status_word)))
        status = StandStatus(
            **bits, fault_code=int(get(m.fault_code)), heartbeat=int(get(m.heartbeat_echo))
        )
        sample = StandSample(
            t_host=0.5 * (t0 + t1),
            rtt_s=t1 - t0,
            angle_deg={a: get(m.axes[a].angle) for a in self.axes},
            rate_deg_s={a: get(m.axes[a].rate) for a in self.axes},
            setpoint_deg={a: get(m.axes[a].setpoint) for a in self.axes},
            status=status,
        )
        self.last_sample = sample
        return sample

    def _raise_fault(self, st: StandStatus) -> None:
        if st.estop:
            raise StandFault(
                f"{self.link.endpoint}: E-stop is active (fault code {st.fault_code})",
                st.fault_code or None,
            )
        if st.fault:
            text = self.map.fault_codes.get(st.fault_code, "unknown fault")
            raise StandFault(
                f"{self.link.endpoint}: stand fault {st.fault_code} ({text})", st.fault_code
            )

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
            time.sleep(0.01)
        self._reset_history(sample)

    def disable(self) -> None:
        """Switch the servo off (the stand brakes to rest)."""
        self._control()
        with self._lock:
            self._last = None

    def heartbeat(self) -> None:
        """Write the next heartbeat counter value; the stand's watchdog stops it if this stops."""
        with self._lock:
            self._hb = (self._hb + 1) & 0xFFFF
            hb = self._hb
        self._write_field(self.map.heartbeat, hb)

    def send_setpoint(self, angle_deg: Mapping[str, float]) -> float:
        """Check one position setpoint against the limits, then write it; returns the send time.

        The angle, the rate implied by the step from the previous setpoint and the acceleration
        implied by the change of that rate are all checked first; any breach raises
        ``LimitError`` (needed vs allowed) and nothing is written. Axes left out hold.
        """
        with self._lock:
            words, new = self._prepare_setpoint(angle_deg)
            t_send = self._clock()
            self._write_words(words)
            assert self._last is not None
            self._last.update(new)
            return t_send

    def send_setpoint_and_read(self, angle_deg: Mapping[str, float]) -> tuple[float, StandSample]:
        """:meth:`send_setpoint` then :meth:`read_sample`, in ONE transaction where the stand can.

        With ``read_write_multiple: true`` in the register map the setpoint write and the
        feedback read travel as one FC23 request (one turnaround instead of two: on RTU at
        115200 baud that is what makes 100 Hz fit); otherwise two requests. Same checks and
        errors as the two methods; returns (send time, sample).
        """
        with self._lock:
            words, new = self._prepare_setpoint(angle_deg)
            runs = _chunks(words, self.map.max_write)
            if not (self.map.read_write_multiple and len(runs) == 1):
                t_send = self._clock()
                self._write_words(words)
                assert self._last is not None
                self._last.update(new)
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
            assert self._last is not None
            self._last.update(new)
        sample = self._decode_feedback(regs, t0, t1)
        self._raise_fault(sample.status)
        return t0, sample

    def _prepare_setpoint(
        self, angle_deg: Mapping[str, float]
    ) -> tuple[dict[int, int], dict[str, _Last]]:
        """Check the setpoint (lock held) and encode it: (address → word, new history)."""
        now = self._clock()
        if self._last is None:
            self._reset_history(self._read_feedback()[1])
            now = self._clock()
        new = self._check_setpoint(angle_deg, now)
        words: dict[int, int] = {}
        for a in angle_deg:
            f = self.map.axes[a].command
            for i, w in enumerate(self.map.encode(f, float(angle_deg[a]))):
                words[f.address + i] = w
        return words, new

    def _check_setpoint(self, angle_deg: Mapping[str, float], now: float) -> dict[str, _Last]:
        assert self._last is not None
        lim = self.limits
        new: dict[str, _Last] = {}
        for a, x in angle_deg.items():
            if a not in self.axes:
                raise LimitError(f"setpoint for axis {a!r}: this stand drives {list(self.axes)}")
            x = float(x)
            if not math.isfinite(x):
                raise LimitError(f"setpoint {a} = {x}: not a finite angle")
            if abs(x) > lim.angle_deg * (1 + _REL_TOL):
                raise LimitError(
                    f"setpoint {a} = {x:.4f}°: needs |angle| {abs(x):.4f}°, allowed "
                    f"{lim.angle_deg}°"
                )
            prev = self._last[a]
            # whole setpoint periods: the stand plays setpoints on its own period, so host
            # jitter below half a period does not change the step's duration (run layer issue #5)
            T = self.setpoint_period_s
            dt = T * max(1, round((now - prev.t) / T))
            v = (x - prev.angle_deg) / dt
            if abs(v) > lim.rate_deg_s * (1 + _REL_TOL):
                raise LimitError(
                    f"setpoint {a} = {x:.4f}° after {prev.angle_deg:.4f}° {dt * 1e3:.1f} ms "
                    f"earlier: needs rate {abs(v):.3f}°/s, allowed {lim.rate_deg_s}°/s"
                )
            acc = (v - prev.rate_deg_s) / max(dt, prev.dt)
            if abs(acc) > lim.accel_deg_s2 * (1 + _REL_TOL):
                raise LimitError(
                    f"setpoint {a} = {x:.4f}°: rate changes {prev.rate_deg_s:.3f} → {v:.3f}°/s "
                    f"in {dt * 1e3:.1f} ms: needs acceleration {abs(acc):.2f}°/s², "
                    f"allowed {lim.accel_deg_s2}°/s²"
                )
            new[a] = _Last(x, v, now, dt)
        return new

    def _reset_history(self, sample: StandSample) -> None:
        with self._lock:
            self._last = {
                a: _Last(
                    sample.setpoint_deg[a] if sample.status.enabled else sample.angle_deg[a],
                    sample.rate_deg_s[a],
                    sample.t_host,
                    self.setpoint_period_s,
                )
                for a in self.axes
            }

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
        for addr, count in _chunks(words, self.map.max_read):
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
        self._raise_fault(self.read_status())
        return 0.5 * (t0 + t1)

    def stop_table(self) -> None:
        """Stop a running table: the stand decelerates within its limits and holds."""
        self.stop()

    def stop(self) -> None:
        """Stop any motion: the stand decelerates within its limits and holds, still enabled."""
        self._control("enable", "stop")
        with self._lock:
            self._last = None

    def estop(self) -> None:
        """Emergency stop (latched in the stand until ``reset_fault``)."""
        self._control("estop")
        with self._lock:
            self._last = None

    def reset_fault(self) -> None:
        """Clear a latched fault or E-stop; raises StandFault if the stand still reports one."""
        self._control("fault_reset")
        self._raise_fault(self.read_status())

    def go_to_zero(self, timeout_s: float = 30.0) -> None:
        """Bring the stand to rest at zero within the limits (same path as :meth:`ramp_to_zero`)."""
        self.ramp_to_zero(timeout_s)

    def ramp_to_zero(self, timeout_s: float = 30.0) -> None:
        """From wherever the stand is, moving or not, ramp to zero within the limits; wait at rest.

        A running table is stopped first. The ramp uses ``RAMP_MARGIN`` of the rate and
        acceleration limits, is streamed at the setpoint period, keeps the heartbeat, and ends
        when every axis has been within ``zero_tolerance_deg`` of zero and at rest for
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
        if s.status.table_running:
            self.stop()
            while True:
                s = self.read_sample()
                if not s.status.table_running and not s.status.moving:
                    break
                self._check_deadline(deadline, "stopping the table")
                time.sleep(0.01)
        if not s.status.enabled:
            self.enable()
        with self._lock:
            if self._last is None or self._clock() - max(v.t for v in self._last.values()) > 0.5:
                self._reset_history(self.read_sample())
            assert self._last is not None
            start = {a: (self._last[a].angle_deg, self._last[a].rate_deg_s) for a in self.axes}
        lim = self.limits
        T = self.setpoint_period_s
        plans = {
            a: plan_ramp_to_zero(
                x0, v0, lim.rate_deg_s * RAMP_MARGIN, lim.accel_deg_s2 * RAMP_MARGIN, T
            )
            for a, (x0, v0) in start.items()
        }
        n = max(len(p) for p in plans.values())
        t_next = self._clock()
        t_hb = t_next
        for k in range(n):
            t_next += T
            pause = t_next - self._clock()
            if pause > 0:
                time.sleep(pause)
            else:
                t_next = self._clock()  # late: carry on from now, never catch up in a burst
            self.send_setpoint({a: float(p[min(k, len(p) - 1)]) for a, p in plans.items()})
            if self._clock() - t_hb >= self.heartbeat_period_s:
                self.heartbeat()
                t_hb = self._clock()
            self._check_deadline(deadline, "ramping to zero")
        tol = self.zero_tolerance_deg
        rest_since: float | None = None
        while True:
            s = self.read_sample()
            if all(abs(s.angle_deg[a]) <= tol for a in self.axes) and not s.status.moving:
                rest_since = s.t_host if rest_since is None else rest_since
                if s.t_host - rest_since >= REST_HOLD_S:  # an overshoot's turning point is no rest
                    return
            else:
                rest_since = None
            if self._clock() - t_hb >= self.heartbeat_period_s:
                self.heartbeat()
                t_hb = self._clock()
            self._check_deadline(deadline, f"waiting at rest at zero (angles {s.angle_deg})")
            time.sleep(0.01)

    def _check_deadline(self, deadline: float, what: str) -> None:
        if self._clock() > deadline:
            raise DeviceTimeout(f"{self.link.endpoint}: timed out {what}")

    # -- low level --------------------------------------------------------------------------
    def _control(self, *bits: str) -> None:
        word = self.map.word_from_bits(self.map.control_bits, bits)
        self._write_field(self.map.control_word, word)

    def _write_field(self, f: Field, value: float) -> None:
        self._write_words({f.address + i: w for i, w in enumerate(self.map.encode(f, value))})

    def _write_words(self, words: Mapping[int, int]) -> None:
        """Write registers (address → word) in as few requests as the map allows (FC6 for one)."""
        for addr, count in _chunks(words, self.map.max_write):
            vals = [words[addr + i] for i in range(count)]
            if count == 1:
                self.link.write_register(pdu_address(addr), vals[0])
            else:
                self.link.write_registers(pdu_address(addr), vals)

    def _read(self, addr: int, count: int) -> list[int]:
        out: list[int] = []
        for a, c in _chunks({addr + i: 0 for i in range(count)}, self.map.max_read):
            out += self.link.read_registers(pdu_address(a), c)
        return out


def _chunks(words: Mapping[int, int], max_count: int) -> list[tuple[int, int]]:
    """(address, count) runs of consecutive addresses, each at most ``max_count`` long."""
    out: list[tuple[int, int]] = []
    for a in sorted(words):
        if out and out[-1][0] + out[-1][1] == a and out[-1][1] < max_count:
            out[-1] = (out[-1][0], out[-1][1] + 1)
        else:
            out.append((a, 1))
    return out


def check_table(tab: HarmonicTable, limits: StandLimitsView, *, axis: str, max_lines: int) -> None:
    """Raise ``LimitError`` if a table exceeds the limits anywhere in its duration.

    Angle, rate and acceleration are evaluated on a grid of at least 40 points per period of the
    highest line (and 20 per fade), including the fades; the message gives needed vs allowed.
    """
    if tab.n_lines > max_lines:
        raise LimitError(f"table {axis}: {tab.n_lines} lines, the stand takes at most {max_lines}")
    if tab.n_lines == 0:
        raise LimitError(f"table {axis}: no lines")
    for name in ("freq_hz", "amp_deg", "phase_rad"):
        if not np.all(np.isfinite(getattr(tab, name))):
            raise LimitError(f"table {axis}: {name} holds a non-finite value")
    if np.any(tab.freq_hz < 0):
        raise LimitError(f"table {axis}: negative frequency {float(tab.freq_hz.min())} Hz")
    if not 0 < tab.duration_s < 1e6:
        raise LimitError(
            f"table {axis}: duration_s {tab.duration_s} s: expected 0 < duration < 1e6 s"
        )
    fmax = float(tab.freq_hz.max())
    step = 1.0 / (40.0 * fmax) if fmax > 0 else tab.duration_s
    fades = [f for f in (tab.fade_in_s, tab.fade_out_s) if f > 0]
    if fades:
        step = min(step, min(fades) / 20.0)
    n = min(math.ceil(tab.duration_s / step) + 1, 5_000_000)
    t = np.linspace(0.0, tab.duration_s, n)
    for deriv, allowed, unit, what in (
        (0, limits.angle_deg, "°", "angle"),
        (1, limits.rate_deg_s, "°/s", "rate"),
        (2, limits.accel_deg_s2, "°/s²", "acceleration"),
    ):
        peak = float(np.max(np.abs(tab.evaluate(t, deriv))))
        if peak > allowed:
            raise LimitError(
                f"table {axis}: needs {what} {peak:.3f}{unit}, allowed {allowed}{unit}"
            )


def plan_ramp_to_zero(
    x0_deg: float, v0_deg_s: float, rate_deg_s: float, accel_deg_s2: float, dt_s: float
) -> np.ndarray:
    """Setpoints every ``dt_s`` that bring an axis from angle x0, rate v0 to rest at 0.

    Each step changes the rate by at most ``accel_deg_s2``·dt and keeps it within
    ``rate_deg_s`` (a current rate above that is first brought down at the acceleration limit);
    the target rate is the largest that can still stop at zero, sign(−x)·min(rate, √(2a|x|)).
    The last setpoint is exactly 0.

    Returns
    -------
    ndarray
        Angles in degrees, one per period after the start (the start itself excluded).
    """
    if rate_deg_s <= 0 or accel_deg_s2 <= 0 or dt_s <= 0:
        raise ValueError("rate_deg_s, accel_deg_s2 and dt_s must be > 0")
    x, v = float(x0_deg), float(v0_deg_s)
    dv = accel_deg_s2 * dt_s
    out: list[float] = []
    for _ in range(10_000_000):
        # finish when one step lands on 0 and the next holds there, both within the limits
        if abs(x) <= dv * dt_s and abs(x / dt_s + v) <= dv:
            out.append(0.0)
            return np.asarray(out)
        v_des = -math.copysign(min(rate_deg_s, math.sqrt(2.0 * accel_deg_s2 * abs(x))), x)
        v += min(max(v_des - v, -dv), dv)
        x += v * dt_s
        out.append(x)
    raise DeviceError("plan_ramp_to_zero did not converge")  # pragma: no cover


def open_stand(cfg: StandConfig) -> ModbusStand:
    """Build a (not yet connected) ``ModbusStand`` from the bench config's ``stand`` section."""
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
    )


__all__ = ["ModbusStand", "check_table", "open_stand", "plan_ramp_to_zero", "span"]
