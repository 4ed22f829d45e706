"""Gain and phase at the traditional periods only where the motion was measured there.

- polyharmonic: a period on a line stays on it when the period refined from the record differs
  from the profile's by a few ppm (a stand clock 5 ppm slow);
- sine steps: the periods stepped take their largest-amplitude step's estimate; a period never
  stepped is not excited (no number from the whole sequence's frequency response).
"""

from __future__ import annotations

import numpy as np
import pytest

from benchctl.analysis import analyze
from benchctl.analysis.frf import TRADITIONAL_PERIODS_S
from benchctl.analysis.lines import LineSet
from benchctl.analysis.steps import StepEstimate, StepsAnalysis, StepWindow


def test_period_on_a_line_of_a_period_refined_a_few_ppm_off() -> None:
    tp = 21.0
    stretch = 1 + 5e-6  # the record's clock: the motion's period reads 21.000105 s
    t = np.arange(0.0, 3 * tp * stretch, 0.01)
    k = np.arange(1, 11)
    rng = np.random.default_rng(1)
    ph = rng.uniform(0, 2 * np.pi, k.size)
    x = sum(np.cos(2 * np.pi * kk * t / (tp * stretch) + p) for kk, p in zip(k, ph, strict=True))
    y = 0.99 * x + 0.001 * rng.standard_normal(t.size)
    r = analyze(t, x, t, y, lines=LineSet(tp, k, "profile"))
    by_period = {p["period_s"]: p for p in r.periods}
    three = by_period[3.0]  # 1/3 Hz = harmonic 7 of 21 s
    assert three["excited"] and three["source"] == "line"
    assert three["gain"] == pytest.approx(0.99, abs=2e-4)
    seven = by_period[7.0]  # harmonic 3
    assert seven["excited"] and seven["source"] == "line"
    five = by_period[5.0]  # 4.2: between harmonics 4 and 5
    assert five["excited"] and five["source"] == "interpolated"


def _step(period: float, amp: float, gain: float) -> StepEstimate:
    w = StepWindow("roll", period, amp, 0.0, 3)
    return StepEstimate(w, gain, (gain - 0.001, gain + 0.001), -2.0, (-2.1, -1.9), amp)


def test_sine_steps_give_the_periods_they_stepped_and_no_other() -> None:
    sa = StepsAnalysis([_step(3.0, 2.0, 0.991), _step(3.0, 5.0, 0.993), _step(5.0, 2.0, 0.996)],
                       limit=0.01)
    got = {p["period_s"]: p for p in sa.periods(TRADITIONAL_PERIODS_S)}
    assert got[3.0]["excited"] and got[3.0]["source"] == "steps"
    assert got[3.0]["gain"] == 0.993 and got[3.0]["amplitude_deg"] == 5.0  # the largest step
    assert got[5.0]["gain"] == 0.996
    for never in (7.0, 10.0):
        assert not got[never]["excited"] and got[never]["gain"] is None
