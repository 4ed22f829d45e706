"""The synthetic instrument and the profiles of the prediction tests (``test_predict``,
``test_predict_axes``, ``test_analysis_degenerate``): a gain × latency × first-order lag with
its closed-form σ under any multisine, and two small profiles."""

from __future__ import annotations

import numpy as np

GAIN, LAG, LATENCY = 0.995, 0.08, 0.01  # the simulated MEMS inclinometer of config/sim.yaml


def lag_response(f: np.ndarray) -> np.ndarray:
    """Gain × latency × first-order lag."""
    return np.asarray(GAIN * np.exp(-2j * np.pi * f * LATENCY) / (1 + 2j * np.pi * f * LAG))


def closed_form(f: np.ndarray, a: np.ndarray, noise_deg: float) -> float:
    return float(np.sum(np.abs(lag_response(f) - 1) ** 2 * a**2 / 2) + noise_deg**2)


PROFILE_A = """
name: flat_a
description: flat roll multisine for prediction tests
reference: synthetic
kind: roll_spectrum
duration_s: 58
fade_in_s: 4
fade_out_s: 4
seed: 3
band_hz: [0.04, 0.6]
axes:
  roll: {model: table, freq_hz: [0.02, 0.65], density_deg2_hz: [5.0, 5.0]}
"""
PROFILE_B = """
name: harmonics_b
description: three lines, one outside the tested band
reference: synthetic
kind: harmonics
duration_s: 30
fade_in_s: 2
fade_out_s: 2
seed: 1
axes:
  roll:
    lines:
      - {amplitude_deg: 3.0, freq_hz: 0.15}
      - {amplitude_deg: 2.0, freq_hz: 0.32}
      - {amplitude_deg: 1.0, freq_hz: 0.9}
"""
NOISE = 0.02
