"""Checks before motion: peaks measured on the samples, refusal with figures, scale-to-fit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchctl.config import StandLimits
from benchctl.errors import LimitError
from benchctl.profiles import check_motion, measure_peaks, parse_profile, sample_times, synthesize

WIDE = StandLimits(angle_deg=90, rate_deg_s=500, accel_deg_s2=5000)


def motion(sigma: float = 3.0, duration: float = 210.0, **over: object):  # type: ignore[no-untyped-def]
    d: dict[str, object] = {
        "name": "m",
        "kind": "roll_spectrum",
        "duration_s": duration,
        "fade_in_s": 5,
        "fade_out_s": 5,
        "seed": 8,
        "band_hz": [0.1, 0.5],
        "axes": {"roll": {"model": "exp_cos", "sigma_deg": sigma, "period_s": 5.0, "damping": 0.2}},
    }
    d.update(over)
    return synthesize(parse_profile(d))


@pytest.mark.parametrize("rate", [50.0, 200.0])
def test_reported_peaks_equal_those_measured_on_the_samples(rate: float) -> None:
    m = motion()
    check = check_motion(m, WIDE, rate_hz=rate)
    tab = m.tables["roll"]
    t = sample_times(m.duration_s, rate)
    # measured independently: the direct (slow) sum of the harmonic table on the same grid
    for d, attr in ((0, "angle_deg"), (1, "rate_deg_s"), (2, "accel_deg_s2")):
        measured = float(np.max(np.abs(tab.evaluate(t, d))))
        assert getattr(check.peaks["roll"], attr) == pytest.approx(measured, rel=1e-9)


def test_peak_rate_and_acceleration_agree_with_finite_differences() -> None:
    m = motion()
    rate = 1000.0
    t = sample_times(m.duration_s, rate)
    x = m.evaluate(t)["roll"]
    peaks = measure_peaks(m, rate)["roll"]
    v = np.diff(x) * rate
    a = np.diff(x, 2) * rate**2
    assert peaks.rate_deg_s == pytest.approx(np.max(np.abs(v)), rel=2e-3)
    assert peaks.accel_deg_s2 == pytest.approx(np.max(np.abs(a)), rel=2e-3)


def test_peak_rate_is_below_the_line_sum_bound() -> None:
    m = motion()
    tab = m.tables["roll"]
    bound = float(np.sum(2 * np.pi * tab.freq_hz * tab.amp_deg))
    fades = np.pi / (2 * 5.0) * float(np.sum(tab.amp_deg))  # e'·|x| during the fades
    assert measure_peaks(m, 100.0)["roll"].rate_deg_s <= bound + fades
    assert m.summary()["per_axis"]["roll"]["rate_bound_deg_s"] == pytest.approx(bound)  # type: ignore[index]


def test_over_the_limits_is_refused_with_needed_and_allowed() -> None:
    m = motion(sigma=8.0)
    peaks = measure_peaks(m, 100.0)["roll"]
    limits = StandLimits(angle_deg=20, rate_deg_s=15, accel_deg_s2=500)
    assert peaks.angle_deg > 20 and peaks.rate_deg_s > 15
    with pytest.raises(LimitError) as exc:
        check_motion(m, limits, rate_hz=100.0)
    msg = str(exc.value)
    assert f"peak angle needed {peaks.angle_deg:.3f} deg, allowed 20.000 deg" in msg
    assert f"peak rate needed {peaks.rate_deg_s:.3f} deg/s, allowed 15.000 deg/s" in msg
    assert "acceleration" not in msg


def test_scale_to_fit_reports_the_factor_and_fits() -> None:
    m = motion(sigma=8.0)
    peaks = measure_peaks(m, 100.0)["roll"]
    limits = StandLimits(angle_deg=20, rate_deg_s=15, accel_deg_s2=500)
    check = check_motion(m, limits, scale_to_fit=True, rate_hz=100.0)
    need = min(20 / peaks.angle_deg, 15 / peaks.rate_deg_s)
    assert check.scale <= need and check.scale == pytest.approx(need, rel=1e-3)
    p = check.peaks["roll"]
    assert p.angle_deg <= 20 and p.rate_deg_s <= 15 and p.accel_deg_s2 <= 500
    assert p.angle_deg == pytest.approx(check.scale * peaks.angle_deg, rel=1e-12)
    assert check.unscaled_peaks["roll"] == peaks
    s = check.motion.summary()
    assert s["scale"] == check.scale
    pa = s["per_axis"]["roll"]  # type: ignore[index]
    assert pa["sigma_deg"] == pytest.approx(check.scale * math.sqrt(m.tables["roll"].variance_deg2))
    assert pa["variance_error"] == pytest.approx(0.0, abs=1e-6)  # target scaled alike


def test_within_limits_returns_the_motion_unscaled() -> None:
    m = motion()
    check = check_motion(m, WIDE, rate_hz=100.0)
    assert check.scale == 1.0 and check.motion is m


def test_two_axes_are_checked_each_against_the_per_axis_limits() -> None:
    d = {
        "axes": {
            "roll": {"model": "exp_cos", "sigma_deg": 1.0, "period_s": 5.0, "damping": 0.2},
            "pitch": {"model": "exp_cos", "sigma_deg": 6.0, "period_s": 5.0, "damping": 0.2},
        }
    }
    m = motion(**d)
    peaks = measure_peaks(m, 100.0)
    limit = (peaks["roll"].angle_deg + peaks["pitch"].angle_deg) / 2
    with pytest.raises(LimitError, match="axis pitch: peak angle") as exc:
        check_motion(m, StandLimits(angle_deg=limit, rate_deg_s=500, accel_deg_s2=5000))
    assert "axis roll" not in str(exc.value)


def test_sine_steps_are_checked_too() -> None:
    data = {
        "name": "steps",
        "kind": "sine_steps",
        "seed": 0,
        "axes": ["roll"],
        "periods_s": [3.0, 10.0],
        "amplitudes_deg": [10.0],
        "cycles": 3,
        "fade_cycles": 2,
        "rest_s": 1,
    }
    m = synthesize(parse_profile(data))
    p = measure_peaks(m, 1000.0)["roll"]
    assert p.angle_deg == pytest.approx(10.0, rel=1e-6)
    assert p.rate_deg_s == pytest.approx(2 * np.pi / 3 * 10, rel=1e-4)
    with pytest.raises(LimitError, match=r"peak rate needed 20\.944 deg/s, allowed 20\.000 deg/s"):
        check_motion(m, StandLimits(angle_deg=30, rate_deg_s=20, accel_deg_s2=500), rate_hz=1000.0)
    scaled = check_motion(
        m,
        StandLimits(angle_deg=30, rate_deg_s=20, accel_deg_s2=500),
        scale_to_fit=True,
        rate_hz=1000.0,
    )
    assert scaled.peaks["roll"].rate_deg_s <= 20 and scaled.motion.tables is None
