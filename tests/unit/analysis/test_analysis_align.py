"""Alignment: the device's grid, gaps, jitter, the reference evaluated at device instants."""

from __future__ import annotations

import numpy as np
import pytest
from analysis_synthetic import Multisine, gain, orthogonal_noise

from benchctl.analysis import analyze
from benchctl.analysis.align import EDGE_STEPS, align, slot_indices
from benchctl.errors import DataError

MS = Multisine(period_s=100.0, f_lo=0.05, f_hi=0.6, rms_deg=5.0)


def test_slots_follow_jitter_and_drops() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(1000) * 0.01 * 1.0002 + 5.0 + rng.uniform(-0.003, 0.003, 1000)
    keep = np.ones(1000, dtype=bool)
    keep[[100, 500, 501, 502]] = False
    k, dt, t0 = slot_indices(t[keep])
    assert np.array_equal(k, np.flatnonzero(keep))
    assert dt == pytest.approx(0.010002, rel=1e-4)
    assert t0 == pytest.approx(5.0, abs=0.001)


def test_reference_is_evaluated_at_device_instants() -> None:
    rng = np.random.default_rng(2)
    tr = np.arange(0, 300, 0.01) + rng.uniform(-0.002, 0.002, 30000)  # 100 Hz
    td = np.arange(1, 299, 1 / 30) + rng.uniform(-0.004, 0.004, 8940)  # 30 Hz
    al = align(tr, MS.reference(tr), td, MS.reference(td))
    assert al.mask.all()
    assert np.max(np.abs(al.x - MS.reference(al.t))) < 1e-5  # cubic spline, 100 Hz, ≤ 0.6 Hz
    assert np.array_equal(al.y, MS.reference(td))  # device values untouched
    assert al.device.jitter_rms == pytest.approx(0.008 / np.sqrt(12), rel=0.1)


def test_device_samples_outside_or_in_reference_gaps_are_excluded() -> None:
    tr = np.arange(0, 100, 0.01)
    keep = (tr < 40) | (tr > 42)
    td = np.arange(-5, 105, 0.05)
    al = align(tr[keep], MS.reference(tr[keep]), td, MS.reference(td))
    lo, hi = tr[keep][tr[keep] < 40][-1], tr[keep][tr[keep] > 42][0]
    inside_gap = np.sum((td > lo) & (td < hi))
    edge = EDGE_STEPS * 0.01  # a hair past either end is read (the spline's end)
    outside = np.sum((td < -edge) | (td > tr[-1] + edge))
    assert al.excluded == inside_gap + outside
    assert np.any((td < 0) & (td >= -edge))  # −5 + 100·0.05 lands at −1.8e-15: kept
    assert al.reference.gap_count == 1
    assert al.reference.longest_gap_s == pytest.approx(2.02, abs=1e-6)


def test_fitted_timebase_removes_receipt_jitter() -> None:
    rng = np.random.default_rng(4)
    fs, n, sn = 20.0, 12000, 0.05
    t_true = np.arange(n) / fs  # the instrument samples on its own clock...
    t_recv = t_true + rng.uniform(-0.01, 0.01, n)  # ...but is stamped on receipt
    tr = np.arange(-100, n * 5 + 100) / 100.0
    y0 = MS.through(gain(0.98), t_true)
    y = y0 + orthogonal_noise(rng, sn, y0 - MS.reference(t_true))
    truth = np.sqrt(MS.error_variance(gain(0.98)) + sn**2)
    given = analyze(tr, MS.reference(tr), t_recv, y, timebase="given")
    fitted = analyze(tr, MS.reference(tr), t_recv, y, timebase="fitted")
    default = analyze(tr, MS.reference(tr), t_recv, y)  # the stamps' jitter seen: fitted
    assert fitted.sigma == pytest.approx(truth, rel=0.01)
    assert default.sigma == fitted.sigma
    assert default.timing["timebase_choice"]["device"]["used"] == "fitted"
    assert given.sigma > 1.05 * truth  # rate × jitter is added error
    assert fitted.timing["device_jitter_rms"] == pytest.approx(0.02 / np.sqrt(12), rel=0.1)


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda t, v: (t[::-1].copy(), v), "decreasing timestamp at sample 1"),
        (lambda t, v: (np.concatenate(([t[0]], t[:-1])), v), "duplicate timestamp at sample 1"),
        (lambda t, v: (t, np.where(np.arange(t.size) == 7, np.nan, v)), "value at sample 7"),
        (lambda t, v: (t, np.full_like(v, 1.5)), "constant"),
        (lambda t, v: (t[:10], v[:10]), "at least 64"),
        (lambda t, v: (t + 1000.0, v), "do not overlap"),
    ],
)
def test_bad_device_stream(mutate, match: str) -> None:
    t = np.arange(0, 100, 0.05)
    v = MS.reference(t)
    td, yd = mutate(t, v)
    with pytest.raises(DataError, match=match):
        analyze(t, v, td, yd)


def test_record_too_short_for_lag_or_band() -> None:
    t = np.arange(0, 30, 0.05)
    x = MS.reference(t)
    with pytest.raises(DataError, match="too short for the band"):
        analyze(t, x, t, 0.99 * x, band_hz=(0.05, 0.5))
    with pytest.raises(DataError, match="record too short"):
        analyze(t, x, t, 0.99 * x, max_lag_s=20.0)
    with pytest.raises(DataError, match="fs/2"):
        analyze(t, x, t, 0.99 * x, band_hz=(0.1, 50.0))
    with pytest.raises(DataError, match=r"narrower than the (record.s )?resolution"):
        analyze(t, x, t, 0.99 * x, band_hz=(0.2, 0.21))


def test_bursts_of_late_receipts_fake_no_drop() -> None:
    t = np.arange(5000) * 0.01
    late = t.copy()
    late[100:103] = late[103] + np.array([1e-4, 2e-4, 3e-4])  # three held back, then a burst
    late[2000] += 0.0045  # one very late, within dt/2
    k, dt, _ = slot_indices(late)
    assert np.array_equal(k, np.arange(5000))
    assert dt == pytest.approx(0.01, rel=1e-5)


def test_wandering_clock_is_followed() -> None:
    n = 100_000  # 1000 s at 100 Hz, clock wandering by ±15 ms (1.5 dt) over the record
    i = np.arange(n)
    t = i * 0.01 + 0.015 * np.sin(2 * np.pi * i / n)
    keep = np.ones(n, dtype=bool)
    keep[[10, 50_000, 50_001, 99_000]] = False
    k, _, _ = slot_indices(t[keep])
    assert np.array_equal(k, np.flatnonzero(keep) - 0)


@pytest.mark.parametrize("jitter", [0.2, 0.35])
def test_heavy_jitter_with_random_drops(jitter: float) -> None:
    rng = np.random.default_rng(8)
    n = 20000
    t = np.arange(n) * 0.01 + rng.uniform(-jitter, jitter, n) * 0.01
    keep = rng.random(n) > 0.01
    k, _, _ = slot_indices(t[keep])
    expected = np.flatnonzero(keep)
    assert np.array_equal(k, expected - expected[0])


def test_short_reference_gaps_are_bridged_and_reported() -> None:
    tr = np.arange(0, 100, 0.01)
    keep = np.ones(tr.size, dtype=bool)
    keep[[1000, 3000, 3001, 3002, 5000, 5001, 5002, 5003]] = False  # 1, 3 and 4 missing
    keep[7000:7030] = False  # 0.3 s: a host stall
    td = np.arange(0.5, 99.5, 0.02)
    al = align(tr[keep], MS.reference(tr[keep]), td, MS.reference(td))
    assert al.reference.gap_count == 4 and al.reference.missing_samples == 38
    # the 1- and 3-sample holes are bridged (error far below 1e-4 deg); the longer ones too:
    # across such spans the spline misses the left-out samples of this smooth motion by far
    # less than 1 % of its rms, and that error is stated
    assert al.excluded == 0
    in_long = np.sum((td > tr[4999]) & (td < tr[5004])) + np.sum((td > tr[6999]) & (td < tr[7030]))
    assert al.bridged == in_long > 0
    miss = al.x[al.mask] - MS.reference(al.t[al.mask])
    stall = (al.t[al.mask] > tr[6999]) & (al.t[al.mask] < tr[7030])
    assert np.max(np.abs(miss[~stall])) < 1e-4
    # the stated error of the bridged samples (as a variance over all samples) is the real one
    # within a factor 3, and tiny: 0.3 s of a 0.6 Hz motion of 5° rms
    actual = float(np.sum(miss[stall] ** 2) / miss.size)
    assert actual / 3 < al.bridge_variance < 3 * actual
    assert al.bridge_variance < 1e-6


def test_reference_gaps_the_spline_cannot_bridge_exclude_samples() -> None:
    """A gap longer than 2 s, or one across which the spline misses the motion by more than
    1 % of its rms (rms over the places tried; here a noisy reference), masks the device
    samples in it."""
    rng = np.random.default_rng(3)
    tr = np.arange(0, 100, 0.01)
    keep = np.ones(tr.size, dtype=bool)
    keep[2000:2300] = False  # 3 s
    keep[6000:6030] = False  # 0.3 s
    td = np.arange(0.5, 99.5, 0.02)
    al = align(tr[keep], MS.reference(tr[keep]), td, MS.reference(td))
    assert al.excluded == np.sum((td > tr[1999]) & (td < tr[2300])) and al.bridged == 15
    noisy = MS.reference(tr) + rng.normal(0, 0.2, tr.size)  # 4 % of the motion's rms
    al = align(tr[keep], noisy[keep], td, MS.reference(td))
    assert al.bridged == 0
    assert al.excluded == np.sum((td > tr[1999]) & (td < tr[2300])) + np.sum(
        (td > tr[5999]) & (td < tr[6030]))
