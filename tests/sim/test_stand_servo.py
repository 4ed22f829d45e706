"""Servo physics, ramp planning and table checks: pure functions against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchctl.devices.base import StandLimitsView
from benchctl.devices.modbus.stand import plan_ramp_to_zero
from benchctl.devices.modbus.table_limits import check_table
from benchctl.errors import LimitError
from benchctl.harmonics import HarmonicTable
from benchctl.sim.servo import AxisState, ServoModel, brake_step, quantise, servo_step


def model(tick_s: float = 1e-3, **kw: float) -> ServoModel:
    p = {"natural_freq_hz": 3.0, "damping": 0.6, "rate_limit_deg_s": 1e3, "accel_limit_deg_s2": 1e5}
    p.update(kw)
    return ServoModel(tick_s=tick_s, **p)


def test_response_is_unity_at_dc_and_tends_to_the_continuous_servo() -> None:
    m = model(tick_s=1e-5)
    assert complex(m.response(0.0)) == pytest.approx(1.0)
    f = np.array([0.5, 3.0, 10.0])
    wn, w = m.omega_n, 2 * np.pi * f
    continuous = wn**2 / (wn**2 - w**2 + 2j * m.damping * wn * w)
    assert np.allclose(m.response(f), continuous, rtol=1e-3)
    # at the natural frequency the continuous servo lags 90° with gain 1/(2ζ)
    assert abs(complex(m.response(3.0))) == pytest.approx(1 / (2 * 0.6), rel=1e-3)


def test_ticked_servo_follows_a_sine_by_its_response() -> None:
    m = model()
    f, amp = 1.5, 0.5
    s = AxisState()
    n = 8000
    t = np.arange(1, n + 1) * m.tick_s
    x = np.empty(n)
    for k in range(n):
        servo_step(m, s, amp * math.cos(2 * math.pi * f * k * m.tick_s))
        x[k] = s.angle_deg
    steady = t > 4.0  # transients (decay time 1/(ζω_n) ≈ 0.09 s) long gone
    a = np.column_stack([np.cos(2 * np.pi * f * t[steady]), -np.sin(2 * np.pi * f * t[steady])])
    c, *_ = np.linalg.lstsq(a, x[steady], rcond=None)
    # the state after tick k (time (k+1)T) answers the target of index k+1 by H(z): no extra delay
    expected = amp * complex(m.response(f))
    assert complex(c[0], c[1]) == pytest.approx(expected, abs=1e-6)


def test_step_respects_rate_and_acceleration_limits() -> None:
    m = model(natural_freq_hz=8.0, damping=0.8, rate_limit_deg_s=10.0, accel_limit_deg_s2=50.0)
    s = AxisState()
    xs, vs = [], []
    for _ in range(5000):
        servo_step(m, s, 20.0)
        xs.append(s.angle_deg)
        vs.append(s.rate_deg_s)
    v = np.array(vs)
    assert np.max(np.abs(v)) <= 10.0 + 1e-12
    assert np.max(np.abs(np.diff(v))) / m.tick_s <= 50.0 + 1e-9
    assert xs[-1] == pytest.approx(20.0, abs=1e-3)


def test_brake_stops_at_the_acceleration_limit() -> None:
    m = model(accel_limit_deg_s2=50.0)
    s = AxisState(0.0, 10.0)
    ticks = 0
    while s.rate_deg_s != 0.0:
        brake_step(m, s)
        ticks += 1
    assert ticks == pytest.approx(10.0 / (50.0 * m.tick_s), abs=1)
    assert s.angle_deg == pytest.approx(10.0**2 / (2 * 50.0), rel=0.01)  # v²/2a


def test_quantise() -> None:
    assert quantise(1.23456, 0.001) == pytest.approx(1.235)
    assert quantise(-0.0004, 0.001) == 0.0
    assert quantise(1.23456, 0.0) == 1.23456


@pytest.mark.parametrize(
    ("x0", "v0"), [(10.0, 0.0), (-3.0, 5.0), (0.5, -15.0), (2.0, 12.0), (0.0, 0.0)]
)
def test_ramp_plan_stays_within_limits_and_ends_at_zero(x0: float, v0: float) -> None:
    rate, acc, dt = 16.0, 80.0, 0.01
    p = plan_ramp_to_zero(x0, v0, rate, acc, dt)
    x = np.concatenate([[x0], p, [0.0]])  # …then the stand holds at zero
    v = np.concatenate([[v0], np.diff(x) / dt])
    assert p[-1] == 0.0
    assert np.max(np.abs(v[1:])) <= max(rate, abs(v0)) + 1e-9
    assert np.max(np.abs(np.diff(v))) / dt <= acc * (1 + 1e-9)
    # no slower than a trapezoid at the limits by more than a few periods
    t_min = abs(x0) / rate + rate / acc + abs(v0) / acc
    assert len(p) * dt <= t_min + 0.2 + 2 * math.sqrt(abs(x0) / acc + 1e-12)


LIM = StandLimitsView(angle_deg=10.0, rate_deg_s=20.0, accel_deg_s2=100.0)


def table(freq: float, amp: float, fade: float = 1.0) -> HarmonicTable:
    return HarmonicTable(
        np.array([freq]),
        np.array([amp]),
        np.array([0.0]),
        duration_s=10.0,
        fade_in_s=fade,
        fade_out_s=fade,
    )


def test_check_table_passes_a_table_within_limits() -> None:
    check_table(table(0.5, 5.0), LIM, axis="roll", max_lines=64)  # 15.7°/s, 49°/s²


@pytest.mark.parametrize(
    ("tab", "what"),
    [
        (table(0.1, 11.0), "needs angle 11.0"),
        (table(1.0, 4.0), "needs rate 25.1"),  # 2π·4 = 25.1°/s
        (table(1.5, 2.0), "needs acceleration 1[78]"),  # (2π·1.5)²·2 = 177.7°/s² + the fades
        (table(0.1, 5.0, fade=0.01), "needs rate 78"),  # the fade itself is a jolt: 5·π/(2·0.01)
    ],
)
def test_check_table_names_needed_vs_allowed(tab: HarmonicTable, what: str) -> None:
    with pytest.raises(LimitError, match=what):
        check_table(tab, LIM, axis="roll", max_lines=64)


def test_check_table_line_count() -> None:
    with pytest.raises(LimitError, match="at most 0"):
        check_table(table(0.5, 1.0), LIM, axis="pitch", max_lines=0)
