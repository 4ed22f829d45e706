"""Multisine synthesis: variance, periodogram, fast sampling, phases, crest factor, fades."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate

from benchctl.harmonics import HarmonicTable
from benchctl.profiles import parse_profile, roll, synthesize
from benchctl.profiles.synthesis import (
    crest_factor,
    design_lines,
    evaluate_table,
    line_harmonics,
    periodogram_lines,
    random_phases,
    reduce_crest,
    sample_times,
)

ALPHA, BETA = roll.exp_cos_parameters(6.0, 0.2)


def g_expcos(f: np.ndarray) -> np.ndarray:
    return roll.exp_cos_psd(f, 3.0, ALPHA, BETA)


def quad_band(density, lo: float, hi: float) -> float:  # type: ignore[no-untyped-def]
    return integrate.quad(lambda f: float(density(np.array([f]))[0]), lo, hi, limit=400)[0]


def expcos_profile(**over: object) -> dict[str, object]:
    d: dict[str, object] = {
        "name": "t",
        "kind": "roll_spectrum",
        "duration_s": 210,
        "fade_in_s": 5,
        "fade_out_s": 5,
        "seed": 11,
        "band_hz": [0.1, 0.3334],
        "axes": {"roll": {"model": "exp_cos", "sigma_deg": 3.0, "period_s": 6.0, "damping": 0.2}},
    }
    d.update(over)
    return d


def test_lines_are_on_k_over_tp_inside_the_band() -> None:
    k = line_harmonics((0.1, 0.3334), 200.0)
    assert k[0] == 20 and k[-1] == 66
    d = design_lines(g_expcos, (0.1, 0.3334), 200.0)
    np.testing.assert_allclose(d.freq_hz, k / 200.0)


def test_cell_amplitudes_hold_the_band_variance() -> None:
    d = design_lines(g_expcos, (0.1, 0.3334), 50.0, method="cell")
    exact = quad_band(g_expcos, 0.1, 0.3334)
    assert d.variance_deg2 == pytest.approx(exact, rel=1e-4)
    assert d.target_variance_deg2 == pytest.approx(exact, rel=1e-4)


def test_point_amplitudes_follow_the_textbook_rule() -> None:
    d = design_lines(g_expcos, (0.1, 0.3334), 880.0, method="point")
    np.testing.assert_allclose(d.amp_deg, np.sqrt(2 * g_expcos(d.freq_hz) / 880.0), rtol=1e-12)
    # with a fine spacing the Riemann sum is within 0.5 % of the band integral
    assert d.variance_deg2 == pytest.approx(quad_band(g_expcos, 0.1, 0.3334), rel=0.005)


@pytest.mark.parametrize("amplitudes", ["cell", "point"])
def test_synthesised_variance_equals_band_integral(amplitudes: str) -> None:
    prof = parse_profile(expcos_profile(duration_s=610, amplitudes=amplitudes))
    motion = synthesize(prof)
    tab = motion.tables["roll"]
    rate = 20.0
    t = 5.0 + np.arange(round(600 * rate)) / rate  # the steady part: one whole period T_p = 600 s
    x = motion.evaluate(t)["roll"]
    exact = quad_band(g_expcos, 0.1, 0.3334)
    assert tab.period_s == pytest.approx(600.0)
    assert np.mean(x**2) == pytest.approx(exact, rel=0.005)


def test_sea_state_motion_variance_equals_band_integral() -> None:
    from benchctl.profiles import spectra

    data = {
        "name": "s",
        "kind": "sea_state",
        "duration_s": 420,
        "fade_in_s": 10,
        "fade_out_s": 10,
        "seed": 5,
        "band_hz": [0.05, 0.5],
        "sea": {"spectrum": "jonswap", "hs_m": 2.0, "tp_s": 8.0, "gamma": 3.3},
        "axes": {
            "roll": {"natural_period_s": 6.0, "damping_ratio": 0.15, "slope_coefficient": 0.6}
        },
    }
    motion = synthesize(parse_profile(data))
    t = 10.0 + np.arange(400 * 10) / 10.0
    x = motion.evaluate(t)["roll"]

    def g(f: np.ndarray) -> np.ndarray:
        return roll.roll_response_psd(f, spectra.jonswap(f, 2.0, 8.0, 3.3), 6.0, 0.15, 0.6)

    exact = sum(
        quad_band(g, a, b) for a, b in ((0.05, 1 / 6.5), (1 / 6.5, 1 / 5.5), (1 / 5.5, 0.5))
    )
    assert np.mean(x**2) == pytest.approx(exact, rel=0.005)


def test_periodogram_over_whole_periods_returns_line_variances() -> None:
    motion = synthesize(parse_profile(expcos_profile(duration_s=130, fade_in_s=5, fade_out_s=5)))
    tab = motion.tables["roll"]
    assert tab.period_s == pytest.approx(120.0)
    rate = 10.0
    for periods in (1, 3):
        t = np.arange(round(periods * 120 * rate)) / rate
        x = tab.steady(t)
        k = np.round(tab.freq_hz * tab.period_s).astype(np.int64)
        np.testing.assert_allclose(periodogram_lines(x, k, periods), tab.amp_deg**2 / 2, rtol=1e-9)
        # nothing leaks to the bins between lines
        spec = np.abs(np.fft.rfft(x)) ** 2 * 2 / x.size**2
        off = np.setdiff1d(np.arange(1, spec.size), k * periods)
        assert spec[off].max() < 1e-20 * spec.max() + 1e-24


@pytest.mark.parametrize("rate", [100.0, 1000.0, 137.0])
@pytest.mark.parametrize("derivative", [0, 1, 2])
def test_fast_sampling_equals_direct_sum(rate: float, derivative: int) -> None:
    motion = synthesize(parse_profile(expcos_profile()))
    tab = motion.tables["roll"]
    t = sample_times(motion.duration_s, rate)[:20000]
    fast = evaluate_table(tab, t, derivative)
    direct = tab.evaluate(t, derivative)
    scale = np.max(np.abs(direct))
    np.testing.assert_allclose(fast, direct, rtol=0, atol=1e-9 * scale)


def test_fast_sampling_on_an_offset_window_and_outside_the_motion() -> None:
    motion = synthesize(parse_profile(expcos_profile()))
    tab = motion.tables["roll"]
    t = (np.arange(5000) + 19_000) / 100.0  # 190 s … 240 s: crosses the end at 210 s
    np.testing.assert_allclose(evaluate_table(tab, t), tab.evaluate(t), atol=1e-9)
    assert np.all(evaluate_table(tab, t)[t > 210.0] == 0.0)


def test_same_seed_same_phases_other_seed_other_phases_same_spectrum() -> None:
    a = synthesize(parse_profile(expcos_profile()))
    b = synthesize(parse_profile(expcos_profile()))
    c = synthesize(parse_profile(expcos_profile()), seed=12)
    ta, tb, tc = a.tables["roll"], b.tables["roll"], c.tables["roll"]
    assert np.array_equal(ta.phase_rad, tb.phase_rad)
    assert not np.allclose(ta.phase_rad, tc.phase_rad)
    np.testing.assert_array_equal(ta.amp_deg, tc.amp_deg)
    np.testing.assert_array_equal(ta.freq_hz, tc.freq_hz)


def test_phases_are_uniform_and_axes_independent() -> None:
    p = random_phases(20000, 3, 0)
    q = random_phases(20000, 3, 1)
    assert p.min() >= 0 and p.max() < 2 * np.pi
    assert abs(np.mean(np.exp(1j * p))) < 0.03  # uniform phases: mean phasor ~ 1/√n
    assert abs(np.mean(np.exp(1j * (p - q)))) < 0.03


def test_two_axis_profile_has_independent_phases() -> None:
    d = expcos_profile()
    d["axes"] = {
        "roll": {"model": "exp_cos", "sigma_deg": 3.0, "period_s": 6.0, "damping": 0.2},
        "pitch": {"model": "exp_cos", "sigma_deg": 3.0, "period_s": 6.0, "damping": 0.2},
    }
    m = synthesize(parse_profile(d))
    roll_only = synthesize(parse_profile(expcos_profile()))
    assert m.axes == ("roll", "pitch")
    np.testing.assert_array_equal(m.tables["roll"].amp_deg, m.tables["pitch"].amp_deg)
    assert not np.allclose(m.tables["roll"].phase_rad, m.tables["pitch"].phase_rad)
    np.testing.assert_array_equal(m.tables["roll"].phase_rad, roll_only.tables["roll"].phase_rad)


def test_crest_factor_of_one_sine_is_root_two() -> None:
    assert crest_factor([3], [2.0], [0.4]) == pytest.approx(math.sqrt(2), rel=1e-3)


@pytest.mark.parametrize("method", ["clip", "schroeder"])
def test_crest_reduction_lowers_crest_and_keeps_the_spectrum(method: str) -> None:
    k = np.arange(10, 110)
    amp = np.ones(k.size)
    phase = random_phases(k.size, 1)
    new, report = reduce_crest(k, amp, phase, method, iterations=60)
    assert report.crest_before == pytest.approx(crest_factor(k, amp, phase))
    assert report.crest_after == pytest.approx(crest_factor(k, amp, new))
    assert report.crest_after < 0.75 * report.crest_before
    assert report.crest_after < 2.0  # a flat 100-line multisine: random ~3-4, optimised < 2
    n = 4096
    x = np.zeros(n)
    tt = np.arange(n) / n
    for kk, ph in zip(k, new, strict=True):
        x += np.cos(2 * np.pi * kk * tt + ph)
    np.testing.assert_allclose(periodogram_lines(x, k), amp**2 / 2, rtol=1e-9)


def test_crest_reduction_in_a_profile_is_reported() -> None:
    m = synthesize(parse_profile(expcos_profile(crest={"method": "clip", "iterations": 30})))
    s = m.summary()["per_axis"]["roll"]  # type: ignore[index]
    assert s["crest"]["method"] == "clip"
    assert s["crest"]["crest_after"] < s["crest"]["crest_before"]


def test_motion_fades_from_and_to_rest() -> None:
    m = synthesize(parse_profile(expcos_profile()))
    ends = np.array([0.0, m.duration_s])
    for d in (0, 1):
        np.testing.assert_allclose(m.evaluate(ends, d)["roll"], 0.0, atol=1e-12)
    outside = np.array([-1.0, m.duration_s + 1.0])
    for d in (0, 1, 2):
        assert np.all(m.evaluate(outside, d)["roll"] == 0.0)


@pytest.mark.parametrize(("duration", "n_periods"), [(120.0, 1), (610.0, 3), (900.0, 4)])
def test_duration_override_keeps_whole_periods(duration: float, n_periods: int) -> None:
    prof = parse_profile(expcos_profile(repeat_period_s=200.0))
    m = synthesize(prof, duration_s=duration)
    tab = m.tables["roll"]
    steady = duration - 10.0
    assert tab.duration_s == duration
    assert steady / tab.period_s == pytest.approx(n_periods)
    np.testing.assert_allclose(
        tab.freq_hz * tab.period_s, np.round(tab.freq_hz * tab.period_s), atol=1e-9
    )


def test_sine_profile_is_one_line() -> None:
    data = {
        "name": "s",
        "kind": "sine",
        "duration_s": 60,
        "seed": 0,
        "axes": {"roll": {"amplitude_deg": 5.0, "period_s": 5.0, "phase_deg": 90}},
    }
    m = synthesize(parse_profile(data))
    tab = m.tables["roll"]
    t = np.array([10.0, 11.25, 30.0])
    np.testing.assert_allclose(
        m.evaluate(t)["roll"], 5 * np.cos(2 * np.pi * t / 5 + np.pi / 2), atol=1e-12
    )
    assert tab.n_lines == 1 and tab.period_s == 5.0


def test_harmonics_profile_uses_given_and_seeded_phases() -> None:
    data = {
        "name": "h",
        "kind": "harmonics",
        "duration_s": 132,
        "fade_in_s": 6,
        "fade_out_s": 6,
        "seed": 3,
        "repeat_period_s": 24,
        "axes": {
            "roll": {
                "lines": [
                    {"amplitude_deg": 3.0, "period_s": 8.0, "phase_deg": 0},
                    {"amplitude_deg": 4.0, "freq_hz": 0.25},
                ]
            }
        },
    }
    tab = synthesize(parse_profile(data)).tables["roll"]
    np.testing.assert_allclose(tab.freq_hz, [0.125, 0.25])
    assert tab.phase_rad[0] == 0.0
    assert tab.phase_rad[1] == random_phases(2, 3, 0)[1]
    t = np.array([50.0, 60.5])
    expected = 3 * np.cos(2 * np.pi * t / 8) + 4 * np.cos(2 * np.pi * 0.25 * t + tab.phase_rad[1])
    np.testing.assert_allclose(tab.evaluate(t), expected, atol=1e-12)


def test_harmonic_table_csv_round_trip() -> None:
    import csv
    import io

    from benchctl.profiles import tables_to_csv

    m = synthesize(parse_profile(expcos_profile()))
    text = tables_to_csv(m.tables)
    rows = list(csv.DictReader(line for line in io.StringIO(text) if not line.startswith("#")))
    tab = m.tables["roll"]
    rebuilt = HarmonicTable(
        np.array([float(r["freq_hz"]) for r in rows]),
        np.array([float(r["amplitude_deg"]) for r in rows]),
        np.array([float(r["phase_rad"]) for r in rows]),
        tab.duration_s,
        tab.fade_in_s,
        tab.fade_out_s,
    )
    np.testing.assert_array_equal(rebuilt.amp_deg, tab.amp_deg)
    np.testing.assert_array_equal(rebuilt.phase_rad, tab.phase_rad)
    assert f"period_s={tab.period_s!r}" in text


def test_fast_path_is_taken_on_whole_period_grids_and_not_otherwise(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    motion = synthesize(parse_profile(expcos_profile()))
    tab = motion.tables["roll"]
    calls: list[int] = []
    original = HarmonicTable.steady

    def spy(self: HarmonicTable, t_s: object, derivative: int = 0) -> np.ndarray:
        calls.append(derivative)
        return original(self, t_s, derivative)  # type: ignore[arg-type]

    monkeypatch.setattr(HarmonicTable, "steady", spy)
    evaluate_table(tab, sample_times(210.0, 1000.0), 2)  # 200 s x 1000 Hz: integer → FFT tiling
    assert calls == []
    t = sample_times(210.0, 10 * math.pi)  # 200 s x 31.4… Hz is not an integer → direct sum
    evaluate_table(tab, t, 0)
    assert calls == [0]
