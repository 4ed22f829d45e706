"""A whole `benchctl run` against the simulators at real time: its timing, losses and memory.

The simulated stand (Modbus TCP on loopback) and instrument (CANopen over slcan on a pty) run in
this process; `benchctl run --json` runs as a child process, exactly as an operator starts it,
and its memory is sampled every second. Printed:

- setpoint period jitter |Δt_send − T| p50/p99 and missed cycles (100 Hz), cycle lateness
  against the absolute deadlines p50/p99;
- instrument samples lost (counter gaps) and bad frames;
- stand-sample round trip p50/p99;
- overhead of the whole run beyond the profile's duration (start-up, prechecks, settling,
  analysis, report);
- peak RSS of the run process, and RSS at 10 %, 50 % and 90 % of the motion (flat = no growth);
- baselines in the same run: a bare 100 Hz absolute-deadline sleep loop (same missed-slot rule)
  for 10 s before the run, and in its own process for the whole run (the stalls this shared
  machine imposes on any 100 Hz loop meanwhile).

Usage: python benchmarks/run_full.py [--duration SEC] [--profile FILE] [--transport tcp|rtu]
(default: the paper's 15-minute profile, full length).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import yaml

from benchctl.config import (
    InstrumentConfig,
    SimInstrumentConfig,
    SimStandConfig,
    StandLimits,
)
from benchctl.recording import load_recording
from benchctl.sim.instrument import SimInstrument
from benchctl.sim.stand import SimStand

ROOT = Path(__file__).resolve().parent.parent
LIMITS = {"angle_deg": 30.0, "rate_deg_s": 30.0, "accel_deg_s2": 60.0}


def baseline_loop(seconds: float = 10.0, rate_hz: float = 100.0) -> dict[str, float]:
    """A bare absolute-deadline sleep loop (the machine's own scheduling noise), with the run
    loop's rule: a slot more than a quarter period late is missed."""
    period = 1.0 / rate_hz
    t0 = time.monotonic() + period
    late = []
    missed = 0
    k = 0
    while k * period < seconds:
        deadline = t0 + k * period
        pause = deadline - time.monotonic()
        if pause > 0:
            time.sleep(pause)
        lt = time.monotonic() - deadline
        if lt >= 0.25 * period:
            skip = int(lt / period) + 1
            missed += skip
            k += skip
            continue
        late.append(lt)
        k += 1
    a = np.array(late)
    return {"p50_ms": 1e3 * np.median(a), "p99_ms": 1e3 * np.quantile(a, 0.99), "missed": missed}


def concurrent_baseline(seconds: float) -> subprocess.Popen[str]:
    """The bare loop in its own process, for as long as the run: the stalls the machine imposes
    on any 100 Hz loop while the run goes."""
    here = str(Path(__file__).parent)
    code = (
        f"import json, sys; sys.path.insert(0, {here!r}); from run_full import baseline_loop; "
        f"print(json.dumps(baseline_loop({seconds!r})))"
    )
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--duration", type=float, help="profile duration (s); default the profile's")
    ap.add_argument("--profile", type=Path, default=ROOT / "profiles/paper_vessel_roll.yaml")
    ap.add_argument("--transport", choices=("tcp", "rtu"), default="tcp")
    ap.add_argument("--baseline-s", type=float, default=10.0)
    args = ap.parse_args()

    base = baseline_loop(args.baseline_s)
    tmp = Path(tempfile.mkdtemp(prefix="benchctl-run-full-"))
    sim_stand = SimStand(
        SimStandConfig(baudrate=460800),
        limits=StandLimits(**LIMITS),
        register_map=ROOT / "drivers/stand_generic.yaml",
        transport=args.transport,  # type: ignore[arg-type]
        port=0,
    )
    sim_stand.start()
    icfg = InstrumentConfig(
        driver="canopen",
        interface="slcan",
        channel="x",
        eds=ROOT / "drivers/cia410_inclinometer.eds",
    )
    sim_instr = SimInstrument(
        SimInstrumentConfig(lag_s=0.05, noise_deg=0.02, rate_hz=100.0), icfg, sim_stand
    )
    sim_instr.start()
    try:
        stand: dict[str, Any] = {
            "driver": f"modbus-{args.transport}",
            "register_map": str(ROOT / "drivers/stand_generic.yaml"),
            "limits": LIMITS,
        }
        if args.transport == "rtu":
            stand.update(serial_port=sim_stand.serial_port, baudrate=460800)
        else:
            stand.update(host="127.0.0.1", port=sim_stand.port)
        cfg = {
            "station": "benchmark",
            "stand": stand,
            "instrument": {
                "driver": "canopen",
                "interface": "slcan",
                "channel": sim_instr.instrument_config().channel,
                "eds": str(icfg.eds),
            },
            "run": {"limit_sigma_deg": 0.4, "output_dir": str(tmp / "runs")},
        }
        cfg_path = tmp / "bench.yaml"
        cfg_path.write_text(yaml.safe_dump(cfg))
        cmd = [sys.executable, "-m", "benchctl", "run", "--config", str(cfg_path)]
        cmd += [
            "--profile",
            str(args.profile),
            "--serial",
            "BENCH",
            "--operator",
            "bench",
            "--json",
        ]
        if args.duration:
            cmd += ["--duration", str(args.duration)]
        rss: list[tuple[float, int]] = []
        profile_s = args.duration or float(yaml.safe_load(args.profile.read_text())["duration_s"])
        side = concurrent_baseline(profile_s)
        t_start = time.monotonic()
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        ps = psutil.Process(proc.pid)
        stop = threading.Event()

        def sample() -> None:
            while not stop.wait(1.0):
                try:
                    rss.append((time.monotonic(), ps.memory_info().rss))
                except psutil.Error:
                    return

        th = threading.Thread(target=sample, daemon=True)
        th.start()
        out, err = proc.communicate()
        wall = time.monotonic() - t_start
        side_out, _ = side.communicate()
        conc = json.loads(side_out)
        stop.set()
        th.join()
    finally:
        sim_instr.stop()
        sim_stand.stop()
    if proc.returncode not in (0, 1):
        print(err[-3000:], file=sys.stderr)
        print(f"run ended with exit code {proc.returncode}", file=sys.stderr)
        return 2
    rep = json.loads(out)
    st = rep["stats"]
    rec = load_recording(rep["recording"])
    sp = rec.streams["setpoints"]["t_send"]
    period = 1.0 / 100.0
    jit = np.abs(np.diff(sp) - period)
    duration = float(rep["duration_s"])
    m0, m1 = st["motion_start"], st["motion_end"]
    rss_arr = np.array(rss, dtype=float)

    def rss_at(frac: float) -> float:
        t = m0 + frac * (m1 - m0)
        # child clock and ours are the same monotonic clock on one host
        i = int(np.argmin(np.abs(rss_arr[:, 0] - t)))
        return rss_arr[i, 1] / 1e6

    print(
        f"profile {rep['profile_name']} {duration:.0f} s, {args.transport}, "
        f"verdict {rep['verdict']}"
    )
    for a, v in rep["axes"].items():
        print(
            f"  σ {a} = {v['sigma']:.4f}° CI [{v['sigma_ci95'][0]:.4f}, {v['sigma_ci95'][1]:.4f}]"
        )
    lat, rtt = st["cycle_lateness_s"], st["stand_rtt_s"]
    print(f"setpoints sent {sp.size}, missed cycles {st['missed_cycles']}")
    print(
        f"setpoint period jitter |Δt−T|: p50 {1e3 * np.median(jit):.3f} ms, "
        f"p99 {1e3 * np.quantile(jit, 0.99):.3f} ms, max {1e3 * jit.max():.2f} ms"
    )
    print(
        f"cycle lateness vs absolute deadline: p50 {1e3 * lat['p50']:.3f} ms, "
        f"p99 {1e3 * lat['p99']:.3f} ms"
    )
    print(
        f"baseline (bare 100 Hz loop, before the run, {args.baseline_s:g} s): "
        f"lateness p50 {base['p50_ms']:.3f} ms, "
        f"p99 {base['p99_ms']:.3f} ms, missed {base['missed']}"
    )
    print(
        f"baseline (bare 100 Hz loop in its own process, during the run): "
        f"lateness p50 {conc['p50_ms']:.3f} ms, p99 {conc['p99_ms']:.3f} ms, "
        f"missed {conc['missed']}"
    )
    print(
        f"instrument samples {st['instrument_samples']}, lost {st['instrument_lost']}, "
        f"bad frames {st['instrument_bad_frames']}"
    )
    print(f"stand round trip: p50 {1e3 * rtt['p50']:.3f} ms, p99 {1e3 * rtt['p99']:.3f} ms")
    print(f"wall time {wall:.1f} s, overhead beyond the profile {wall - duration:.1f} s")
    print(
        f"run process RSS: peak {rss_arr[:, 1].max() / 1e6:.1f} MB; at 10/50/90 % of the motion "
        f"{rss_at(0.1):.1f} / {rss_at(0.5):.1f} / {rss_at(0.9):.1f} MB"
    )
    print(f"recording {rep['recording']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
