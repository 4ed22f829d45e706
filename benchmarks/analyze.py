"""Benchmark `benchctl analyze --json` on a 15-minute, 1 kHz record (900 000 samples/channel).

Makes the CSV (time,reference,device: a multisine through a first-order lag plus noise) in a
temporary folder, then runs, each as its own subprocess and in alternation (best of REPEATS, 7:
the baseline's own time swings by a third between runs on a shared machine):

- ``benchctl analyze FILE --json`` (the product), stdout to a file;
- the baseline: a Python process that reads the same CSV with ``numpy.loadtxt`` and runs one
  ``scipy.signal.welch`` of ε = device − reference.

Wall time from ``time.perf_counter`` around the subprocess; peak RSS from
``os.wait4``'s rusage (``ru_maxrss``, KiB on Linux) of that child alone.

Two records: 15 periods of a 60 s multisine and one period of a 900 s one (lines over
0.05 … 1.2 Hz each), analysed with ``--period``.

Run: ``python benchmarks/analyze.py``
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

FS = 1000.0
DURATION_S = 900.0
REPEATS = 7

BASELINE = """
import sys
import numpy as np
from scipy.signal import welch
d = np.loadtxt(sys.argv[1], delimiter=",", skiprows=1)
eps = d[:, 2] - d[:, 1]
f, p = welch(eps, fs=1.0 / np.median(np.diff(d[:, 0])), nperseg=1 << 16)
print(float(np.sum(p) * (f[1] - f[0])))
"""


#: the records: name → the multisine's period (s): lines k/T over 0.05 … 1.2 Hz
RECORDS = {"15 periods of 60 s": 60.0, "one period of 900 s": 900.0}


def make_csv(path: Path, period_s: float) -> None:
    n = int(FS * DURATION_S)
    t = np.arange(n) / FS
    rng = np.random.default_rng(0)
    k = np.arange(round(0.05 * period_s), round(1.2 * period_s) + 1)  # 0.05 … 1.2 Hz
    f = k / period_s
    amp = np.full(k.size, 5.0 * np.sqrt(2.0 / k.size))
    ph = rng.uniform(0, 2 * np.pi, k.size)
    h = 1.0 / (1.0 + 2j * np.pi * f * 0.05)
    x = np.zeros(n)
    y = np.zeros(n)
    for a, fk, p, hk in zip(amp, f, ph, h, strict=True):
        x += a * np.cos(2 * np.pi * fk * t + p)
        y += a * abs(hk) * np.cos(2 * np.pi * fk * t + p + np.angle(hk))
    y += rng.normal(0, 0.05, n)
    with path.open("w", encoding="ascii") as fh:
        fh.write("time,reference,device\n")
        np.savetxt(fh, np.column_stack((t, x, y)), delimiter=",", fmt="%.6f,%.6f,%.6f")


def measure(argv: list[str], out: Path) -> tuple[float, float, int]:
    """(wall s, peak RSS MiB, exit code) of one child process."""
    with out.open("wb") as fh:
        t0 = time.perf_counter()
        proc = subprocess.Popen(argv, stdout=fh, stderr=subprocess.PIPE)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    assert proc.stderr is not None
    err = proc.stderr.read().decode()
    proc.stderr.close()
    if proc.returncode != 0:
        print(err, file=sys.stderr)
    return wall, usage.ru_maxrss / 1024.0, proc.returncode


def main() -> int:
    worst = 0
    for name, period in RECORDS.items():
        print(f"--- {name}")
        worst = max(worst, one_record(period))
    return worst


def one_record(period_s: float) -> int:
    benchctl = Path(sys.executable).with_name("benchctl")
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "record.csv"
        t0 = time.perf_counter()
        make_csv(csv, period_s)
        print(f"record: {csv.stat().st_size / 1e6:.1f} MB, {int(FS * DURATION_S)} samples "
              f"per channel, made in {time.perf_counter() - t0:.1f} s")
        runs: dict[str, list[tuple[float, float]]] = {"benchctl": [], "baseline": []}
        cmds = {
            "benchctl": [str(benchctl), "analyze", str(csv), "--json", "--period",
                         f"{period_s:g}"],
            "baseline": [sys.executable, "-c", BASELINE, str(csv)],
        }
        for _ in range(REPEATS):
            for name, argv in cmds.items():
                wall, rss, code = measure(argv, Path(tmp) / f"{name}.out")
                if code != 0:
                    print(f"{name} failed with exit code {code}")
                    return 1
                runs[name].append((wall, rss))
        size = (Path(tmp) / "benchctl.out").stat().st_size
        best = {name: min(r[0] for r in rs) for name, rs in runs.items()}
        peak = {name: max(r[1] for r in rs) for name, rs in runs.items()}
        print(f"benchctl analyze --json: wall {best['benchctl']:.2f} s (best of {REPEATS}), "
              f"peak RSS {peak['benchctl']:.0f} MiB, JSON {size / 1e6:.1f} MB")
        print(f"baseline loadtxt + welch: wall {best['baseline']:.2f} s (best of {REPEATS}), "
              f"peak RSS {peak['baseline']:.0f} MiB")
        print(f"ratio: wall {best['benchctl'] / best['baseline']:.2f}x, "
              f"memory {peak['benchctl'] / peak['baseline']:.2f}x "
              f"(goal: wall within 1.3x of the baseline, memory within 1.6x)")
        load = os.getloadavg()  # the machine's load as measured: 2 shared cores, say
        print(f"load average: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f} (1, 5, 15 min) "
              f"on {os.cpu_count()} cores")
    return 0


if __name__ == "__main__":
    sys.exit(main())
