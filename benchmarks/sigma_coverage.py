"""How often the 95 % interval of σ holds the true σ: the long Monte Carlo, per kind of error.

The analysis's interval of σ on synthetic records whose true σ is known exactly (a multisine
through a known instrument, ``analysis_synthetic``; the truth is the error process's σ:
Σ(A²/2)|1 − H|² plus the noise process's variance, not a record's sample variance):

- ``multisine``: 300 s at 10 Hz, 3 periods of 100 s, gain 0.98 and white noise 0.1°;
- ``coloured``: the same motion, the error an AR(1) Gaussian noise (a = 0.6) alone;
- per kind, 900 s at 4 Hz in 9 periods of 100 s, and as one period of 900 s (every bin a line:
  the local polynomial method) for the kinds that depend on the noise at the lines:
  ``white`` 0.1° beside a gain error of 0.05°; ``in_band`` noise at 0.25 ± 0.05 Hz, inside
  the motion's band; ``drift``, a corner at 0.005 Hz holding 54 % of the noise's variance;
  ``linear``, 99.9 % linear (a 50 ms lag and 0.03° of white noise);
- non-stationary, 900 s in 9 periods of 100 s: ``walk``, a random walk of 0.1° over the
  record beside white noise 0.1° and a gain error; ``modulated``, a gain
  ``0.99·(1 + 0.01 sin(2π·0.003 t + φ))`` with φ random (the test does not start at the
  modulation's zero) and 0.03° of white noise; both also as one period of 900 s
  (``walk_1p``, ``modulated_1p``). Their truth is σ of the process (the README),
  and the script also prints how often the record was flagged non-stationary and the ratio
  of the interval's mean half-width to 1.96 × the spread of σ̂ over the records.

Each coverage is binomial: over R records its standard deviation is √(0.95·0.05/R) — 0.0069
at R = 1000, 0.0126 at R = 300. ``tests/unit/analysis/test_analysis_uncertainty.py`` runs
the same cases with fewer records (``SUITE_RECORDS``) and a tolerance of about 3 of those
standard deviations; this script runs the long ones (``LONG_RECORDS``, fixed seeds) and
prints each coverage with its binomial standard deviation, and the mean σ̂/σ.

Usage: python benchmarks/sigma_coverage.py [--records N] [--case NAME ...]
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Callable

import numpy as np
from analysis_synthetic import Multisine, first_order, gain
from numpy.typing import NDArray
from scipy.signal import lfilter

from benchctl.analysis import AnalysisResult, analyze

# -- the multisine cases: 300 s at 10 Hz --------------------------------------------------------
MS = Multisine(period_s=100.0, f_lo=0.05, f_hi=1.0, rms_deg=5.0)
T10 = np.arange(3000) / 10.0
ErrorMaker = Callable[[NDArray[np.float64], NDArray[np.float64], np.random.Generator],
                      NDArray[np.float64]]


def coverage(make_error: ErrorMaker, true_sigma: float, records: int) -> float:
    """The share of ``records`` records whose σ interval holds ``true_sigma``."""
    x = MS.reference(T10)
    rng = np.random.default_rng(2024)
    hits = 0
    for _ in range(records):
        r = analyze(T10, x, T10, x + make_error(T10, x, rng))
        hits += r.sigma_ci95[0] <= true_sigma <= r.sigma_ci95[1]
    return hits / records


def multisine_gain_white(records: int) -> float:
    h, sn = gain(0.98), 0.1
    true_sigma = float(np.sqrt(MS.error_variance(h) + sn**2))
    return coverage(lambda t, x, rng: MS.through(h, t) - x + rng.normal(0, sn, t.size),
                    true_sigma, records)


def coloured_gaussian(records: int) -> float:
    a, sn = 0.6, 0.1  # AR(1) noise, variance sn²

    def err(t: NDArray[np.float64], x: NDArray[np.float64],
            rng: np.random.Generator) -> NDArray[np.float64]:
        e = rng.normal(0, sn * np.sqrt(1 - a * a), t.size + 200)
        return np.asarray(lfilter([1.0], [1.0, -a], e)[200:])

    return coverage(err, sn, records)


# -- the kinds of error: 900 s at 4 Hz ---------------------------------------------------------
FS4 = 4.0
N4 = 3600
T4 = np.arange(N4) / FS4


def _gaussian_band(rng: np.random.Generator, reps: int, f0: float, width: float,
                   sigma: float) -> NDArray[np.float64]:
    """Stationary Gaussian noise, density ∝ exp(−(f − f0)²/2w²), variance σ²: a window of a
    long circular record made by inverse FFT (so not periodic in the window)."""
    length = 8 * N4
    f = np.fft.rfftfreq(length, 1 / FS4)
    w = np.exp(-0.5 * ((f - f0) / width) ** 2)
    w[0] = 0.0
    w /= w.sum()
    z = (rng.normal(size=(reps, f.size)) + 1j * rng.normal(size=(reps, f.size))) * np.sqrt(w / 2)
    x = np.fft.irfft(z, length, axis=1) * length / np.sqrt(2) * sigma
    start = rng.integers(0, length - N4, reps)
    return np.stack([x[i, s : s + N4] for i, s in enumerate(start)])


def _ar1(rng: np.random.Generator, reps: int, corner_hz: float,
         sigma: float) -> NDArray[np.float64]:
    """First-order low-pass noise (corner ``corner_hz``), stationary from the first sample."""
    a = np.exp(-2 * np.pi * corner_hz / FS4)
    e = rng.normal(0, sigma * np.sqrt(1 - a * a), (reps, N4))
    return np.asarray(
        lfilter([1.0], [1.0, -a], e, axis=1, zi=rng.normal(0, sigma, (reps, 1)) * a)[0])


KINDS = {
    # white noise 0.1° beside a linear error of 0.05°
    "white": (gain(0.99), lambda rng, r: rng.normal(0, 0.1, (r, N4)), 0.1**2),
    # noise inside the motion's band (0.25 ± 0.05 Hz)
    "in_band": (gain(0.99), lambda rng, r: _gaussian_band(rng, r, 0.25, 0.05, 0.1), 0.1**2),
    # drift: corner 0.005 Hz (correlation time 32 s, near the 90 s max lag), 54 % of the
    # noise's variance beside white noise; the mean removal takes 2.9 % of σ² out
    "drift": (gain(0.99),
              lambda rng, r: np.sqrt(0.46) * rng.normal(0, 0.1, (r, N4))
              + _ar1(rng, r, 0.005, np.sqrt(0.54) * 0.1), 0.1**2),
    # 99.9 % linear: a 50 ms lag (0.91°) and 0.03° white noise
    "linear": (first_order(0.05), lambda rng, r: rng.normal(0, 0.03, (r, N4)), 0.03**2),
}
# -- non-stationary kinds: 900 s at 4 Hz in 9 periods of 100 s ---------------------------------
# The truth is σ of the process: the root mean square about the record's mean that tests of
# this length give on average (README, "σ of the process").
WALK_AT_T = 0.1  # a random walk's standard deviation after the whole record, deg


def _walk(rng: np.random.Generator, reps: int) -> NDArray[np.float64]:
    """A random walk from 0 (steps of equal variance), beside white noise 0.1°."""
    steps = rng.normal(0.0, WALK_AT_T / np.sqrt(N4), (reps, N4))
    return np.cumsum(steps, axis=1) + rng.normal(0.0, 0.1, (reps, N4))


#: a random walk of variance q² over the record, mean removed, has E = q²/6·(1 − 1/N²)
WALK_VARIANCE = WALK_AT_T**2 / 6.0 * (1.0 - 1.0 / N4**2) + 0.1**2 * (1.0 - 1.0 / N4)
MOD_DEPTH, MOD_HZ, MOD_GAIN, MOD_NOISE = 0.01, 0.003, 0.99, 0.03


def modulated_error(x: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.float64]:
    """ε of a gain ``0.99·(1 + 0.01 sin(2π·0.003 t + φ))``, φ uniform (the modulation is
    not locked to the test's start), and white noise 0.03°."""
    phase = rng.uniform(0.0, 2.0 * np.pi)
    g = MOD_GAIN * (1.0 + MOD_DEPTH * np.sin(2.0 * np.pi * MOD_HZ * T4 + phase))
    return (g - 1.0) * x + rng.normal(0.0, MOD_NOISE, N4)


def modulated_variance(x: NDArray[np.float64]) -> float:
    """E over φ of the record's mean square about its mean: the modulated gain's error
    averaged over a 720-point quadrature of φ, plus the white noise's variance."""
    phases = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)
    total = 0.0
    for ph in phases:
        e = (MOD_GAIN * (1.0 + MOD_DEPTH * np.sin(2.0 * np.pi * MOD_HZ * T4 + ph)) - 1.0) * x
        total += float(np.var(e))
    return total / len(phases) + MOD_NOISE**2 * (1.0 - 1.0 / N4)


def nonstationary_coverage(kind: str, records: int,
                           period: float = 100.0) -> tuple[float, float, float, float, float]:
    """(coverage, flagged share, mean σ̂/σ, width ratio, drift share) over ``records``
    records of a random walk (``walk``) or a modulated gain (``modulated``): the flagged share
    is the period-to-period test's, the drift share that of the drift flag
    (``uncertainty["drift"]["flagged"]``); the width ratio is the mean half-width of σ's
    interval over 1.96 × the spread (standard deviation) of σ̂; ``period`` 100 s (nine
    periods) or 900 s (one)."""
    ms = Multisine(period_s=period, f_lo=0.05, f_hi=1.0, rms_deg=5.0)
    opts = {"period_s": period} if period >= T4.size / FS4 else {}
    x = ms.reference(T4)
    rng = np.random.default_rng(31 + len(kind))
    if kind == "walk":
        y0 = ms.through(gain(0.99), T4)
        truth = np.sqrt(ms.error_variance(gain(0.99)) + WALK_VARIANCE)
        errs = _walk(rng, records)
    else:
        y0 = x
        truth = np.sqrt(modulated_variance(x))
        errs = np.stack([modulated_error(x, rng) for _ in range(records)])
    hits = flagged = drifts = 0
    sig = np.empty(records)
    half = np.empty(records)
    for i in range(records):
        r = analyze(T4, x, T4, y0 + errs[i], **opts)
        lo, hi = r.sigma_ci95
        hits += lo <= truth <= hi
        st = r.uncertainty["stationarity"]
        flagged += st is not None and not st["stationary"]
        drifts += drift_flagged(r)
        sig[i], half[i] = r.sigma, (hi - lo) / 2.0
    return (hits / records, flagged / records, float(sig.mean() / truth),
            float(half.mean() / (1.959964 * sig.std(ddof=1))), drifts / records)


def drift_flagged(r: AnalysisResult) -> bool:
    """Whether the analysis flagged a drift (``uncertainty["drift"]``)."""
    d = r.uncertainty.get("drift")
    return bool(d is not None and d["flagged"])


#: the kinds that depend on the noise at the lines: checked on one-period records too
ONE_PERIOD_KINDS = ("in_band", "linear")


def kind_coverage(kind: str, period: float,
                  records: int) -> tuple[float, float, float, float]:
    """(coverage, mean σ̂/σ, standard error of that mean, drift share) of the σ interval over
    ``records`` records of one kind; the drift share: how often a drift was flagged."""
    ms = Multisine(period_s=period, f_lo=0.05, f_hi=1.0, rms_deg=5.0)
    h, make, noise_var = KINDS[kind]
    x, y0 = ms.reference(T4), ms.through(h, T4)
    truth = np.sqrt(ms.error_variance(h) + noise_var)
    noise = make(np.random.default_rng(20240 + len(kind)), records)
    opts = {"period_s": period} if period >= T4.size / FS4 else {}
    hits = drifts = 0
    ratios = np.empty(records)
    for i in range(records):
        r = analyze(T4, x, T4, y0 + noise[i], **opts)
        if r.uncertainty["method"] != "lines":
            raise AssertionError(f"{kind}: not the line-wise estimate ({r.uncertainty['method']})")
        hits += r.sigma_ci95[0] <= truth <= r.sigma_ci95[1]
        drifts += drift_flagged(r)
        ratios[i] = r.sigma / truth
    return (hits / records, float(ratios.mean()), float(ratios.std(ddof=1) / np.sqrt(records)),
            drifts / records)


def drift_mean_removal() -> float:
    """The share of σ² the mean removal takes from the drift kind's records: var(ε̄)/σ²."""
    a = np.exp(-2 * np.pi * 0.005 / FS4)
    lag = np.arange(1 - N4, N4)
    var_mean = 0.54 * 0.1**2 * np.sum((N4 - np.abs(lag)) * a ** np.abs(lag)) / N4**2
    truth2 = Multisine(100.0, 0.05, 1.0, 5.0).error_variance(gain(0.99)) + 0.1**2
    return float(var_mean / truth2)


#: the records of each case here, and in the suite (test_analysis_uncertainty.py)
LONG_RECORDS = {"multisine": 800, "coloured": 800, "kind": 1000, "one_period": 600}
SUITE_RECORDS = {"multisine": 300, "coloured": 300, "kind": 300, "one_period": 300}


def _show_flags(kind: str,
                res: tuple[float, float, float, float, float]) -> tuple[float, float]:
    print(f"  {kind}: flagged non-stationary (power period to period) in {res[1]:.3f} of the "
          f"records, a drift in {res[4]:.3f}; interval half-width / (1.96 × spread of σ̂) = "
          f"{res[3]:.2f}", flush=True)
    return res[0], res[2]


def _show_drift(kind: str, res: tuple[float, float, float, float]) -> tuple[float, float]:
    print(f"  {kind}: a drift flagged in {res[3]:.3f} of the records", flush=True)
    return res[0], res[1]


def binomial_sd(records: int, p: float = 0.95) -> float:
    return math.sqrt(p * (1 - p) / records)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--records", type=int, help="records per case (default: the long ones)")
    ap.add_argument("--case", action="append", help="only these cases (multisine, coloured, "
                    "white, in_band, drift, linear, in_band_1p, linear_1p, walk, modulated, "
                    "walk_1p, modulated_1p)")
    a = ap.parse_args(argv)
    cases: list[tuple[str, Callable[[int], tuple[float, float | None]], int]] = [
        ("multisine", lambda n: (multisine_gain_white(n), None), LONG_RECORDS["multisine"]),
        ("coloured", lambda n: (coloured_gaussian(n), None), LONG_RECORDS["coloured"]),
    ]
    for k in KINDS:
        cases.append((k, lambda n, k=k: _show_drift(k, kind_coverage(k, 100.0, n)),
                      LONG_RECORDS["kind"]))
    for k in ONE_PERIOD_KINDS:
        cases.append((f"{k}_1p", lambda n, k=k: _show_drift(f"{k}_1p",
                                                             kind_coverage(k, 900.0, n)),
                      LONG_RECORDS["one_period"]))
    for k in ("walk", "modulated"):
        cases.append((k, lambda n, k=k: _show_flags(k, nonstationary_coverage(k, n)),
                      LONG_RECORDS["kind"]))
        cases.append((f"{k}_1p", lambda n, k=k: _show_flags(
            f"{k}_1p", nonstationary_coverage(k, n, 900.0)), LONG_RECORDS["one_period"]))
    print(f"{'case':<12} {'records':>7} {'coverage':>9} {'± sd':>7} {'σ̂/σ':>8} {'s':>6}")
    for name, run, default in cases:
        if a.case and name not in a.case:
            continue
        n = a.records or default
        t0 = time.perf_counter()
        cov, ratio = run(n)
        shown = "" if ratio is None else f"{ratio:.4f}"
        print(f"{name:<12} {n:>7} {cov:>9.4f} {binomial_sd(n):>7.4f} {shown:>8} "
              f"{time.perf_counter() - t0:>6.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
