"""Figures for the profiles issue: synthesis time of a 15-minute 1 kHz motion, and the
target-vs-synthesised band variance error of every profile in the library.

    python benchmarks/synthesis.py

Timing: the fast path (inverse FFT over one period T_p, tiled; exact because 1 kHz x T_p is an
integer) against the baseline measured in the same run, the direct sum of cosines of
``HarmonicTable.evaluate`` on the same grid; the two are compared sample by sample.
Variance error: the synthesised motion sampled at 100 Hz over its steady part (whole periods),
its mean square compared with the target ∫_band G df computed independently by adaptive
quadrature (scipy.integrate.quad) of the target density.
"""

from __future__ import annotations

import itertools
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy import integrate

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchctl.profiles import (  # noqa: E402
    check_motion,
    load_profile,
    parse_profile,
    sample_times,
    synthesize,
)
from benchctl.profiles.motion import TableMotion  # noqa: E402

TIMED = ("paper_vessel_roll", "sea_state_4_small_vessel", "fast_craft_roll")


def best_of(fn, repeat: int = 3) -> float:  # type: ignore[no-untyped-def]
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def timing() -> None:
    from benchctl.config import StandLimits

    limits = StandLimits(angle_deg=30, rate_deg_s=30, accel_deg_s2=60)
    print("## Synthesis time, 15-minute motion at 1 kHz (900 001 samples), best of 3")
    print(
        f"{'profile':28s} {'lines':>5s} {'design':>8s} {'sample':>8s} {'check':>8s} "
        f"{'csv':>7s} {'baseline':>9s} {'speed-up':>8s} {'max diff':>9s}"
    )
    for name in TIMED:
        prof = load_profile(ROOT / "profiles" / f"{name}.yaml")
        t_design = best_of(lambda p=prof: synthesize(p, duration_s=900.0, setpoint_rate_hz=1000.0))
        motion = synthesize(prof, duration_s=900.0, setpoint_rate_hz=1000.0)
        t = sample_times(900.0, 1000.0)
        t_sample = best_of(lambda m=motion, t=t: m.evaluate(t))
        t_check = best_of(
            lambda m=motion: check_motion(m, limits, rate_hz=1000.0, scale_to_fit=True), 1
        )
        x = motion.evaluate(t)["roll"]
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "m.csv"
            table = np.column_stack([t, x])

            def write(out: Path = out, table: np.ndarray = table) -> None:
                np.savetxt(
                    out, table, fmt="%.6f", delimiter=",", header="time_s,roll_deg", comments=""
                )

            t_csv = best_of(write, 1)
        tab = motion.tables["roll"]  # type: ignore[index]
        t0 = time.perf_counter()
        direct = tab.evaluate(t)
        t_base = time.perf_counter() - t0
        diff = float(np.max(np.abs(direct - x)))
        print(
            f"{name:28s} {tab.n_lines:5d} {t_design:7.3f}s {t_sample:7.3f}s {t_check:7.3f}s "
            f"{t_csv:6.2f}s {t_base:8.2f}s {t_base / t_sample:7.0f}x {diff:9.1e}"
        )
    print(
        "design = profile -> lines, phases, crest; sample = angle at 1 kHz; check = angle, rate and"
    )
    print(
        "acceleration at 1 kHz against limits; csv = np.savetxt; baseline = direct sum (angle only)"
    )
    print()


def band_target(motion: TableMotion, axis: str) -> float:
    target = motion.targets[axis]
    assert target is not None
    lo, hi = target.band_hz
    edges = np.linspace(lo, hi, 41)
    return sum(
        integrate.quad(lambda f: float(target.psd(np.array([f]))[0]), a, b, limit=200)[0]
        for a, b in itertools.pairwise(edges)
    )


def steady_variance(motion: TableMotion, axis: str, rate: float = 100.0) -> float:
    tab = motion.tables[axis]
    n = round((tab.duration_s - tab.fade_in_s - tab.fade_out_s) * rate)
    t = tab.fade_in_s + np.arange(n) / rate
    x = motion.evaluate(t)[axis]
    return float(np.mean(x**2))


def variance_errors() -> None:
    print(
        "## Target vs synthesised band variance (samples at 100 Hz over the steady whole periods)"
    )
    print(
        f"{'profile':28s} {'axis':5s} {'lines':>5s} {'target deg²':>12s} {'cell err':>9s} "
        f"{'point err':>9s}"
    )
    for path in sorted((ROOT / "profiles").glob("*.yaml")):
        prof = load_profile(path)
        motion = synthesize(prof)
        if not isinstance(motion, TableMotion) or all(t is None for t in motion.targets.values()):
            print(
                f"{prof.name:28s} {'':5s} {'':5s} {'(no target spectrum: ' + prof.kind + ')':>31s}"
            )
            continue
        data = prof.spec.model_dump(mode="json")
        data["amplitudes"] = "point"
        point = synthesize(parse_profile(data, path))
        assert isinstance(point, TableMotion)
        for axis in motion.axes:
            target = band_target(motion, axis)
            e_cell = steady_variance(motion, axis) / target - 1
            e_point = steady_variance(point, axis) / target - 1
            print(
                f"{prof.name:28s} {axis:5s} {motion.tables[axis].n_lines:5d} {target:12.5f} "
                f"{100 * e_cell:+8.4f}% {100 * e_point:+8.4f}%"
            )
    print(
        "cell = A_k from the integral of G over each line's cell (the default); "
        "point = √(2 G(f_k) Δf)"
    )


if __name__ == "__main__":
    timing()
    variance_errors()
