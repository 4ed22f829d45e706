"""Exact ground truth: a multisine over whole periods through known linear instruments.

σ² = Σ (A_k²/2)|1 − H(f_k)|² + σ_n² holds exactly for the synthetic records (the noise is
made exactly orthogonal to the multisine error), so σ is checked tightly on the device's own
grid and within 1 % when the streams differ in rate, jitter, or have gaps. Gain within 0.5 %,
phase within 1° at the traditional periods (3, 5, 7, 10 s).
"""

from __future__ import annotations

import numpy as np
import pytest
from analysis_synthetic import (
    Multisine,
    Response,
    delay,
    first_order,
    gain,
    orthogonal_noise,
    second_order,
)

from benchctl.analysis import analyze, core
from benchctl.errors import AnalysisError

MS = Multisine(period_s=200.0, f_lo=0.05, f_hi=0.6, rms_deg=5.0)
FS = 20.0
N = 12000  # 600 s = 3 whole periods
SN = 0.05  # deg, white noise

MODELS: dict[str, Response] = {
    "gain": gain(0.98),
    "first_order": first_order(0.2),
    "second_order": second_order(0.8, 0.3),
    "delay": delay(0.15),
}


def record(h: Response, variant: str, seed: int = 5):
    """(t_ref, x_ref, t_dev, y_dev) for one instrument and one way of sampling."""
    rng = np.random.default_rng(seed)
    td = np.arange(N) / FS
    if variant == "same":
        x = MS.reference(td)
        y0 = MS.through(h, td)
        return td, x, td, y0 + orthogonal_noise(rng, SN, y0 - x)
    nr = 600 * 50 + 50  # reference at 50 Hz, Modbus-like jitter of ±2 ms
    tr = np.arange(nr) / 50.0 - 0.5 + rng.uniform(-0.002, 0.002, nr)
    if variant in ("jitter", "gaps"):
        td = td + rng.uniform(-0.005, 0.005, N)
    x = MS.reference(tr)
    y0 = MS.through(h, td)
    y = y0 + orthogonal_noise(rng, SN, y0 - MS.reference(td))
    if variant == "gaps":
        keep = rng.random(N) > 0.01  # 1 % dropped samples
        keep[4000:4060] = False  # and a 3 s hole
        td, y = td[keep], y[keep]
        kr = np.ones(nr, dtype=bool)
        kr[20000:20050] = False  # a 1 s hole in the reference
        tr, x = tr[kr], x[kr]
    return tr, x, td, y


def true_sigma(h: Response) -> float:
    return float(np.sqrt(MS.error_variance(h) + SN**2))


def check_frf(result, h: Response) -> None:
    assert [p["period_s"] for p in result.periods] == [3.0, 5.0, 7.0, 10.0]
    for p in result.periods:
        hk = h(np.array([p["freq"]]))[0]
        assert p["gain"] == pytest.approx(abs(hk), rel=0.005), p
        assert abs(p["phase_deg"] - np.degrees(np.angle(hk))) < 1.0, p
        assert p["coherence"] > 0.99


@pytest.mark.parametrize("model", MODELS)
def test_exact_on_device_grid(model: str) -> None:
    h = MODELS[model]
    r = analyze(*record(h, "same"))
    assert r.sigma == pytest.approx(true_sigma(h), rel=1e-9)
    assert r.mean_error == pytest.approx(0.0, abs=1e-9)
    assert r.rms_error == pytest.approx(true_sigma(h), rel=1e-9)
    check_frf(r, h)
    # decomposition: linear part Σ(A²/2)|1−H|², incoherent σ_n², each within 0.5 % of σ²
    assert abs(r.linear - MS.error_variance(h)) < 0.005 * r.variance
    assert abs(r.incoherent - SN**2) < 0.005 * r.variance
    assert r.cross_checks["parseval_rel_diff"] < 1e-9
    assert r.cross_checks["welch_agrees"] is True
    assert r.sigma_ci95[0] < r.sigma < r.sigma_ci95[1]
    assert r.n_samples == N and r.sample_rate == pytest.approx(FS)
    assert r.max_lag_samples == N // 10 and r.max_lag == pytest.approx(N / 10 / FS)


@pytest.mark.parametrize("variant", ["rates", "jitter", "gaps"])
@pytest.mark.parametrize("model", MODELS)
def test_two_rates_jitter_gaps(model: str, variant: str) -> None:
    h = MODELS[model]
    r = analyze(*record(h, variant))
    assert r.sigma == pytest.approx(true_sigma(h), rel=0.01)
    check_frf(r, h)
    assert r.cross_checks["welch_agrees"] is True
    if variant == "gaps":
        dev = r.gaps["device"]
        assert dev["count"] >= 100 and dev["longest_s"] == pytest.approx(3.05, abs=0.02)
        assert r.gaps["reference"]["count"] == 1
        assert r.gaps["reference"]["longest_s"] == pytest.approx(1.02, abs=0.01)
        assert r.gaps["excluded_samples"] == 20  # device samples inside the reference's hole
    else:
        assert r.gaps["device"]["count"] == 0


def test_delay_estimate_and_compensation() -> None:
    h = delay(0.15)
    args = record(h, "rates")
    r = analyze(*args)
    assert r.delay == pytest.approx(0.15, abs=0.002)
    assert r.delay_compensated == 0.0
    fixed = analyze(*args, compensate_delay=0.15)
    assert fixed.delay_compensated == 0.15
    assert fixed.delay == pytest.approx(0.15, abs=0.002)  # reported before compensation
    assert fixed.sigma == pytest.approx(SN, rel=0.01)  # only the noise is left
    auto = analyze(*args, compensate_delay="auto")
    assert auto.delay_compensated == pytest.approx(0.15, abs=0.002)
    assert auto.uncertainty["compensate_delay"] == "auto"
    assert auto.sigma == pytest.approx(SN, rel=0.05)
    assert r.to_dict()["uncertainty"]["compensate_delay"] == "none"


def test_first_order_delay_is_its_time_constant_at_low_frequency() -> None:
    r = analyze(*record(first_order(0.2), "same"))
    # phase −atan(2πfτ) ≈ −2πfτ(1 − (2πfτ)²/3): equivalent delay a little under τ in band
    assert 0.15 < r.delay < 0.2


def test_band_sigma() -> None:
    h = gain(0.98)
    r = analyze(*record(h, "same"), band_hz=(0.02, 1.0))
    # all the lines and a 0.98 Hz slice of the white noise density 2σ²/fs
    expected = MS.error_variance(h) + 2 * SN**2 / FS * 0.98
    assert r.band is not None
    assert r.band["variance"] == pytest.approx(expected, rel=0.01)
    assert r.band["sigma"] == pytest.approx(np.sqrt(expected), rel=0.005)
    assert r.frf_freq.min() >= 0.02 and r.frf_freq.max() <= 1.0


def test_parseval_disagreement_raises(monkeypatch: pytest.MonkeyPatch) -> None:
    real = core.trapezoid_area
    monkeypatch.setattr(core, "trapezoid_area", lambda f, g: real(f, g) * (1 + 1e-6))
    with pytest.raises(AnalysisError, match="Parseval"):
        analyze(*record(gain(0.98), "same"))


def test_to_dict_has_the_documented_keys() -> None:
    d = analyze(*record(gain(0.98), "same"), band_hz=(0.05, 0.6)).to_dict()
    for key in ("sigma", "variance", "mean_error", "rms_error", "sigma_ci95", "dof", "delay",
                "delay_compensated", "n_samples", "duration", "sample_rate", "max_lag",
                "max_lag_samples", "resolution_hz", "components", "band", "periods", "frf",
                "psd", "gaps", "timing", "cross_checks", "uncertainty", "warnings", "lines"):
        assert key in d, key
    assert set(d["frf"]) == {"freq", "gain", "phase_deg", "coherence", "gain_ci95",
                             "phase_ci95_deg", "reliable", "source"}
    assert {"freq", "error", "dof"} <= set(d["psd"])
    assert {"linear", "incoherent", "static", "source"} == set(d["components"])
    assert {"source", "period_s", "period_nominal_s", "n_periods", "n_lines", "freq",
            "reference_amplitude", "gain", "gain_ci95", "phase_deg", "phase_ci95_deg",
            "coherence", "snr", "reliable", "snr_floor", "n_reliable", "noise", "noise_dof",
            "noise_method", "linear", "linear_ci95",
            "incoherent", "incoherent_ci95", "mean_removal", "variance", "variance_ci95",
            "sigma", "sigma_ci95", "dof", "dof_parts", "reference_fit",
            "stationarity"} == set(d["lines"])
    assert {"period_s", "freq", "excited", "gain", "gain_ci95", "phase_deg", "phase_ci95_deg",
            "coherence", "source"} == set(d["periods"][0])
    assert {"method", "mean_removal", "sigma_corrected", "dof_parts",
            "stationarity"} <= set(d["uncertainty"])
    assert len(d["psd"]["freq"]) == len(d["psd"]["error"])
    assert len(d["sigma_ci95"]) == 2


@pytest.mark.parametrize("d", [0.088, -0.031, 0.0])
def test_delay_through_a_fade_and_gaps(d: float) -> None:
    """A short record that is mostly a fade-in, with a hole near its loud end: the delay is
    still the shift that makes the records most alike (the edges and the gap must not pull
    the correlation peak to zero)."""
    rng = np.random.default_rng(11)
    ms = Multisine(period_s=20.0, f_lo=0.05, f_hi=0.6, rms_deg=5.0, seed=3)

    def faded(t: np.ndarray) -> np.ndarray:
        env = 0.5 - 0.5 * np.cos(np.pi * np.clip(t / 30.0, 0.0, 1.0))
        return env * ms.reference(t)

    tr = np.arange(0, 40, 0.01) + rng.uniform(-0.002, 0.002, 4000)
    td = np.arange(1, 39, 0.01)
    keep = (td < 37.0) | (td > 37.3)
    td = td[keep]
    y = faded(td - d) + rng.normal(0, 0.02, td.size)
    r = analyze(tr, faded(tr), td, y)
    assert r.delay == pytest.approx(d, abs=0.001)
    comp = analyze(tr, faded(tr), td, y, compensate_delay="auto")
    assert comp.sigma == pytest.approx(0.02, rel=0.05)


def test_to_dict_is_strict_json_even_with_nan() -> None:
    import json

    r = analyze(*record(gain(0.98), "same"))
    r.delay = float("nan")
    r.cross_checks["welch_area"] = float("inf")
    r.periods[0]["coherence"] = float("nan")
    d = json.loads(json.dumps(r.to_dict(), allow_nan=False))
    assert d["delay"] is None and d["cross_checks"]["welch_area"] is None
    assert d["periods"][0]["coherence"] is None
