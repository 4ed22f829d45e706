"""σ of one instrument over the simulated stand on Modbus RTU and on Modbus TCP.

The same bench as the suite's end-to-end tests (`benchmarks/live_bench.py`: an instrument of
50 ms lag and 0.01° noise on CANopen over slcan, the 20 s `ROLL` profile, buffered mode), run in
this process `--pairs` times on each transport (RTU at `--baud`, 115 200 Bd by default). Printed per
run: σ, its line-wise value, the delay estimate and the reference's time base; then the RTU σ
against the TCP σ of the same pair (goal: within 0.5 %), and the instrument model's stated σ.

Usage: python benchmarks/rtu_vs_tcp.py [--pairs 3] [--baud 115200]
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

# benchmarks/live_bench.py: this script's folder is on sys.path when it is run
from live_bench import ROLL, expected_sigma, live_bench

from benchctl.run import RunOptions, run_test
from benchctl.run.prepare import prepare_motion


def one(tmp: Path, transport: str, baud: int) -> tuple[float, float]:
    tmp.mkdir(parents=True)
    profile = tmp / "profile.yaml"
    profile.write_text(ROLL)
    stand: dict[str, object] = {"mode": "buffered"}
    sim: dict[str, object] = {}
    if transport == "rtu":
        stand["baudrate"] = sim["baudrate"] = baud
    with live_bench(tmp, transport=transport, stand=stand, sim_stand=sim) as b:
        stated = expected_sigma(b, prepare_motion(b.cfg, profile, RunOptions("B", "b")).motion,
                                "roll")
        res = run_test(b.cfg, profile, RunOptions("RTU-TCP", "bench"))
    if res.recording is None or res.state != "done":
        raise SystemExit(f"{transport}: the run ended {res.state}: {res.reason}")
    axis = json.loads((res.recording / "report.json").read_text())["axes"]["roll"]
    a = axis["analysis"]
    print(f"  {transport}: σ {axis['sigma']:.5f}°  line-wise {a['lines']['sigma']:.5f}°  "
          f"delay {1e3 * axis['delay']:.2f} ms  reference time base "
          f"{a['timing']['reference_timebase']}", flush=True)
    return float(axis["sigma"]), stated


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--baud", type=int, default=115200)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="benchctl-rtu-tcp-") as d:
        for i in range(args.pairs):
            print(f"pair {i + 1}:")
            tcp, stated = one(Path(d) / f"tcp{i}", "tcp", args.baud)
            rtu, _ = one(Path(d) / f"rtu{i}", "rtu", args.baud)
            print(f"  RTU/TCP {rtu / tcp - 1:+.2%} (goal within ±0.5 %); the instrument's "
                  f"stated σ {stated:.5f}°")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
