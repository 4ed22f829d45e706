"""Figures for clocks that drift and for timing by default.

Every figure is with the default options of ``benchctl analyze`` (nothing about time bases
given), against a truth computed independently of the analysis: the instrument is a known
linear system (gain 0.995, 80 ms first-order lag, 10 ms delay) applied line by line to a
multisine (lines k/100 s, 0.05 … 0.6 Hz, 5° rms), plus white noise, so
``σ² = Σ (A_k²/2)|1 − H(f_k)|² + σ_n²`` exactly.

1. **Skew**: the instrument's stamps from its own clock, fast by 0, 50, 200 ppm (and slow by
   200), on a two-CSV record (reference 100 Hz on the host's clock, instrument 50 Hz, 900 s):
   σ's error and the skew read against the truth; periodic (period detected) and not (one
   900 s period, nothing to detect).
   Then a delay that changes slowly: the clock's rate ramping from 0 to 200 ppm over the
   record (a parabola, 90 ms at the end), or wandering up to ±200 ppm and back (a delay
   ``A(1 − cos 2πt/T)``, 57 ms at its peak).
2. **Jittered CSV**: 1.15 ms rms jitter on both streams' stamps, a 0.027° instrument (a
   gain error orthogonal noise only) at 5°/s rms roll rate, 100 Hz, 300 s: σ's error by
   default and as given.
3. **Coverage** (``--coverage N``): N records of 300 s, 2 ms rms jitter on both streams
   (reference 50 Hz, instrument 20 Hz, the lagging instrument above with 0.02° noise),
   the share of σ's 95 % intervals holding the truth, by default and with the stamps forced
   as given.

4. **Skew coverage** (``--skew-coverage N``): N records per case (50 and 200 ppm, periodic or
   not; each its own motion and noise): the skew's error, σ's error, the share of σ's 95 %
   intervals holding the truth and their mean width over the spread of σ (×3.92).

    python benchmarks/timing_drift.py [--coverage 200] [--skew-coverage 40] [--csv]

``--csv`` runs the skew and jitter cases through ``benchctl analyze`` on CSV files instead of
the Python API (the same numbers; slower).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from analysis_synthetic import Multisine, delay, first_order, orthogonal_noise

from benchctl.analysis import analyze

FloatArray = np.ndarray
MS = Multisine(period_s=100.0, f_lo=0.05, f_hi=0.6, rms_deg=5.0)


def lagging(f: FloatArray) -> FloatArray:
    """The instrument: gain 0.995, 80 ms first-order lag, 10 ms delay."""
    return 0.995 * first_order(0.08)(f) * delay(0.01)(f)


def slowly(kind: str, ms: Multisine = MS, span: float = 900.0) -> tuple[tuple[FloatArray, ...],
                                                                         float]:
    """The instrument's stamps delayed by a curve: its clock's rate ramping from 0 to 200 ppm
    (``ramp``) or wandering up to ±200 ppm and back (``wander``); the true σ."""
    (tr, x, td, y), truth = skewed(0.0, ms, span=span)
    u = td - td[0]
    if kind == "ramp":
        delay = 200e-6 * u**2 / (2 * span)
    else:
        delay = 200e-6 * span / (2 * np.pi) * (1 - np.cos(2 * np.pi * u / span))
    return (tr, x, td + delay, y), truth


def skewed(ppm: float, ms: Multisine = MS, span: float = 900.0, noise: float = 0.05,
           seed: int = 0) -> tuple[tuple[FloatArray, ...], float]:
    """(t_ref, x, stamps of the instrument, y) with the instrument's clock fast by ``ppm``,
    and the true σ."""
    rng = np.random.default_rng(seed)
    tr = 1000.0 + np.arange(-100, int(span * 100.0) + 100) / 100.0
    td = 1000.0 + np.arange(int(span * 50.0)) / 50.0
    y0 = ms.through(lagging, td)
    y = y0 + orthogonal_noise(rng, noise, y0)
    stamps = td[0] + (td - td[0]) * (1.0 + ppm * 1e-6)
    truth = math.sqrt(ms.error_variance(lagging) + noise**2)
    return (tr, ms.reference(tr), stamps, y), truth


RATE_1 = Multisine(period_s=100.0, f_lo=0.05, f_hi=0.6, rms_deg=1.0)
ROLL_5 = Multisine(period_s=100.0, f_lo=0.05, f_hi=0.6, rms_deg=5.0 / math.sqrt(float(
    np.sum((RATE_1.amps * 2 * np.pi * RATE_1.freqs) ** 2 / 2))))


def jittered_streams(jitter_s: float = 1.15e-3, seed: int = 3) -> tuple[FloatArray, ...]:
    """A 0.027° instrument (noise only) at 5°/s rms, 100 Hz, 300 s: (the reference's true
    instants, its angle, the instrument's true instants, its angle, both streams' stamps
    jittered by ``jitter_s`` rms)."""
    rng = np.random.default_rng(seed)
    t = 1000.0 + np.arange(30_000) / 100.0
    tr = 1000.0 + np.arange(-100, 30_100) / 100.0
    y0 = ROLL_5.reference(t)
    y = y0 + orthogonal_noise(rng, 0.027, y0)
    jr = tr + rng.normal(0.0, jitter_s, tr.size)
    jd = t + rng.normal(0.0, jitter_s, t.size)
    return tr, ROLL_5.reference(tr), t, y, jr, jd


def jittered(jitter_s: float = 1.15e-3, seed: int = 3) -> tuple[tuple[FloatArray, ...], float]:
    """``jittered_streams`` as the stamps give them; the true σ 0.027°."""
    _, x, _, y, jr, jd = jittered_streams(jitter_s, seed)
    return (jr, x, jd, y), 0.027


def coverage_record(seed: int, jitter_s: float = 2e-3) -> tuple[tuple[FloatArray, ...], float]:
    """300 s, reference 50 Hz, instrument 20 Hz, the lagging instrument with 0.02° white
    noise (a new draw per seed), both streams' stamps jittered by ``jitter_s`` rms; the truth
    is the process's σ."""
    rng = np.random.default_rng(1000 + seed)
    tr = 1000.0 + np.arange(-50, 300 * 50 + 50) / 50.0
    td = 1000.0 + np.arange(300 * 20) / 20.0
    noise = 0.02
    y = MS.through(lagging, td) + rng.normal(0.0, noise, td.size)
    truth = math.sqrt(MS.error_variance(lagging) + noise**2)
    return (tr + rng.normal(0.0, jitter_s, tr.size), MS.reference(tr),
            td + rng.normal(0.0, jitter_s, td.size), y), truth


def via_cli(rec: tuple[FloatArray, ...], extra: list[str]) -> dict:
    """``benchctl analyze --reference ref.csv --device dev.csv --json`` on the record."""
    from benchctl.cli import main

    with tempfile.TemporaryDirectory() as d:
        ref, dev = Path(d) / "ref.csv", Path(d) / "dev.csv"
        np.savetxt(ref, np.column_stack(rec[:2]), delimiter=",", header="time,angle",
                   comments="", fmt="%.9f")
        np.savetxt(dev, np.column_stack(rec[2:]), delimiter=",", header="time,angle",
                   comments="", fmt="%.9f")
        import contextlib
        import io

        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            code = main(["analyze", "--reference", str(ref), "--device", str(dev), "--json",
                         *extra])
        if code not in (0, 1):
            raise SystemExit(f"benchctl analyze exited {code}")
        return dict(json.loads(buf.getvalue()))


def measure(rec: tuple[FloatArray, ...], csv: bool, **kw: str) -> tuple[float, dict, list]:
    if csv:
        extra = [f"--{k.replace('_', '-')}={v}" for k, v in kw.items()]
        out = via_cli(rec, extra)
        return float(out["sigma"]), out["timing"], out["sigma_ci95"]
    r = analyze(*rec, **kw)  # type: ignore[arg-type]
    return r.sigma, r.timing, list(r.sigma_ci95)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--coverage", type=int, default=0, metavar="N",
                    help="also the coverage of σ's interval over N jittered records")
    ap.add_argument("--skew-coverage", type=int, default=0, metavar="N",
                    help="also the skew cases over N records each")
    ap.add_argument("--csv", action="store_true", help="through benchctl analyze on CSVs")
    a = ap.parse_args(argv)
    print("1. instrument clock skew, default options (900 s, reference 100 Hz, instrument 50 Hz,"
          " gain 0.995, lag 80 ms, delay 10 ms, 0.05° noise)")
    print(f"   {'motion':<22}{'true ppm':>9}{'read ppm':>10}{'95 %':>20}{'σ error':>10}")
    for label, ms in (("periodic (detected)", MS),
                      ("one 900 s period", Multisine(900.0, 0.05, 0.6, 5.0, seed=3))):
        for ppm in (0.0, 50.0, 200.0, -200.0):
            rec, truth = skewed(ppm, ms)
            sigma, tm, _ = measure(rec, a.csv)
            lo, hi = tm["skew_ci95_ppm"]
            mark = "" if tm["skew_corrected"] else " (not corrected)"
            print(f"   {label:<22}{ppm:>9.0f}{tm['skew_ppm']:>10.2f}{lo:>10.2f} … {hi:<7.2f}"
                  f"{100 * (sigma / truth - 1):>+9.3f} %{mark}")
    print(f"   {'motion':<22}{'clock rate':<26}{'degree':>7}{'mean ppm':>10}{'σ error':>10}")
    for label, ms in (("periodic (detected)", MS),
                      ("one 900 s period", Multisine(900.0, 0.05, 0.6, 5.0, seed=3))):
        for kind, what in (("ramp", "ramping 0 → 200 ppm"), ("wander", "wandering ±200 ppm")):
            rec, truth = slowly(kind, ms)
            sigma, tm, _ = measure(rec, a.csv)
            deg = tm.get("skew_degree") if tm["skew_corrected"] else "-"
            print(f"   {label:<22}{what:<26}{deg!s:>7}{tm['skew_ppm']:>10.2f}"
                  f"{100 * (sigma / truth - 1):>+9.3f} %")
    print("2. CSV with 1.15 ms rms jitter on both streams, 0.027° instrument, 5°/s rms, 100 Hz,"
          " 300 s")
    rec, truth = jittered()
    for label, kw in (("default (auto)", {}),
                      ("as given", {"timebase": "given", "reference_timebase": "given"})):
        sigma, tm, ci = measure(rec, a.csv, **kw)
        ch = tm["timebase_choice"]
        print(f"   {label:<16} σ {100 * (sigma / truth - 1):+.3f} %  time bases "
              f"{ch['device']['used']}/{ch['reference']['used']}  stamps' share of the scatter "
              f"{ch['device']['stamp_share']:.3f}/{ch['reference']['stamp_share']:.3f}  "
              f"interval {ci[0]:.5g} … {ci[1]:.5g}° (truth {truth:g})")
    if a.coverage:
        print(f"3. coverage of σ's 95 % interval, {a.coverage} records of 300 s, 2 ms rms jitter "
              "on both streams (reference 50 Hz, instrument 20 Hz, lagging, 0.02° noise)")
        t0 = time.time()
        for label, kw in (("default (auto)", {}),
                          ("as given", {"timebase": "given", "reference_timebase": "given"})):
            hits, errs = 0, []
            for seed in range(a.coverage):
                rec, truth = coverage_record(seed)
                sigma, _, ci = measure(rec, False, **kw)
                hits += ci[0] <= truth <= ci[1]
                errs.append(sigma / truth - 1)
            print(f"   {label:<16} coverage {hits / a.coverage:.3f}  mean σ error "
                  f"{100 * float(np.mean(errs)):+.3f} %  ({time.time() - t0:.0f} s)")
    if a.skew_coverage:
        n = a.skew_coverage
        print(f"4. skew over {n} records per case (each its own motion and noise), default options")
        for ppm in (50.0, 200.0):
            for label, period in (("periodic", 100.0), ("one 900 s period", 900.0)):
                hits, dskew, errs, width = 0, [], [], []
                for seed in range(n):
                    rec, truth = skewed(ppm, Multisine(period, 0.05, 0.6, 5.0, seed=seed),
                                        seed=seed)
                    sigma, tm, ci = measure(rec, False)
                    hits += ci[0] <= truth <= ci[1]
                    dskew.append(tm["skew_ppm"] - ppm)
                    errs.append(sigma / truth - 1)
                    width.append((ci[1] - ci[0]) / truth)
                e = np.asarray(errs)
                print(f"   {ppm:>5.0f} ppm {label:<18} skew error {np.mean(dskew):+.3f} ± "
                      f"{np.std(dskew):.3f} ppm  σ error {100 * e.mean():+.3f} ± "
                      f"{100 * e.std():.3f} % (max {100 * np.abs(e).max():.3f} %)  coverage "
                      f"{hits / n:.3f}  width / spread {np.mean(width) / (3.92 * e.std()):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
