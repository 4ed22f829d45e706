"""The instrument model against closed forms: its stated H(f) is the response it really has."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchctl.config import SimInstrumentConfig
from benchctl.sim.instrument_model import InstrumentModel


def _sine(f: float, a: float = 1.0, c: float = 0.0):  # type: ignore[no-untyped-def]
    return lambda t: {"roll": c + a * math.sin(2 * math.pi * f * t)}


def _fit(t: np.ndarray, y: np.ndarray, f: float) -> tuple[complex, float]:
    """Least squares y ≈ Im(H e^{jωt}) + c: returns (H, c)."""
    w = 2 * math.pi * f
    x = np.c_[np.sin(w * t), np.cos(w * t), np.ones_like(t)]
    (a, b, c), *_ = np.linalg.lstsq(x, y, rcond=None)
    return complex(a, b), float(c)


def _run(cfg: SimInstrumentConfig, motion, duration_s: float) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    m = InstrumentModel(cfg, axes=("roll",))
    t = 0.0123 + np.arange(int(duration_s * cfg.rate_hz)) / cfg.rate_hz
    y = np.array([m.output(float(ti), motion)["roll"] for ti in t])
    return t, y


def test_transfer_function_closed_forms() -> None:
    tau = 0.1
    m = InstrumentModel(SimInstrumentConfig(lag_s=tau, gain=0.9, latency_s=0.02))
    f = np.array([0.0, 0.3, 1.0, 3.0])
    w = 2 * np.pi * f
    expected = 0.9 * np.exp(-1j * w * 0.02) / (1 + 1j * w * tau)
    np.testing.assert_allclose(m.transfer_function(f), expected, rtol=1e-12)
    # second order at its natural frequency: |H| = 1/(2ζ), phase −90°
    m2 = InstrumentModel(SimInstrumentConfig(natural_freq_hz=2.0, damping=0.25))
    h = complex(m2.transfer_function(2.0))
    assert abs(h) == pytest.approx(2.0, rel=1e-12)
    assert math.degrees(np.angle(h)) == pytest.approx(-90.0, abs=1e-9)


@pytest.mark.parametrize(
    "params",
    [
        {"lag_s": 0.1},
        {"natural_freq_hz": 2.0, "damping": 0.3},
        {"lag_s": 0.05, "natural_freq_hz": 3.0, "damping": 0.6, "latency_s": 0.02, "gain": 0.98},
        {"latency_s": 0.013, "gain": 1.02},
    ],
)
@pytest.mark.parametrize("f", [0.2, 1.3, 5.0])
def test_simulated_response_matches_stated_transfer_function(params: dict, f: float) -> None:
    cfg = SimInstrumentConfig(rate_hz=50.0, **params)
    t, y = _run(cfg, _sine(f), 12.0)
    keep = t > 6.0  # transients (slowest: τ = 0.1 s, 2nd order decay 1/(ζωn) ≈ 0.27 s) gone
    h, c = _fit(t[keep], y[keep], f)
    h_true = complex(InstrumentModel(cfg).transfer_function(f))
    assert abs(h / h_true - 1) < 1e-3  # the 0.1 % the model promises
    assert abs(c) < 1e-6


def test_constant_input_starts_at_rest_and_bias_drift_add() -> None:
    cfg = SimInstrumentConfig(rate_hz=10.0, lag_s=0.5, gain=0.9, bias_deg=0.25, drift_deg_s=0.01)
    t, y = _run(cfg, lambda _t: {"roll": 3.0}, 5.0)
    np.testing.assert_allclose(y, 0.9 * 3.0 + 0.25 + 0.01 * (t - t[0]), atol=1e-9)


def test_noise_sigma_and_quantisation() -> None:
    cfg = SimInstrumentConfig(rate_hz=100.0, noise_deg=0.05, seed=3)
    _t, y = _run(cfg, lambda _t: {"roll": 1.0}, 100.0)
    n = len(y)
    # σ estimate from n = 10 000 normal samples: relative SE 1/√(2n) = 0.7 %; allow 4 %
    assert np.std(y, ddof=1) == pytest.approx(0.05, rel=0.04)
    assert abs(np.mean(y) - 1.0) < 5 * 0.05 / math.sqrt(n)
    q = SimInstrumentConfig(rate_hz=100.0, noise_deg=0.05, quantisation_deg=0.02, seed=3)
    _, yq = _run(q, lambda _t: {"roll": 1.0}, 10.0)
    steps = yq / 0.02
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-9)


def test_expected_error_variance_matches_simulated_error() -> None:
    cfg = SimInstrumentConfig(rate_hz=50.0, lag_s=0.08, gain=0.97, latency_s=0.01,
                              noise_deg=0.03, bias_deg=0.4, seed=5, substep_hz=1000.0)
    amps, freqs = np.array([4.0, 1.5]), np.array([0.1, 0.35])

    def motion(t: float) -> dict[str, float]:
        return {"roll": float(np.sum(amps * np.cos(2 * np.pi * freqs * t + np.array([0.3, 1.1]))))}

    t, y = _run(cfg, motion, 100.0)  # whole periods of both lines (10 s and 20/7 s)
    keep = t >= t[0] + 20.0
    x = np.array([motion(float(ti))["roll"] for ti in t[keep]])
    eps = y[keep] - x
    m = InstrumentModel(cfg)
    expected = m.expected_error_variance(amps, freqs)
    dynamic = float(np.sum(amps**2 * np.abs(m.transfer_function(freqs) - 1) ** 2) / 2)
    assert expected == pytest.approx(dynamic + 0.03**2, rel=1e-12)
    # the noise part (0.0009 deg² of ≈0.066) has a sampling SE of ≈ 1e-5 deg² here
    assert np.var(eps) == pytest.approx(expected, rel=0.01)
    assert np.mean(eps) == pytest.approx(0.4, abs=0.01)


def test_output_instants_must_increase() -> None:
    m = InstrumentModel(SimInstrumentConfig(lag_s=0.1), axes=("roll",))
    m.output(1.0, lambda _t: {"roll": 0.0})
    with pytest.raises(ValueError, match="must increase"):
        m.output(0.5, lambda _t: {"roll": 0.0})


def test_static_nonlinearity_and_cross_axis_coupling_exact_without_dynamics() -> None:
    cfg = SimInstrumentConfig(cubic_per_deg2=0.01, saturation_deg=3.0,
                              cross_axis={"roll_from_pitch": 0.02, "pitch_from_roll": -0.1})
    m = InstrumentModel(cfg, axes=("roll", "pitch"))
    for t, (r, p) in enumerate([(1.0, 2.0), (2.5, -1.0), (-4.0, 0.5)]):
        out = m.output(float(t), lambda _t, r=r, p=p: {"roll": r, "pitch": p})
        ur, up = r + 0.02 * p, p - 0.1 * r
        assert out["roll"] == pytest.approx(float(np.clip(ur + 0.01 * ur**3, -3, 3)), abs=1e-12)
        assert out["pitch"] == pytest.approx(float(np.clip(up + 0.01 * up**3, -3, 3)), abs=1e-12)
    np.testing.assert_allclose(m.cross_transfer_function([0.2], "pitch"),
                               -0.1 * m.transfer_function([0.2]))


def test_default_model_is_untouched_by_the_new_options() -> None:
    base = SimInstrumentConfig(lag_s=0.08, noise_deg=0.05, gain=0.995, seed=3)
    explicit = SimInstrumentConfig(lag_s=0.08, noise_deg=0.05, gain=0.995, seed=3,
                                   cubic_per_deg2=0.0, cross_axis={"roll_from_pitch": 0.0})
    motion = _sine(0.3, 5.0)
    _, y0 = _run(base, motion, 5.0)
    _, y1 = _run(explicit, motion, 5.0)
    np.testing.assert_array_equal(y0, y1)


def test_cross_axis_coupling_through_the_dynamics() -> None:
    """With a lag, roll's response to a pitch sine is k·H(f) (the coupling shares the dynamics)."""
    k, f = 0.05, 0.4
    cfg = SimInstrumentConfig(lag_s=0.1, latency_s=0.01, cross_axis={"roll_from_pitch": k})
    m = InstrumentModel(cfg, axes=("roll",))
    t = 0.0123 + np.arange(4000) / cfg.rate_hz
    y = np.array([m.output(float(ti), lambda s: {"roll": 0.0,
                                                 "pitch": math.sin(2 * math.pi * f * s)})["roll"]
                  for ti in t])
    keep = t > 2.0  # the start-up transient decayed
    h, _ = _fit(t[keep], y[keep], f)
    assert abs(h - complex(m.cross_transfer_function(f, "roll"))) < 1e-4
