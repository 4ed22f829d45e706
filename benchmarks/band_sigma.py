"""Band-limited σ (``analyze --band``) from the line-wise estimate: its bias and how often its
95 % interval holds the truth, per kind of record and band.

Records (``--records`` each, fixed seeds): a multisine of lines k/T_p through a gain and an
80 ms lag (|H − 1|² known at each line) plus a noise of known one-sided density G_n(f):

- ``white``: 3 periods of 40 s at 20 Hz, lines 0.05 … 0.6 Hz, white noise 0.2°;
- ``coloured``: the same, the noise an AR(1) (a = 0.8) of 0.2°;
- ``one_period``: one period of 120 s at 20 Hz (every bin a line: the noise at the lines from
  the local polynomial method), white noise 0.2°;
- ``sea_state``: one period (880 s) of ``sea_state_3_small_vessel`` (its lowest lines weak)
  through config/sim.yaml's instrument (benchmarks/predict_sea_states.py), 0.05° white noise.

The truth in a band [lo, hi] is ``Σ_{lo ≤ f_k ≤ hi} |H(f_k) − 1|²A_k²/2 + ∫_lo^hi G_n df``
(the lines' power whole, the noise's density integrated: a process's variance in the band).
Bands: a line-dominated one, a narrow one (0.05 Hz), one with no line (noise only; above the
lines), one whose edges fall between bins, and the sea state's weak lines' band.

Printed per case: mean relative error of the band's variance with its standard error, the
coverage of its 95 % interval (binomial sd √(0.95·0.05/R)), and the mean half-width of the
interval against 1.96 × the spread of the estimate (both relative to the truth), and the
records that got no line-wise estimate (left out of the figures; the band is then the PSD's
area, without an interval).

Usage: python benchmarks/band_sigma.py [--records R]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.signal import lfilter

from benchctl.analysis import analyze
from benchctl.errors import DataError

FloatArray = NDArray[np.float64]
AR = 0.8


@dataclass(frozen=True)
class Case:
    name: str
    band: tuple[float, float]
    make: Callable[[int], tuple[FloatArray, FloatArray, FloatArray, dict[str, object]]]
    truth: float


def _multisine(tp: float, n_per: int, noise: str, seed: int, fs: float = 20.0,
               sigma_n: float = 0.2) -> tuple[FloatArray, FloatArray, FloatArray]:
    k = np.arange(round(0.05 * tp), round(0.6 * tp) + 1)
    f = k / tp
    h = 0.98 / (1 + 2j * np.pi * f * 0.08)
    n = round(fs * tp * n_per)
    t = np.arange(n) / fs
    rng = np.random.default_rng(seed)
    ph = np.random.default_rng(1000 + seed).uniform(0, 2 * np.pi, k.size)
    arg = 2 * np.pi * f[:, None] * t + ph[:, None]
    x = np.cos(arg).sum(0)
    y = (np.abs(h)[:, None] * np.cos(arg + np.angle(h)[:, None])).sum(0)
    e = rng.normal(0.0, 1.0, n)
    if noise == "coloured":
        e = lfilter([1.0], [1.0, -AR], e) * math.sqrt(1 - AR**2)
    return t, x, y + sigma_n * e


def _ms_truth(tp: float, noise: str, lo: float, hi: float, fs: float = 20.0,
              sigma_n: float = 0.2) -> float:
    k = np.arange(round(0.05 * tp), round(0.6 * tp) + 1)
    f = k / tp
    h = 0.98 / (1 + 2j * np.pi * f * 0.08)
    inb = (f >= lo - 1e-12) & (f <= hi + 1e-12)
    lines = float(np.sum(np.abs(h[inb] - 1) ** 2 / 2))
    ff = np.linspace(lo, hi, 20001)
    if noise == "coloured":  # one-sided density of the unit-variance AR(1), times σ_n²
        g = 2.0 / fs * (1 - AR**2) / np.abs(1 - AR * np.exp(-2j * np.pi * ff / fs)) ** 2
    else:
        g = np.full_like(ff, 2.0 / fs)
    return lines + sigma_n**2 * float(np.trapezoid(g, ff))


def cases() -> list[Case]:
    out: list[Case] = []
    for name, tp, n_per, noise in (("white", 40.0, 3, "white"),
                                   ("coloured", 40.0, 3, "coloured"),
                                   ("one_period", 120.0, 1, "white")):
        for band in ((0.1, 0.3), (0.2, 0.25), (0.7, 0.9), (0.1013, 0.2013)):
            out.append(Case(
                f"{name} {band[0]:g}–{band[1]:g} Hz", band,
                lambda s, tp=tp, n_per=n_per, noise=noise: (
                    *_multisine(tp, n_per, noise, s), {"period_s": tp}),
                _ms_truth(tp, noise, *band)))
    from predict_sea_states import FS_HZ, NOISE_DEG, record, response, sea_table

    from benchctl.analysis.lines import line_set_from_tables

    tab = sea_table(3, 900.0)
    ls, _ = line_set_from_tables(tab, None, [])
    f, a = np.asarray(tab.freq_hz), np.asarray(tab.amp_deg)
    for band in ((0.05, 0.1), (0.1, 0.2)):
        inb = (f >= band[0] - 1e-9) & (f <= band[1] + 1e-9)
        truth = float(np.sum(np.abs(response(f[inb]) - 1) ** 2 * a[inb] ** 2 / 2)) + (
            NOISE_DEG**2 * (band[1] - band[0]) / (FS_HZ / 2))
        out.append(Case(f"sea_state_3 {band[0]:g}–{band[1]:g} Hz", band,
                        lambda s: (*record(tab, s), {"lines": ls}), truth))
    return out


def run(case: Case, records: int, seed0: int = 0
        ) -> tuple[float, float, float, float, float, int]:
    """(mean rel. error, its standard error, coverage, mean half-width, sd of the estimate,
    records without a line-wise estimate — left out of the rest)"""
    rel, hits, half, without = [], 0, [], 0
    for seed in range(seed0, seed0 + records):
        t, x, y, kw = case.make(seed)
        try:
            b = analyze(t, x, t, y, band_hz=case.band, **kw).band  # type: ignore[arg-type]
        except DataError:  # no lines, and the band narrower than the PSD's resolution
            b = None
        if b is None or b["method"] != "lines":
            without += 1
            continue
        lo, hi = b["variance_ci95"]
        rel.append(b["variance"] / case.truth - 1)
        hits += lo <= case.truth <= hi
        half.append((hi - lo) / (2 * case.truth))
    e = np.array(rel)
    return (float(e.mean()), float(e.std() / math.sqrt(e.size)), hits / e.size,
            float(np.mean(half)), float(e.std()), without)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--records", type=int, default=400, help="records per case (default 400)")
    ap.add_argument("--case", nargs="*", help="only the cases whose name starts so")
    ap.add_argument("--seed0", type=int, default=0,
                    help="first seed (default 0; every case draws the same seeds' records)")
    args = ap.parse_args(argv)
    start = time.perf_counter()
    sd = math.sqrt(0.95 * 0.05 / args.records)
    print(f"{args.records} records per case (seeds {args.seed0} …); coverage sd {sd:.3f}")
    print("case                                  bias (variance)        coverage   "
          "half-width   1.96 × spread   no lines")
    for c in cases():
        if args.case and not any(c.name.startswith(p) for p in args.case):
            continue
        m, se, cov, hw, spread, without = run(c, args.records, args.seed0)
        print(f"  {c.name:34s}  {100 * m:+7.3f} ± {100 * se:.3f} %   {cov:6.3f}    "
              f"{100 * hw:7.3f} %   {100 * 1.96 * spread:7.3f} %      {without}", flush=True)
    print(f"{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
