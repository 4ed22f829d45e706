"""Sustained setpoint streaming to the simulated stand over Modbus TCP and RTU: rate and jitter.

Each cycle starts on an absolute deadline t0 + k·T (host monotonic clock), sends one position
setpoint (FC16, both axes), reads the feedback block (FC3) and every 10th cycle writes the
heartbeat (FC6) — the stream mode's cycle; "+fc23" runs send the setpoint and read the feedback
in one FC23 request (``ModbusStand.send_setpoint_and_read``). A cycle that starts a whole
period late skips to the current slot (no burst of catch-up setpoints) and the skipped slots
are counted as slips.

The simulated stand runs in a child process (as ``benchctl sim`` would), so its physics and
server threads do not share this process's interpreter lock. The baseline is the same
scheduling loop with no I/O, measured in the same run.

    python benchmarks/stand_streaming.py    # 60 s each: baseline, TCP, TCP+FC23, RTU, RTU+FC23
    python benchmarks/stand_streaming.py --seconds 10 --rate-hz 50 --json
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import sys
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
MAP = ROOT / "drivers" / "stand_generic.yaml"
LIMITS = {"angle_deg": 20.0, "rate_deg_s": 30.0, "accel_deg_s2": 200.0}


def serve(transport: str, conn: Connection) -> None:
    """Child process: run a SimStand until told to stop; send its endpoint first."""
    from benchctl.config import SimStandConfig, StandLimits
    from benchctl.sim.stand import SimStand

    with SimStand(
        SimStandConfig(watchdog_s=2.0),
        limits=StandLimits(**LIMITS),
        register_map=MAP,
        transport="rtu" if transport == "rtu" else "tcp",
    ) as sim:
        conn.send({"port": sim.port, "serial_port": sim.serial_port, "endpoint": sim.endpoint})
        conn.recv()  # stop
        conn.send({"requests": sim.requests})


def run_loop(seconds: float, rate_hz: float, cycle: Callable[[int, float], None]) -> dict[str, Any]:
    """Absolute-deadline loop; returns lateness, periods, slips and cycle durations."""
    period = 1.0 / rate_hz
    n_slots = int(seconds * rate_hz)
    t0 = time.monotonic() + period
    k = 0
    t_prof = -period
    starts: list[float] = []
    late: list[float] = []
    busy: list[float] = []
    slips = 0
    while k < n_slots:
        deadline = t0 + k * period
        pause = deadline - time.monotonic()
        if pause > 0:
            time.sleep(pause)
        now = time.monotonic()
        lateness = now - deadline
        if lateness >= period:  # stalled: skip to the current slot, never burst
            skip = int(lateness / period)
            slips += skip
            k += skip
            deadline = t0 + k * period
            lateness = now - deadline
            if k >= n_slots:
                break
        t_prof = max(now - t0, t_prof + period)  # profile time: at least one period per setpoint
        starts.append(now)
        late.append(lateness)
        cycle(k, t_prof)
        busy.append(time.monotonic() - now)
        k += 1
    elapsed = time.monotonic() - t0
    periods = np.diff(starts)
    jitter = np.abs(periods - period)
    lat = np.asarray(late)
    return {
        "cycles": len(starts),
        "rate_hz": len(starts) / elapsed,
        "slips": slips,
        "period_jitter_ms": {
            "p50": 1e3 * float(np.percentile(jitter, 50)),
            "p99": 1e3 * float(np.percentile(jitter, 99)),
            "max": 1e3 * float(jitter.max()),
        },
        "start_late_ms": {
            "p50": 1e3 * float(np.percentile(lat, 50)),
            "p99": 1e3 * float(np.percentile(lat, 99)),
            "max": 1e3 * float(lat.max()),
        },
        "cycle_busy_ms": {
            "p50": 1e3 * float(np.percentile(busy, 50)),
            "p99": 1e3 * float(np.percentile(busy, 99)),
        },
    }


def baseline(seconds: float, rate_hz: float) -> dict[str, Any]:
    sink: list[float] = []
    return run_loop(seconds, rate_hz, lambda k, t: sink.append(math.sin(t)))


def streaming(transport: str, seconds: float, rate_hz: float, fc23: bool) -> dict[str, Any]:
    from benchctl.config import StandConfig
    from benchctl.devices.modbus import open_stand

    parent, child = mp.Pipe()
    proc = mp.get_context("spawn").Process(target=serve, args=(transport, child), daemon=True)
    proc.start()
    info = parent.recv()
    common = {
        "limits": LIMITS,
        "register_map": MAP,
        "timeout_s": 0.5,
        "retries": 0,
        "setpoint_rate_hz": rate_hz,
    }
    if transport == "tcp":
        cfg = StandConfig.model_validate({"driver": "modbus-tcp", "port": info["port"], **common})
    else:
        cfg = StandConfig.model_validate(
            {"driver": "modbus-rtu", "serial_port": info["serial_port"], **common}
        )
    stand = open_stand(cfg)
    rtts: list[float] = []
    try:
        stand.connect()
        stand.enable()
        amp, f = 5.0, 0.2

        def cycle(k: int, t: float) -> None:
            x = amp * (1.0 - math.cos(2 * math.pi * f * t)) / 2.0  # starts at rest
            if fc23:
                rtts.append(stand.send_setpoint_and_read({"roll": x, "pitch": -x})[1].rtt_s)
            else:
                stand.send_setpoint({"roll": x, "pitch": -x})
                rtts.append(stand.read_sample().rtt_s)
            if k % 10 == 0:
                stand.heartbeat()

        out = run_loop(seconds, rate_hz, cycle)
        stand.ramp_to_zero(timeout_s=10)
        stand.disable()
    finally:
        stand.close()
        parent.send("stop")
        served = parent.recv()
        proc.join(timeout=10)
    r = np.asarray(rtts)
    out["read_rtt_ms"] = {
        "p50": 1e3 * float(np.percentile(r, 50)),
        "p99": 1e3 * float(np.percentile(r, 99)),
    }
    out["endpoint"] = info["endpoint"]
    out["requests_served"] = served["requests"]
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--seconds", type=float, default=60.0, help="duration of each run (default 60)")
    ap.add_argument("--rate-hz", type=float, default=100.0, help="setpoint rate (default 100)")
    ap.add_argument("--transports", default="tcp,rtu", help="comma list of tcp, rtu")
    ap.add_argument(
        "--cycle",
        choices=("separate", "fc23", "both"),
        default="both",
        help="setpoint write and feedback read as two requests (FC16 + FC3), as one "
        "(FC23), or both in turn (default)",
    )
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    args = ap.parse_args(argv)
    results: dict[str, Any] = {"seconds": args.seconds, "rate_hz_nominal": args.rate_hz}
    results["baseline"] = baseline(args.seconds, args.rate_hz)
    runs: list[str] = []
    for tr in args.transports.split(","):
        for fc23 in {"separate": [False], "fc23": [True], "both": [False, True]}[args.cycle]:
            name = f"{tr}+fc23" if fc23 else tr
            results[name] = streaming(tr, args.seconds, args.rate_hz, fc23)
            runs.append(name)
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    print(f"setpoint streaming at {args.rate_hz:g} Hz nominal, {args.seconds:g} s per run")
    print(
        f"{'run':10} {'rate Hz':>8} {'slips':>6} {'jit p50':>8} {'jit p99':>8} {'jit max':>8} "
        f"{'late p50':>8} {'late p99':>8} {'busy p50':>8} {'busy p99':>8} "
        f"{'rtt p50':>8} {'rtt p99':>8}"
    )
    for name in ("baseline", *runs):
        r = results[name]
        rtt = r.get("read_rtt_ms", {"p50": float("nan"), "p99": float("nan")})
        print(
            f"{name:10} {r['rate_hz']:8.2f} {r['slips']:6d} {r['period_jitter_ms']['p50']:8.3f} "
            f"{r['period_jitter_ms']['p99']:8.3f} {r['period_jitter_ms']['max']:8.2f} "
            f"{r['start_late_ms']['p50']:8.3f} {r['start_late_ms']['p99']:8.3f} "
            f"{r['cycle_busy_ms']['p50']:8.3f} {r['cycle_busy_ms']['p99']:8.3f} "
            f"{rtt['p50']:8.3f} {rtt['p99']:8.3f}"
        )
    print(
        "(ms; jitter = |period between cycle starts − T|; late = start after its deadline; "
        "busy = setpoint write + feedback read (+ heartbeat); rtt = feedback read round trip "
        "(+fc23: of the combined write+read))"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
