"""What one hand-over of the virtual clock's baton costs, with its threads on one CPU and free.

Two clock threads pass the baton back and forth through two events (``set`` then ``wait``), N
times each way: every pass is one hand-over between two operating-system threads, the step a
simulated run takes about 245 times per simulated second (the stand loop, the instrument's
reader, the simulators; 220 000 times in the paper's 15-minute test). Measured twice in one
process, alternating, so that both see the same load: ``VirtualClock(pin_cpu=True)`` (the
default: the threads kept on one CPU while the clock runs) and ``pin_cpu=False``. Printed: host
µs and CPU µs per hand-over, each the median of the rounds, and their ratio. The machine's load
average is printed before and after: this is a measurement on a shared machine.

Usage: python benchmarks/clock_handover.py [--n 20000] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from benchctl.clock.virtual import VirtualClock


def handovers(n: int, pin: bool) -> tuple[float, float]:
    """(host µs, CPU µs) per hand-over over ``2 n`` of them."""
    c = VirtualClock(pin_cpu=pin)
    with c.running():
        a, b = c.event(), c.event()

        def other() -> None:
            for _ in range(n):
                a.wait()
                a.clear()
                b.set()

        t = c.thread(other, name="other")
        t.start()
        wall0, cpu0 = time.perf_counter(), time.process_time()
        for _ in range(n):
            a.set()
            b.wait()
            b.clear()
        wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
        t.join()
    return wall / (2 * n) * 1e6, cpu / (2 * n) * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20000)
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    print(f"CPUs allowed: {sorted(os.sched_getaffinity(0))}; load average before: "
          + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    res: dict[bool, list[tuple[float, float]]] = {True: [], False: []}
    for r in range(a.rounds):
        for pin in (True, False):
            res[pin].append(handovers(a.n, pin))
            w, c = res[pin][-1]
            print(f"round {r + 1}: {'one CPU' if pin else 'free   '}  {w:7.1f} µs host, "
                  f"{c:7.1f} µs CPU per hand-over")
    med = {p: (statistics.median(x[0] for x in v), statistics.median(x[1] for x in v))
           for p, v in res.items()}
    print("load average after: " + " ".join(f"{x:.2f}" for x in os.getloadavg()))
    print(f"one CPU: {med[True][0]:.1f} µs host, {med[True][1]:.1f} µs CPU; free: "
          f"{med[False][0]:.1f} µs host, {med[False][1]:.1f} µs CPU (medians); one CPU ×"
          f"{med[False][0] / med[True][0]:.1f} as fast")


if __name__ == "__main__":
    main()
