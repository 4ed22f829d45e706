"""The kinematic safety of commanded motion: the setpoint check judges the sequence as the stand
plays it, the safe stop is never refused and never exceeds a limit, a rejoin stays in limits.

The driver runs against an in-memory Modbus peer (``MemoryStand``: the register map's own
encoding, a stand that follows its setpoint and reports it as its measured angle) and an
injected clock whose ``sleep`` may stall the host at random, so the properties are checked
exactly, without wall-clock timing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from repo_paths import ROOT

from benchctl.clock import RealClock
from benchctl.devices.base import StandLimitsView
from benchctl.devices.modbus.regmap import RegisterMap
from benchctl.devices.modbus.regmap_load import load_register_map
from benchctl.devices.modbus.stand import ModbusStand
from benchctl.devices.modbus.table_limits import check_table, table_peak
from benchctl.errors import LimitError
from benchctl.harmonics import HarmonicTable
from benchctl.kinematics import (
    AxisCommand,
    Limits,
    StaleSetpoint,
    check_step,
    plan_ramp_to_zero,
    plan_rejoin,
    profile_peaks,
)

MAP = ROOT / "drivers" / "stand_generic.yaml"
LIM = Limits(angle_deg=30.0, rate_deg_s=30.0, accel_deg_s2=60.0)
T = 0.01


class FakeClock(RealClock):
    """Monotonic time that moves only when slept on (plus any stall the test injects)."""

    def __init__(self, stalls: Sequence[float] = ()) -> None:
        self.t = 1000.0
        self.stalls = list(stalls)

    def __call__(self) -> float:
        return self.t

    def monotonic(self) -> float:
        return self.t

    def sleep(self, dt: float) -> None:
        self.t += max(0.0, dt)
        if self.stalls:
            self.t += self.stalls.pop(0)  # the host was descheduled after the sleep


class MemoryStand:
    """An in-memory Modbus peer for the driver: holding registers per the register map.

    The stand follows each setpoint: its measured angle is the last setpoint, its rate the last
    step over T (0 once it has held for more than 1.5 T). ``sent`` records (time, roll, pitch).
    """

    endpoint = "memory"

    def __init__(self, regmap: RegisterMap, clock: FakeClock, x0: float, v0: float) -> None:
        self.m = regmap
        self.clock = clock
        self.regs: dict[int, int] = {}
        self.angle = {"roll": x0, "pitch": 0.0}
        self.rate = {"roll": v0, "pitch": 0.0}
        self.setpoint = dict(self.angle)
        self.enabled = True
        self.t_last = clock()
        self.sent: list[tuple[float, float, float]] = []
        for _name, f in regmap.identity.items():
            self._put(f, "x" if f.type == "string" else 1)

    def _put(self, f, value) -> None:  # type: ignore[no-untyped-def]
        for i, w in enumerate(self.m.encode(f, value)):
            self.regs[f.address + i] = w

    def _refresh(self) -> None:
        m = self.m
        if self.clock() - self.t_last > 1.5 * T:
            self.rate = dict.fromkeys(self.rate, 0.0)
        moving = any(abs(v) > 1e-9 for v in self.rate.values())
        bits = ["ready"] + (["enabled"] if self.enabled else []) + (["moving"] if moving else [])
        self._put(m.status_word, m.word_from_bits(m.status_bits, bits))
        self._put(m.fault_code, 0)
        self._put(m.heartbeat_echo, 0)
        for a, ax in m.axes.items():
            self._put(ax.angle, self.angle[a])
            self._put(ax.rate, self.rate[a])
            self._put(ax.setpoint, self.setpoint[a])
            self._put(ax.fault_code, 0)
        tr = m.trajectory
        if tr is not None:
            for f in (tr.level, tr.next_index, tr.played, tr.underruns):
                self._put(f, 0)

    # the ModbusLink interface
    def connect(self) -> None: ...

    def close(self) -> None: ...

    def read_registers(self, address: int, count: int) -> list[int]:
        self._refresh()
        return [self.regs.get(address + i, 0) for i in range(count)]

    def write_register(self, address: int, value: int) -> None:
        self.write_registers(address, [value])

    def write_registers(self, address: int, values: Sequence[int]) -> None:
        for i, v in enumerate(values):
            self.regs[address + i] = v
        m = self.m
        if address == m.control_word.address:
            self.enabled = bool(values[0] >> m.control_bits["enable"] & 1)
        cmd = {}
        for a, ax in m.axes.items():
            if ax.command.address == address or ax.command.address in range(
                address, address + len(values)
            ):
                words = [self.regs[ax.command.address + i] for i in range(2)]
                cmd[a] = float(m.decode(ax.command, words))
        if cmd:
            now = self.clock()
            held = now - self.t_last > 1.5 * T
            for a, x in cmd.items():
                self.rate[a] = (x - self.angle[a]) / T
                self.angle[a] = self.setpoint[a] = x
            self.sent.append((now, self.angle["roll"], self.angle["pitch"], held))  # type: ignore[arg-type]
            self.t_last = now

    def read_write_registers(
        self, read_address: int, read_count: int, write_address: int, values: Sequence[int]
    ) -> list[int]:
        self.write_registers(write_address, values)
        return self.read_registers(read_address, read_count)


def _driver(x0: float, v0: float, stalls: Sequence[float] = ()) -> tuple[ModbusStand, MemoryStand]:
    clock = FakeClock(stalls)
    regmap = load_register_map(MAP)
    peer = MemoryStand(regmap, clock, x0, v0)
    stand = ModbusStand(
        peer,  # type: ignore[arg-type]
        regmap,
        limits=StandLimitsView(LIM.angle_deg, LIM.rate_deg_s, LIM.accel_deg_s2),
        axes=("roll", "pitch"),
        setpoint_period_s=T,
        zero_tolerance_deg=0.05,
        clock=clock,
    )
    stand.connect()
    return stand, peer


def _judge(sent: list, x0: float, v0: float) -> tuple[float, float]:  # type: ignore[type-arg]
    """Largest rate and acceleration of the sequence the stand played, from its measured start;
    a step after a hold starts from rest. Steps that leave an over-limit start are excused as
    the driver excuses them (moving back towards the limits)."""
    x_prev, v_prev = x0, v0
    worst_v = worst_a = 0.0
    for _t, x, _p, held in sent:
        v = (x - x_prev) / T
        base = 0.0 if held else v_prev
        if not (abs(v) <= abs(base) and v * base >= 0):
            worst_v = max(worst_v, abs(v))
        worst_a = max(worst_a, abs(v - base) / T)
        x_prev, v_prev = x, v
    return worst_v, worst_a


def _stoppable(x: float, v: float) -> bool:
    """A state from which a stop at the acceleration limit stays within the angle limit."""
    return abs(x + math.copysign(v * v / (2 * LIM.accel_deg_s2), v)) <= LIM.angle_deg - 0.05


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(
    x0=st.floats(-30.0, 30.0),
    v0=st.floats(-30.0, 30.0),
    prior=st.tuples(st.floats(-30.0, 30.0), st.floats(-30.0, 30.0), st.floats(0.0, 1.0)),
    stalls=st.lists(st.sampled_from([0.0, 0.0, 0.0, 0.004, 0.012, 0.025, 0.1]), max_size=40),
)
def test_ramp_to_zero_is_never_refused_and_stays_in_limits(
    x0: float, v0: float, prior: tuple[float, float, float], stalls: list[float]
) -> None:
    """Whatever was commanded before (any angle, rate, any time since the last setpoint) and
    however the host stalls during the ramp, the stop from the measured state is accepted by
    the driver's own checks, keeps the rate and acceleration of the played sequence within the
    limits, and ends at rest at zero."""
    if not _stoppable(x0, v0):
        return
    stand, peer = _driver(x0, v0, stalls)
    px, pv, since = prior
    stand._last = {"roll": AxisCommand(px, pv), "pitch": AxisCommand(0.0, 0.0)}
    stand._t_last = peer.clock() - since
    stand.ramp_to_zero(timeout_s=60.0)  # raises on any refusal
    assert abs(peer.angle["roll"]) <= 0.05
    worst_v, worst_a = _judge(peer.sent, x0, v0)
    # the stand plays the setpoints as float32 on the wire (the driver judges them before the
    # encoding): a rounding of at most one float32 ulp at 30° (1.9e-6°) per point is allowed
    ulp = float(np.spacing(np.float32(LIM.angle_deg)))
    assert worst_v <= LIM.rate_deg_s * (1 + 1e-9) + 2 * ulp / T
    assert worst_a <= LIM.accel_deg_s2 * (1 + 1e-9) + 4 * ulp / T**2
    assert max(abs(x) for _t, x, _p, _h in peer.sent) <= LIM.angle_deg


def test_ramp_after_a_pause_mid_stream_is_accepted() -> None:
    """The issue's reproduction: stream at 4°/s, pause 25 ms, call ramp_to_zero."""
    stand, peer = _driver(0.0, 0.0)
    clock = peer.clock
    x = v = 0.0
    for _ in range(200):
        v = min(4.0, v + 0.5)  # up to 4°/s at 50°/s²
        x += v * T
        stand.send_setpoint({"roll": x})
        clock.sleep(T)
    clock.sleep(0.025)
    stand.ramp_to_zero(timeout_s=30.0)
    assert abs(peer.angle["roll"]) <= 0.05


@settings(max_examples=50, deadline=None)
@given(
    jitter=st.lists(st.floats(-0.49, 0.49), min_size=300, max_size=300),
    amp=st.floats(0.5, 10.0),
    period=st.floats(3.0, 12.0),
)
def test_host_jitter_never_fails_a_valid_profile(
    jitter: list[float], amp: float, period: float
) -> None:
    """Setpoints of a profile within the limits, sent with any host jitter below half a period,
    are all accepted: the check judges the sequence, not the send intervals."""
    t = np.arange(300) * T
    w = 2 * math.pi / period
    env = np.minimum(1.0, t / 1.0) ** 3
    x = amp * env * np.sin(w * t)
    v, a = profile_peaks(x, T)
    if v > LIM.rate_deg_s or a > LIM.accel_deg_s2:
        return
    stand, peer = _driver(0.0, 0.0)
    clock = peer.clock
    for k in range(300):
        clock.t = 2000.0 + (k + jitter[k]) * T
        stand.send_setpoint({"roll": float(x[k])})
    assert len(peer.sent) == 300


def test_a_step_after_the_stand_held_is_stale_not_a_limit() -> None:
    stand, peer = _driver(0.0, 0.0)
    clock = peer.clock
    x = v = 0.0
    for _ in range(50):
        v = min(10.0, v + 0.5)
        x += v * T
        stand.send_setpoint({"roll": x})
        clock.sleep(T)
    clock.sleep(0.05)  # the host stalled: the stand held
    n = len(peer.sent)
    with pytest.raises(StaleSetpoint):
        stand.send_setpoint({"roll": x + 10.0 * T})
    assert len(peer.sent) == n  # nothing was written
    with pytest.raises(LimitError):
        stand.send_setpoint({"roll": x + 1.0})  # 100°/s: a real limit breach, also refused


@settings(max_examples=150, deadline=None)
@given(
    x=st.floats(-30.0, 30.0),
    v=st.floats(-30.0, 30.0),
    held=st.booleans(),
    step=st.floats(-2.0, 2.0),
)
def test_check_step_refuses_exactly_the_breaches(
    x: float, v: float, held: bool, step: float
) -> None:
    """A step is accepted iff it keeps angle, rate and acceleration within the limits (or moves
    back towards them from a start already beyond)."""
    prev = AxisCommand(x, v)
    new_x = x + step
    v0 = 0.0 if held else v
    new_v = (new_x - x) / T
    ok_angle = abs(new_x) <= LIM.angle_deg * (1 + 1e-9) or abs(new_x) <= abs(x)
    ok_rate = abs(new_v) <= LIM.rate_deg_s * (1 + 1e-9) or (
        abs(new_v) <= abs(v0) and new_v * v0 >= 0
    )
    ok_acc = abs(new_v - v0) / T <= LIM.accel_deg_s2 * (1 + 1e-9)
    if ok_angle and ok_rate and ok_acc:
        assert check_step("roll", prev, new_x, LIM, T, held=held) == AxisCommand(new_x, new_v)
    else:
        with pytest.raises(LimitError):
            check_step("roll", prev, new_x, LIM, T, held=held)


@settings(max_examples=100, deadline=None)
@given(
    slot=st.integers(10, 5000),
    dx=st.floats(-3.0, 3.0),
    amp=st.floats(0.5, 8.0),
    period=st.floats(4.0, 12.0),
)
def test_rejoin_stays_in_limits_and_lands_on_the_profile(
    slot: int, dx: float, amp: float, period: float
) -> None:
    t = np.arange(6001) * T
    prof = amp * np.sin(2 * math.pi * t / period) * np.minimum(1.0, t / 5.0) ** 3
    peaks = profile_peaks(prof, T)
    if peaks[0] > 0.9 * LIM.rate_deg_s or peaks[1] > 0.9 * LIM.accel_deg_s2:
        return
    x_held = float(prof[slot - 1]) + dx
    if abs(x_held) > LIM.angle_deg:
        return
    last = {"roll": AxisCommand(x_held, 0.0)}
    rej = plan_rejoin({"roll": prof}, slot, last, LIM, T, {"roll": peaks})
    path = rej.points["roll"]
    seq = np.concatenate([[x_held], path, prof[rej.first_slot + path.size :][:3]])
    v = np.diff(seq) / T
    acc = np.diff(np.concatenate([[0.0], v])) / T
    assert np.max(np.abs(v)) <= LIM.rate_deg_s * (1 + 1e-9)
    assert np.max(np.abs(acc)) <= LIM.accel_deg_s2 * (1 + 1e-9)
    # the path's last point is on the profile
    assert path.size == 0 or abs(path[-1] - prof[rej.first_slot + path.size - 1]) < 1e-9


def test_plan_ramp_to_zero_ends_at_zero_within_limits() -> None:
    for x0, v0 in ((10.0, 0.0), (-5.0, 20.0), (0.3, -29.0), (29.0, 30.0)):
        p = plan_ramp_to_zero(x0, v0, 30.0, 60.0, T)
        assert p[-1] == 0.0
        seq = np.concatenate([[x0], p])
        v = np.diff(seq) / T
        acc = np.diff(np.concatenate([[v0], v])) / T
        assert np.max(np.abs(acc)) <= 60.0 * (1 + 1e-9)


def test_table_check_holds_in_continuous_time() -> None:
    """A table scaled so its acceleration peak sits between grid points: the continuous-time
    peak (found by refinement) is what the check judges, to 1e-6 of a dense evaluation."""
    tab = HarmonicTable(
        np.array([0.1, 0.173, 0.31]),
        np.array([3.0, 2.0, 1.0]),
        np.array([0.3, 1.1, 2.0]),
        duration_s=60.0,
        fade_in_s=5.0,
        fade_out_s=5.0,
    )
    dense = np.linspace(0.0, 60.0, 3_000_001)
    true_acc = float(np.max(np.abs(tab.evaluate(dense, 2))))
    found = table_peak(tab, 2)
    assert found == pytest.approx(true_acc, rel=1e-6)
    assert found >= true_acc * (1 - 1e-9)
    lim = StandLimitsView(30.0, 30.0, true_acc * (1 - 1e-5))  # just below the true peak
    with pytest.raises(LimitError, match="acceleration"):
        check_table(tab, lim, axis="roll", max_lines=64)
    check_table(tab, StandLimitsView(30.0, 30.0, true_acc * (1 + 1e-5)), axis="roll", max_lines=64)
