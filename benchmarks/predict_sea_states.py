"""`predict` between the shipped sea states, both ways, against the σ of a known instrument.

Each record is one steady period of a shipped ``sea_state_{3,4,6}_small_vessel`` profile as
the stand would play it (the profile's own lines and phases at ``--duration``, 900 s by
default: one period of 880 s) seen by the simulated MEMS inclinometer of ``config/sim.yaml``
(gain 0.995, 80 ms first-order lag, 10 ms latency, 0.05° white noise) sampled at 20 Hz. The
line-wise analysis takes the profile's lines (as a recording's does); each record then
predicts σ under the two other sea states. The truth is computed apart from the analysis,
from the model: ``σ² = Σ_j |H(f_j) − 1|²·A_j²/2 + σ_n²`` over the target's lines.

Printed per direction (source → target): the mean and largest relative error of the predicted
σ, its standard deviation over the records beside the mean half-width of its 95 % interval
(both relative to the truth), how often the interval held the truth (binomial sd
√(0.95·0.05/R)), how often the prediction was only a bound (``bounded``), how often σ's bound
held the truth, and the recording's weak lines (SNR below the floor, not used). Lighter →
heavier is the hard way: the lighter sea's band-edge lines are a few 1e-8° high (its spectrum
dies away below its modal period) and measure nothing, while the heavier sea rolls there.

``tests/unit/analysis/test_predict_sea_states.py`` runs a few records of the same cases.

Usage: python benchmarks/predict_sea_states.py [--records R] [--duration SEC]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from benchctl.analysis import analyze
from benchctl.analysis.lines import line_set_from_tables
from benchctl.analysis.linewise import LineAnalysis
from benchctl.analysis.predict import Prediction, noise_from_lines, predict, response_from_lines
from benchctl.harmonics import HarmonicTable
from benchctl.profiles import load_profile, synthesize

ROOT = Path(__file__).resolve().parents[1]
GAIN, LAG_S, LATENCY_S, NOISE_DEG = 0.995, 0.08, 0.01, 0.05  # config/sim.yaml's instrument
FS_HZ = 20.0
SEA_STATES = (3, 4, 6)


def response(f: NDArray[np.float64]) -> NDArray[np.complex128]:
    """The model's H(f): gain × latency × first-order lag."""
    return np.asarray(GAIN * np.exp(-2j * np.pi * f * LATENCY_S) / (1 + 2j * np.pi * f * LAG_S))


def sea_table(state: int, duration_s: float) -> HarmonicTable:
    """The roll lines of ``profiles/sea_state_<state>_small_vessel.yaml`` at ``duration_s``."""
    prof = load_profile(ROOT / f"profiles/sea_state_{state}_small_vessel.yaml")
    return synthesize(prof, duration_s=duration_s).tables["roll"]  # type: ignore[index,no-any-return]


def true_sigma(table: HarmonicTable) -> float:
    """The model's σ under ``table``'s motion (about the mean), independent of the analysis."""
    f, a = np.asarray(table.freq_hz), np.asarray(table.amp_deg)
    return math.sqrt(float(np.sum(np.abs(response(f) - 1) ** 2 * a**2 / 2)) + NOISE_DEG**2)


def record(table: HarmonicTable, seed: int) -> tuple[NDArray[np.float64], ...]:
    """One steady period of ``table`` (t, stand angle, instrument output) at ``FS_HZ``."""
    n = round(table.period_s * FS_HZ)
    t = np.arange(n) / FS_HZ
    f, a, ph = (np.asarray(v, dtype=float) for v in (table.freq_hz, table.amp_deg,
                                                      table.phase_rad))
    h = response(f)
    x, y = np.zeros(n), np.zeros(n)
    for fk, ak, pk, hk in zip(f, a, ph, h, strict=True):
        arg = 2 * np.pi * fk * t + pk
        x += ak * np.cos(arg)
        y += ak * abs(hk) * np.cos(arg + np.angle(hk))
    return t, x, y + np.random.default_rng(seed).normal(0.0, NOISE_DEG, n)


def measure(table: HarmonicTable, seed: int) -> LineAnalysis:
    """The line-wise analysis of one record, the profile's lines given (a recording's path)."""
    t, x, y = record(table, seed)
    ls, why = line_set_from_tables(table, None, [])
    assert ls is not None, why
    la = analyze(t, x, t, y, lines=ls).lines
    assert la is not None
    return la


def predict_for(la: LineAnalysis, target: HarmonicTable) -> Prediction:
    return predict(response_from_lines(la), noise_from_lines(la), target.freq_hz,
                   target.amp_deg)


@dataclass
class Tally:
    errors: list[float]
    halfwidths: list[float]
    covered: int = 0
    bounded: int = 0
    bound_held: int = 0
    weak: int = 0

    def add(self, p: Prediction, truth: float, weak: int) -> None:
        self.errors.append(p.sigma / truth - 1.0)
        self.halfwidths.append((p.sigma_ci95[1] - p.sigma_ci95[0]) / (2.0 * truth))
        self.covered += p.sigma_ci95[0] <= truth <= p.sigma_ci95[1]
        self.bounded += p.bounded
        self.bound_held += p.sigma_bound >= truth
        self.weak = weak


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--records", type=int, default=200, help="records per source (default 200)")
    ap.add_argument("--duration", type=float, default=900.0,
                    help="the profiles' duration, s (default 900, as shipped)")
    args = ap.parse_args(argv)
    tables = {s: sea_table(s, args.duration) for s in SEA_STATES}
    truth = {s: true_sigma(tab) for s, tab in tables.items()}
    start = time.perf_counter()
    tallies: dict[tuple[int, int], Tally] = {}
    for src in SEA_STATES:
        for seed in range(args.records):
            la = measure(tables[src], seed)
            weak = int((~la.reliable).sum())
            for dst in SEA_STATES:
                if dst != src:
                    tallies.setdefault((src, dst), Tally([], [])).add(
                        predict_for(la, tables[dst]), truth[dst], weak)
    r = args.records
    sd = math.sqrt(0.95 * 0.05 / r)
    print(f"{r} records per source, {args.duration:g} s profiles (period "
          f"{tables[3].period_s:g} s), {FS_HZ:g} Hz; coverage sd {sd:.3f}; "
          f"{time.perf_counter() - start:.0f} s")
    print("source → target  true σ °   mean err   max |err|   sd err   CI half-width   "
          "coverage   bounded   bound ≥ truth   weak lines")
    for (src, dst), tl in sorted(tallies.items()):
        e = np.array(tl.errors)
        hw = 100 * float(np.mean(tl.halfwidths))
        print(f"  {src} → {dst}        {truth[dst]:.5f}   {100 * e.mean():+7.3f} %  "
              f"{100 * np.abs(e).max():7.3f} %  {100 * e.std():6.3f} %   {hw:6.3f} %      "
              f"{tl.covered / r:6.3f}    {tl.bounded:4d}      {tl.bound_held / r:6.3f}"
              f"          {tl.weak}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
