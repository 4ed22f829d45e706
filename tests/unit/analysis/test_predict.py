"""Prediction of σ under another motion (``benchctl.analysis.predict``, ``benchctl predict``):
synthetic instruments of known response measured line-wise with one multisine, predicted for
another, against the closed form ``Σ|H(f_j) − 1|²A_j²/2 + σ_n²``.

Tolerances: noise-free, the prediction is exact on the measured lines (1e-9) and within its
stated interpolation bound between them; with white noise, one long record is within 1 % of
the closed form in σ, and the 95 % interval covers it in 0.95 ± 0.03 of 400 records.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from predict_cases import NOISE, PROFILE_A, PROFILE_B, closed_form, lag_response
from repo_paths import ROOT

from benchctl.analysis.lines import LineSet
from benchctl.analysis.linewise import analyze_lines
from benchctl.analysis.predict import (
    MeasuredResponse,
    NoisePart,
    dof_from_interval,
    noise_from_lines,
    predict,
    response_from_lines,
)
from benchctl.cli import main
from benchctl.errors import DataError
from benchctl.profiles import load_profile, synthesize


def measure(
    noise_deg: float, *, seed: int = 1, fs: float = 10.0, tp: float = 40.0, n_periods: int = 3,
    harmonics: np.ndarray | None = None, weak: int = 0,
) -> tuple[object, np.ndarray]:
    """Line-wise analysis of a flat-ish multisine (lines k/tp) through ``lag_response`` plus
    white noise; returns it and the measured lines' frequencies. ``weak``: the lowest lines
    this many are 1e-8° high (a profile's band edge)."""
    k = np.arange(1, 25) if harmonics is None else harmonics
    f = k / tp
    rng = np.random.default_rng(seed)
    amp = 2.0 * np.exp(-(((f - 0.17) / 0.15) ** 2)) + 0.3
    amp[:weak] = 1e-8
    ph = rng.uniform(0, 2 * np.pi, k.size)
    n = round(fs * tp * n_periods)
    t = np.arange(n) / fs
    arg = 2 * np.pi * f[:, None] * t + ph[:, None]
    h = lag_response(f)
    x = (amp[:, None] * np.cos(arg)).sum(0)
    y = (amp[:, None] * np.abs(h)[:, None] * np.cos(arg + np.angle(h)[:, None])).sum(0)
    y = y + rng.normal(0.0, noise_deg, n) if noise_deg > 0 else y
    la = analyze_lines(x, y, np.ones(n, dtype=bool), 1 / fs, LineSet(tp, k, "period"))
    return la, f


def sea_state_lines() -> tuple[np.ndarray, np.ndarray]:
    """The lines of sea_state_4_small_vessel at 50 s (k/30 s over 0.067 … 0.5 Hz)."""
    tab = synthesize(load_profile(ROOT / "profiles/sea_state_4_small_vessel.yaml"),
                     duration_s=50.0).tables["roll"]  # type: ignore[index]
    return np.asarray(tab.freq_hz), np.asarray(tab.amp_deg)


# ------------------------------------------------------------------------------ exact cases
def test_noise_free_exact_on_lines_and_within_the_interpolation_bound() -> None:
    la, f = measure(0.0)
    resp, noise = response_from_lines(la), noise_from_lines(la)  # type: ignore[arg-type]
    # target lines on the measured lines: exact
    on = f[3:17:2]
    amp = np.linspace(0.5, 2.0, on.size)
    p = predict(resp, noise, on, amp)
    assert p.interpolation_bound == 0.0
    assert p.variance == pytest.approx(closed_form(on, amp, 0.0), rel=1e-9)
    # a sea state's lines k/30 s between the lines k/40 s: within the stated bound, which is small
    fb, ab = sea_state_lines()
    p = predict(resp, noise, fb, ab)
    truth = closed_form(fb, ab, 0.0)
    assert p.outside_share == 0.0 and p.n_inside == fb.size == 14
    assert abs(p.variance - truth) <= p.interpolation_bound
    assert 0 < p.interpolation_bound < 1e-3 * truth
    lo, hi = p.variance_ci95
    assert lo <= truth <= hi and p.sigma == pytest.approx(math.sqrt(truth), rel=1e-4)


def test_lag_and_white_noise_against_the_closed_form() -> None:
    noise = 0.05
    la, _ = measure(noise, n_periods=6)
    fb, ab = sea_state_lines()
    p = predict(response_from_lines(la), noise_from_lines(la), fb, ab)  # type: ignore[arg-type]
    truth = closed_form(fb, ab, noise)
    assert p.sigma == pytest.approx(math.sqrt(truth), rel=0.01)
    assert p.sigma_ci95[0] <= math.sqrt(truth) <= p.sigma_ci95[1]
    assert p.noise == pytest.approx(noise**2, rel=0.1)  # the record's incoherent part
    assert p.noise_ci95[0] <= noise**2 <= p.noise_ci95[1]
    assert p.linear == pytest.approx(truth - noise**2, rel=0.02)
    assert p.linear_ci95[0] <= truth - noise**2 <= p.linear_ci95[1]


def test_interval_coverage() -> None:
    """The 95 % interval of σ² covers the closed form in 0.95 ± 0.03 of 400 noisy records
    (two periods of 40 s at 5 Hz, white noise 0.3°: the noise and the line estimates' errors
    both matter)."""
    noise = 0.3
    fb, ab = sea_state_lines()
    truth = closed_form(fb, ab, noise)
    hits, errs = 0, []
    for r in range(400):
        la, _ = measure(noise, seed=100 + r, fs=5.0, n_periods=2)
        p = predict(response_from_lines(la), noise_from_lines(la), fb, ab)  # type: ignore[arg-type]
        hits += p.variance_ci95[0] <= truth <= p.variance_ci95[1]
        errs.append(p.variance / truth - 1)
    assert 0.92 <= hits / 400 <= 0.98, hits / 400
    assert abs(float(np.mean(errs))) < 3 * float(np.std(errs)) / math.sqrt(400)  # unbiased


def test_outside_band_share_exact() -> None:
    la, f = measure(0.0)
    resp, noise = response_from_lines(la), noise_from_lines(la)  # type: ignore[arg-type]
    lo_band, hi_band = f[0], f[-1]  # 0.025 … 0.6 Hz
    ft = np.array([0.01, 0.02, 0.1, 0.2, 0.3, 0.7, 1.0])
    at = np.array([1.0, 2.0, 3.0, 2.0, 1.0, 0.5, 0.25])
    p = predict(resp, noise, ft, at)
    inside = (ft >= lo_band) & (ft <= hi_band)
    out_var = float(np.sum(at[~inside] ** 2 / 2))
    assert p.inside.tolist() == inside.tolist()
    assert p.outside_variance == pytest.approx(out_var, rel=1e-12)
    assert p.outside_share == pytest.approx(out_var / float(np.sum(at**2 / 2)), rel=1e-12)
    assert p.tested_band_hz == pytest.approx((lo_band, hi_band))
    # σ holds the inside lines only; the bound adds the outside variance whole
    assert p.variance == pytest.approx(closed_form(ft[inside], at[inside], 0.0),
                                       abs=p.interpolation_bound + 1e-12)
    assert p.sigma_outside_bound == pytest.approx(math.sqrt(p.variance + out_var))
    assert np.all(np.isnan(p.error_gain[~inside])) and np.all(p.contribution[~inside] == 0)
    # the outside lines hold 2.8 of 10.1 deg²: σ is only bounded, the bands named; below the
    # band |1 − H| at most as at the lowest line (noise-free: exactly it), above it 1
    b_low = abs(complex(lag_response(np.array([f[0]]))[0]) - 1.0)
    extra = b_low**2 * (1.0**2 + 2.0**2) / 2 + (0.5**2 + 0.25**2) / 2
    assert p.bounded and p.sigma_bound == pytest.approx(
        math.sqrt(p.variance_ci95[1] + extra), rel=1e-9)
    truth = closed_form(ft, at, 0.0)
    assert p.sigma_bound >= math.sqrt(truth)
    assert p.outside_bands_hz == [(0.01, 0.02, 2), (0.7, 1.0, 2)]
    assert any("σ not predicted, only bounded" in w and "0.01 … 0.02 Hz (2 lines)" in w
               for w in p.warnings)


def test_weak_lines_are_reported_but_not_used() -> None:
    """A recording whose band-edge lines are 1e-8° high (as a sea-state profile's are) measures
    nothing there: their SNR is reported, they are not in the gain table, and a heavier
    motion there is bounded, never multiplied by their noise-made gains."""
    from benchctl.analysis.lineperiods import periods_from_lines
    from benchctl.analysis.linewise import SNR_FLOOR

    la, f = measure(0.01, weak=3)
    assert la.reliable.tolist() == [False] * 3 + [True] * 21  # type: ignore[attr-defined]
    assert np.all(la.snr[:3] < 1e-6) and np.all(la.snr[3:] > 1e4)  # type: ignore[attr-defined]
    # the linear part is the reliable lines' (within the noise), not the weak lines' noise
    strong = (f >= f[3])
    amp = 2.0 * np.exp(-(((f - 0.17) / 0.15) ** 2)) + 0.3
    lin_true = float(np.sum(np.abs(lag_response(f[strong]) - 1) ** 2 * amp[strong] ** 2 / 2))
    lo, hi = la.linear_ci95  # type: ignore[attr-defined]
    assert lo <= lin_true <= hi
    # the gain table: a period on a weak line is not measured, and says why
    table = periods_from_lines(la, (20.0, 10.0))  # type: ignore[arg-type]
    assert table[0]["excited"] is False and "below 10: not measured reliably" in table[0]["note"]
    assert table[1]["excited"] is True
    # a heavier sea with real motion at the weak lines' frequencies
    ft = np.concatenate((f[:3], f[8:12]))
    at = np.concatenate((np.full(3, 5.0), np.full(4, 1.0)))
    p = predict(response_from_lines(la), noise_from_lines(la), ft, at)  # type: ignore[arg-type]
    truth = closed_form(ft, at, 0.01)
    assert p.weak_lines_hz == pytest.approx(f[:3].tolist())
    assert p.inside.tolist() == [False] * 3 + [True] * 4
    assert p.bounded and p.sigma_bound >= math.sqrt(truth)
    assert p.to_dict()["sigma"] is None
    inside = closed_form(ft[3:], at[3:], 0.01)
    assert p.sigma == pytest.approx(math.sqrt(inside), rel=0.02)
    assert p.outside_bands_hz == [(f[0], f[2], 3)]
    assert any(f"SNR below {SNR_FLOOR:g}" in w for w in p.warnings)
    # every line weak: no prediction at all
    flat = response_from_lines(la)  # type: ignore[arg-type]
    none = MeasuredResponse(flat.freq, flat.harmonics, flat.h, np.full(24, 1.0), flat.dof)
    with pytest.raises(DataError, match="none of its 24 lines was measured reliably"):
        predict(none, noise_from_lines(la), ft, at)  # type: ignore[arg-type]


def test_holes_in_the_measured_lines_are_not_bridged() -> None:
    # lines 1 … 5 and 12 … 24 of 40 s: the hole 0.125 … 0.3 Hz is untested
    k = np.concatenate((np.arange(1, 6), np.arange(12, 25)))
    la, _ = measure(0.0, harmonics=k)
    p = predict(response_from_lines(la), noise_from_lines(la),  # type: ignore[arg-type]
                np.array([0.1, 0.2, 0.4]), np.array([1.0, 1.0, 2.0]))
    assert p.inside.tolist() == [True, False, True]
    assert p.untested_gaps_hz == [pytest.approx((5 / 40, 12 / 40))]
    assert p.outside_share == pytest.approx(0.5 / 3.0)
    # an odd multisine (every other harmonic) is bridged
    la, _ = measure(0.0, harmonics=np.arange(1, 25, 2))
    p = predict(response_from_lines(la), noise_from_lines(la),  # type: ignore[arg-type]
                np.array([0.1, 0.2, 0.4]), np.array([1.0, 1.0, 2.0]))
    assert p.inside.all() and not p.untested_gaps_hz


def test_noise_dof_from_its_interval() -> None:
    from benchctl.analysis.uncertainty import chi2_ppf

    for nu in (3.0, 40.0, 2000.0):
        lo = nu / float(chi2_ppf(0.975, nu))
        hi = nu / float(chi2_ppf(0.025, nu))
        assert dof_from_interval(1.0, lo, hi) == pytest.approx(nu, rel=1e-6)
    assert dof_from_interval(1.0, 1.0, 1.0) == math.inf


def test_bad_targets_are_errors() -> None:
    resp = MeasuredResponse(np.array([0.1]), np.array([1]), np.array([1 + 0j]), np.zeros(1),
                            np.full(1, np.inf))
    noise = NoisePart(0.0, (0.0, 0.0), math.inf)
    with pytest.raises(DataError, match="target lines"):
        predict(resp, noise, [], [])
    with pytest.raises(DataError, match="finite frequencies"):
        predict(resp, noise, [0.1, math.nan], [1.0, 1.0])
    empty = MeasuredResponse(np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0, complex),
                             np.zeros(0), np.zeros(0))
    with pytest.raises(DataError, match="no line"):
        predict(empty, noise, [0.1], [1.0])


# ------------------------------------------------------------------------------ the CLI
def make_recording(folder: Path, profile_path: Path) -> Path:
    """A closed recording of ``profile_path`` (steady 50 s: lines k/50 s over 0.04 … 0.6 Hz):
    stand 100 Hz, instrument 50 Hz through ``lag_response`` with white noise ``NOISE``."""
    from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
    from benchctl.recording import RecordingWriter

    profile = load_profile(profile_path)
    table = synthesize(profile).tables["roll"]  # type: ignore[index]
    meta = {"serial": "P-1", "profile": profile.to_dict(), "seed": 3, "duration_s": 58.0,
            "fade_in_s": 4.0, "fade_out_s": 4.0}
    w = RecordingWriter(folder, ("roll",), meta)
    status = StandStatus(ready=True, enabled=True, moving=True, fault=False, estop=False,
                         limit=False)
    rng = np.random.default_rng(4)
    t0 = 100.0
    ts = t0 - 1.0 + np.arange(6000) / 100.0
    for t, a in zip(ts.tolist(), table.evaluate(ts - t0).tolist(), strict=True):
        w.write_stand(StandSample(t_host=t, rtt_s=0.004, angle_deg={"roll": a},
                                  rate_deg_s={"roll": 0.0}, setpoint_deg={"roll": 0.0},
                                  status=status))
    ti = t0 + np.arange(2900) / 50.0
    h = lag_response(table.freq_hz)
    arg = 2 * np.pi * table.freq_hz[:, None] * (ti - t0) + table.phase_rad[:, None]
    yi = (table.amp_deg[:, None] * np.abs(h)[:, None] * np.cos(arg + np.angle(h)[:, None])).sum(0)
    yi = yi + rng.normal(0.0, NOISE, ti.size)
    for i, (t, a) in enumerate(zip(ti.tolist(), yi.tolist(), strict=True)):
        w.write_instrument(InstrumentSample(t_host=t, angle_deg={"roll": a}, counter=i))
    w.close("done", analysis_window=[t0 + 4.0, t0 + 54.0])
    return folder


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    tmp = tmp_path_factory.mktemp("predict")
    (tmp / "a.yaml").write_text(PROFILE_A)
    (tmp / "b.yaml").write_text(PROFILE_B)
    return make_recording(tmp / "rec", tmp / "a.yaml"), tmp / "b.yaml"


def test_cli_json_and_text(recording: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
                           ) -> None:
    rec, prof_b = recording
    assert main(["predict", str(rec), "--profile", str(prof_b), "--json", "--axis", "roll"]) == 0
    d = json.loads(capsys.readouterr().out)
    f_in, a_in = np.array([0.15, 0.32]), np.array([3.0, 2.0])
    truth = closed_form(f_in, a_in, NOISE)
    assert d["axis"] == "roll" and d["profile_name"] == "harmonics_b"
    # the line at 0.9 Hz (0.5 deg² of 7) lies outside the tested band: with |1 − H| ≤ 1 there
    # it could add far more than 5 % to σ, so σ is not predicted, only bounded
    assert d["bounded"] is True and d["sigma"] is None and d["sigma_ci95"] is None
    assert d["sigma_measured_lines"] == pytest.approx(math.sqrt(truth), rel=0.01)
    lo, hi = d["sigma_measured_lines_ci95"]
    assert lo <= math.sqrt(truth) <= hi
    assert d["sigma_bound"] == pytest.approx(math.sqrt(d["variance_ci95"][1] + 0.5), rel=1e-12)
    assert d["sigma_bound"] >= math.sqrt(closed_form(np.array([0.15, 0.32, 0.9]),
                                                     np.array([3.0, 2.0, 1.0]), NOISE))
    assert d["outside_bands_hz"] == [[0.9, 0.9, 1]]
    assert d["outside_band_share"] == pytest.approx(0.5 / (4.5 + 2.0 + 0.5))
    assert d["lines"]["inside"] == [True, True, False]
    assert d["tested_band_hz"] == pytest.approx([2 / 50, 30 / 50])
    assert d["variance"] == pytest.approx(d["linear"] + d["noise"])
    assert d["measured"]["lines_source"] == "profile" and d["measured"]["n_lines"] == 29
    assert main(["predict", str(rec), "--profile", str(prof_b), "--json"]) == 0
    assert set(json.loads(capsys.readouterr().out)["axes"]) == {"roll"}
    assert main(["predict", str(rec), "--profile", str(prof_b)]) == 0
    text = capsys.readouterr().out
    assert f"predicted σ ≤ {d['sigma_bound']:.5g}° (95 %): a bound, not an estimate" in text
    assert "outside the tested band 7.14 % (0.5 deg², 1 lines)" in text
    assert "σ not predicted, only bounded: 7.14 % of the target's variance" in text
    assert "lies at 0.9 … 0.9 Hz (1 line), where H was not excited in the recording" in text
    # a small line outside (0.1°: 0.005 deg², 2.5 % of σ at most): σ is predicted
    small = prof_b.with_name("b_small.yaml")
    small.write_text(PROFILE_B.replace("amplitude_deg: 1.0, freq_hz: 0.9",
                                       "amplitude_deg: 0.1, freq_hz: 0.9"))
    assert main(["predict", str(rec), "--profile", str(small), "--json", "--axis", "roll"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert d["bounded"] is False
    assert d["sigma"] == pytest.approx(math.sqrt(truth), rel=0.01)
    assert d["sigma_ci95"][0] <= math.sqrt(truth) <= d["sigma_ci95"][1]
    assert main(["predict", str(rec), "--profile", str(small)]) == 0
    assert f"predicted σ = {d['sigma']:.5g}°" in capsys.readouterr().out


def test_cli_errors(recording: tuple[Path, Path], tmp_path: Path,
                    capsys: pytest.CaptureFixture[str]) -> None:
    rec, prof_b = recording
    steps = ROOT / "profiles/linearity_sine_steps.yaml"
    assert main(["predict", str(rec), "--profile", str(steps)]) == 2
    assert "sine_steps has no single table of lines" in capsys.readouterr().err
    assert main(["predict", str(tmp_path), "--profile", str(prof_b)]) == 2
    assert "not a benchctl recording" in capsys.readouterr().err
    assert main(["predict", str(rec), "--profile", str(prof_b), "--axis", "pitch"]) == 2
    assert "--axis pitch: the recording holds roll" in capsys.readouterr().err
    pitch = tmp_path / "pitch.yaml"
    pitch.write_text(PROFILE_B.replace("  roll:", "  pitch:"))
    assert main(["predict", str(rec), "--profile", str(pitch)]) == 2
    assert "moves pitch, none of the recording's roll" in capsys.readouterr().err
    assert main(["predict", str(rec), "--profile", str(prof_b), "--duration", "-1"]) == 2
    assert "--duration -1.0: expected a positive number" in capsys.readouterr().err
