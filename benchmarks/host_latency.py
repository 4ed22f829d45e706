"""The host fitness check's figures on this machine: unloaded, then beside N CPU-bound child
processes.

The same measurement a run makes before its motion (``benchctl.run.fitness.measure_host``, the
real clock): one thread per period (1 ms and 10 ms, the default stand loop's) asks to wake on
absolute deadlines for the window; each wake's lateness is printed as count, median, p99,
p99.9, max and wakes later than 0.1/1/10/100 ms, with the verdict against ``--config``'s stand.
``--priority P`` asks for SCHED_FIFO P in the measuring threads (and says whether it was
granted) — a third row set, loaded, at that priority.

Usage: python benchmarks/host_latency.py [--window 2] [--burners 2] [--config config/sim.yaml]
       [--priority 50] [--repeat 1]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from benchctl.clock import REAL
from benchctl.config import load_config
from benchctl.run.fitness import HostLatency, assess, measure_host, periods_s

ROOT = Path(__file__).resolve().parent.parent


def burners(n: int) -> list[subprocess.Popen[bytes]]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def row(label: str, period: float, lateness: list[float]) -> str:
    from benchctl.run.latency import lateness_stats

    s = lateness_stats(lateness, period, 0.0)
    over = " ".join(f"{n:5d}" for _, n in s.over)
    return (f"{label:<28} {period * 1e3:6g} {s.count:6d} {s.median_s * 1e3:8.3f} "
            f"{s.p99_s * 1e3:8.3f} {s.p999_s * 1e3:8.3f} {s.max_s * 1e3:8.3f}   {over}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--window", type=float, default=2.0, help="seconds per measurement")
    ap.add_argument("--burners", type=int, default=2, help="CPU-bound child processes")
    ap.add_argument("--config", type=Path, default=ROOT / "config" / "sim.yaml",
                    help="the bench config judged against (its stand's buffer and watchdog)")
    ap.add_argument("--priority", type=int, default=None,
                    help="also measure loaded at this SCHED_FIFO priority")
    ap.add_argument("--repeat", type=int, default=1, help="measurements per condition")
    args = ap.parse_args()
    cfg = load_config(args.config)
    periods = periods_s(cfg)
    print(f"host latency on this machine: {args.window:g} s windows, periods "
          f"{', '.join(f'{p * 1e3:g} ms' for p in periods)}; judged against {args.config}")
    print(f"{'condition':<28} {'period':>6} {'wakes':>6} {'median':>8} {'p99':>8} {'p99.9':>8} "
          f"{'max':>8}   >0.1ms  >1ms >10ms >0.1s   (ms)")
    conditions: list[tuple[str, int, int | None]] = [("unloaded", 0, None),
                                                     (f"{args.burners} CPU-bound children",
                                                      args.burners, None)]
    if args.priority is not None:
        conditions.append((f"{args.burners} children, FIFO {args.priority}", args.burners,
                           args.priority))
    verdicts: list[str] = []
    for label, n, prio in conditions:
        hogs = burners(n)
        try:
            time.sleep(0.5 if n else 0.0)  # the children running
            for i in range(args.repeat):
                got: HostLatency = measure_host(REAL, periods, args.window, REAL.event(), prio)
                tag = label if args.repeat == 1 else f"{label} #{i + 1}"
                for p in periods:
                    print(row(tag, p, got.series[p]))
                check = assess(cfg, got)
                verdicts.append(f"{tag}: {check.line}")
        finally:
            for h in hogs:
                h.kill()
                h.wait()
    print()
    print("\n".join(verdicts))
    return 0


if __name__ == "__main__":
    sys.exit(main())
