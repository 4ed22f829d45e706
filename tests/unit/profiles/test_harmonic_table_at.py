"""``HarmonicTable.at`` (one instant, the simulated stand's 1 kHz tick in table mode) against
``HarmonicTable.evaluate`` and its envelope against ``fade_envelope``, over any instant and any
fades (hypothesis, bounded)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchctl.harmonics import HarmonicTable, fade_envelope, fade_envelope_at


@settings(max_examples=300, deadline=None)
@given(
    duration=st.floats(1.0, 2000.0),
    fade_in=st.floats(0.0, 1.0),
    fade_out=st.floats(0.0, 1.0),
    where=st.floats(-0.1, 1.1),
)
def test_the_scalar_envelope_is_the_arrays_to_the_bit(
    duration: float, fade_in: float, fade_out: float, where: float
) -> None:
    fi, fo = fade_in * duration / 2, fade_out * duration / 2
    for t in (where * duration, 0.0, fi, duration - fo, duration, math.nextafter(fi, 0.0)):
        assert fade_envelope_at(t, duration, fi, fo) == float(
            fade_envelope(np.array([t]), duration, fi, fo)[0]
        ), t


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), where=st.floats(-0.05, 1.05))
def test_at_is_the_faded_sum_of_cosines(seed: int, where: float) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 80))
    tab = HarmonicTable(rng.uniform(0.01, 2.0, n), rng.uniform(0.0, 3.0, n),
                        rng.uniform(-math.pi, math.pi, n), 100.0, 7.0, 9.0)
    t = where * 100.0
    assert tab.at(t) == pytest.approx(float(tab.evaluate(t)[0]), abs=1e-12)
    # exactly as the array form computes it, term by term
    e = float(fade_envelope(np.array([t]), 100.0, 7.0, 9.0)[0]) if 0.0 <= t <= 100.0 else 0.0
    direct = 0.0 if e == 0.0 else e * float(
        np.dot(tab.amp_deg, np.cos(2.0 * np.pi * tab.freq_hz * t + tab.phase_rad)))
    assert tab.at(t) == direct
