"""The default simulated test, repeatedly, on a loaded machine with host stalls: aborts, σ, limits.

The simulators are built from `config/sim.yaml`'s own `sim:` section (the default bench) and run
in THIS process, so the stand's true motion is measured here; `benchctl run --json` runs as a
child process with the same stand/instrument/run settings pointed at them (buffered mode, as the
default config). Two CPU-bound processes run beside it for the whole benchmark, and the run
process is stopped (SIGSTOP) for 50–300 ms every 2–4 s of its motion, then continued.

First one run with neither load nor stalls gives the reference σ. Printed per loaded run and in
total: verdict, aborts (goal 0), the largest stand round trip (`rtt_s`: one Modbus exchange,
against the stand's reply timeout and watchdog), missed polls/slots, rejoins, buffer underruns,
the largest commanded step rate and acceleration (from the recorded setpoints, as the stand
plays them) and
the largest rate and acceleration the simulated stand measured while following (against the
limits: the goal is within them), the number and total length of the stalls, and σ against the
unloaded σ.

Usage: python benchmarks/run_under_load.py [--runs 5] [--duration 60] [--mode buffered|stream]
       [--profile FILE] [--no-load]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from benchctl.config import load_config
from benchctl.recording import load_recording
from benchctl.sim.instrument import SimInstrument
from benchctl.sim.stand import SimStand

ROOT = Path(__file__).resolve().parent.parent


def burners(n: int) -> list[subprocess.Popen[bytes]]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def stall_thread(
    pid: int, stop: threading.Event, started: threading.Event, seed: int
) -> tuple[threading.Thread, list[float]]:
    """SIGSTOP the run for 50–300 ms every 2–4 s once its motion has started."""
    stalls: list[float] = []
    rng = np.random.default_rng(seed)

    def run() -> None:
        started.wait()
        while not stop.wait(float(rng.uniform(2.0, 4.0))):
            d = float(rng.uniform(0.05, 0.3))
            try:
                os.kill(pid, signal.SIGSTOP)
                time.sleep(d)
                os.kill(pid, signal.SIGCONT)
            except ProcessLookupError:
                return
            stalls.append(d)

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th, stalls


def commanded_peaks(rec: Any, axis: str, period: float) -> tuple[float, float]:
    """Largest |rate| and |acceleration| of the recorded setpoints, one period apart as the
    stand plays them (from rest after a hold: a gap of more than one slot)."""
    sp = rec.streams["setpoints"]
    x = sp[f"{axis}_deg"]
    t_slot = sp["t_slot"]
    ok = np.isfinite(t_slot)
    x, t_slot = x[ok], t_slot[ok]
    if x.size < 3:
        return 0.0, 0.0
    v = np.diff(x) / period
    gap = np.diff(t_slot) > 1.5 * period
    v_prev = np.concatenate([[0.0], v[:-1]])
    v_prev[gap] = 0.0
    return float(np.max(np.abs(v))), float(np.max(np.abs((v - v_prev) / period)))


def one_run(
    cfg_path: Path, args: argparse.Namespace, stand: SimStand, stalls_on: bool, seed: int
) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "benchctl", "run", "--config", str(cfg_path)]
    cmd += ["--profile", str(args.profile), "--serial", "LOAD", "--operator", "bench"]
    cmd += ["--json", "--quiet", "--duration", str(args.duration)]
    stand.peaks(reset=True)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    started, stop = threading.Event(), threading.Event()
    th, stalls = stall_thread(proc.pid, stop, started, seed)
    if stalls_on:
        out_dir = Path(yaml.safe_load(cfg_path.read_text())["run"]["output_dir"])
        before = set(out_dir.glob("*"))

        def watch() -> None:
            while proc.poll() is None and not started.is_set():
                for d in set(out_dir.glob("*")) - before:
                    ev = d / "events.jsonl"
                    if ev.is_file() and '"motion_start"' in ev.read_text():
                        started.set()
                time.sleep(0.05)

        threading.Thread(target=watch, daemon=True).start()
    out, err = proc.communicate()
    stop.set()
    started.set()
    th.join()
    peaks = stand.peaks()
    try:
        rep = json.loads(out)
    except json.JSONDecodeError:
        return {"code": proc.returncode, "error": err[-2000:], "stalls": stalls, "peaks": peaks}
    return {"code": proc.returncode, "rep": rep, "stalls": stalls, "peaks": peaks}


def main() -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--profile", type=Path, default=ROOT / "profiles/paper_vessel_roll.yaml")
    ap.add_argument("--mode", choices=("buffered", "stream"), default="buffered")
    ap.add_argument("--no-load", action="store_true", help="no CPU burners, no stalls")
    args = ap.parse_args()

    base = load_config(ROOT / "config/sim.yaml")
    assert base.sim is not None
    tmp = Path(tempfile.mkdtemp(prefix="benchctl-load-"))
    sim_stand = SimStand(
        base.sim.stand,
        limits=base.stand.limits,
        register_map=base.stand.register_map,
        transport="tcp",
        port=0,
    )
    sim_stand.start()
    sim_instr = SimInstrument(base.sim.instrument, base.instrument, sim_stand)
    sim_instr.start()
    lim = base.stand.limits
    period = 1.0 / base.stand.setpoint_rate_hz
    results: list[dict[str, Any]] = []
    hogs: list[subprocess.Popen[bytes]] = []
    try:
        data = yaml.safe_load((ROOT / "config/sim.yaml").read_text())
        data.pop("sim")
        data["stand"].update(
            host="127.0.0.1",
            port=sim_stand.port,
            register_map=str(base.stand.register_map),
            mode=args.mode,
            watchdog_s=base.sim.stand.watchdog_s,  # the stand's: the config is checked against it
        )
        data["instrument"].update(
            channel=sim_instr.instrument_config().channel, eds=str(base.instrument.eds)
        )
        data["run"]["output_dir"] = str(tmp / "runs")
        (tmp / "runs").mkdir()
        cfg_path = tmp / "bench.yaml"
        cfg_path.write_text(yaml.safe_dump(data))

        ref = one_run(cfg_path, args, sim_stand, False, 0)
        if "rep" not in ref or ref["code"] != 0:
            why = ref["rep"].get("reason") or ref["rep"].get("verdict") if "rep" in ref else ""
            print(f"reference run failed: exit {ref['code']} {why} {ref.get('error', '')}")
            return 2
        sigma_ref = {a: v["sigma"] for a, v in ref["rep"]["axes"].items()}
        print(
            f"reference (no load, no stalls): {ref['rep']['verdict']}, σ "
            + ", ".join(f"{a} {s:.4f}°" for a, s in sigma_ref.items())
        )
        if not args.no_load:
            hogs = burners(2)
        for i in range(args.runs):
            r = one_run(cfg_path, args, sim_stand, not args.no_load, 100 + i)
            results.append(r)
            if "rep" not in r:
                print(f"run {i + 1}: exit {r['code']}, no report: {r['error'][-300:]}")
                continue
            rep, st = r["rep"], r["rep"]["stats"]
            rec = load_recording(Path(rep["recording"]))
            axes = list(sigma_ref)
            cp = {a: commanded_peaks(rec, a, period) for a in axes}
            r["cmd_peaks"] = cp
            sig = {a: rep["axes"][a]["sigma"] for a in axes} if rep.get("axes") else {}
            r["sigma"] = sig
            print(
                f"run {i + 1}: {rep['verdict']} (exit {r['code']})"
                + (f" reason {rep.get('reason')}" if rep["verdict"] == "ABORTED" else "")
                + f"; stalls {len(r['stalls'])} ({1e3 * sum(r['stalls']):.0f} ms in all, "
                f"longest {1e3 * max(r['stalls'], default=0):.0f} ms); largest rtt_s "
                f"{st['stand_rtt_s'].get('max', float('nan')):.3f} s; missed {st['missed_cycles']}"
                f", rejoins {st.get('rejoins')}, underruns {st.get('underruns')}"
            )
            for a in axes:
                pk = r["peaks"][a]
                ratio = sig[a] / sigma_ref[a] if a in sig else float("nan")
                print(
                    f"    {a}: commanded max rate {cp[a][0]:.2f}°/s, accel {cp[a][1]:.2f}°/s²; "
                    f"measured max rate {pk['rate_deg_s']:.2f}°/s, accel "
                    f"{pk['accel_deg_s2']:.2f}°/s² (limits {lim.rate_deg_s}°/s, "
                    f"{lim.accel_deg_s2}°/s²); σ {sig.get(a, float('nan')):.4f}° "
                    f"= {ratio:.4f} × unloaded"
                )
    finally:
        for h in hogs:
            h.kill()
            h.wait()
        sim_instr.stop()
        sim_stand.stop()
    done = [r for r in results if "rep" in r]
    aborts = sum(1 for r in results if r.get("code") == 2)
    print("--- summary")
    print(
        f"mode {args.mode}, profile {args.profile.name} {args.duration:g} s, runs {len(results)}, "
        f"aborts {aborts}, load {'none' if args.no_load else '2 CPU-bound processes + stalls'}"
    )
    print(
        f"stand: reply timeout {base.stand.timeout_s:g} s × {base.stand.retries + 1} "
        f"tries + heartbeat {base.stand.heartbeat_period_s:g} s, watchdog "
        f"{base.sim.stand.watchdog_s:g} s"
    )
    if done:
        axes = list(sigma_ref)
        rtts = [(r["rep"]["stats"]["stand_rtt_s"].get("max", 0.0), i + 1)
                for i, r in enumerate(results) if "rep" in r]
        rtt, at = max(rtts)
        print(f"largest rtt_s {rtt:.3f} s (run {at}); per run "
              + ", ".join(f"{v:.3f}" for v, _ in rtts))
        print(
            f"stalls {sum(len(r['stalls']) for r in done)} "
            f"(longest {1e3 * max(max(r['stalls'], default=0) for r in done):.0f} ms); "
            f"missed {sum(r['rep']['stats']['missed_cycles'] for r in done)}; "
            f"rejoins {sum(r['rep']['stats'].get('rejoins', 0) for r in done)}; "
            f"underruns {sum(r['rep']['stats'].get('underruns', 0) for r in done)}"
        )
        for a in axes:
            cr = max(r["cmd_peaks"][a][0] for r in done if "cmd_peaks" in r)
            ca = max(r["cmd_peaks"][a][1] for r in done if "cmd_peaks" in r)
            mr = max(r["peaks"][a]["rate_deg_s"] for r in done)
            ma = max(r["peaks"][a]["accel_deg_s2"] for r in done)
            ratios = [r["sigma"][a] / sigma_ref[a] for r in done if a in r.get("sigma", {})]
            print(
                f"{a}: largest commanded rate {cr:.2f}°/s accel {ca:.2f}°/s²; largest measured "
                f"rate {mr:.2f}°/s accel {ma:.2f}°/s² (limits {lim.rate_deg_s}, "
                f"{lim.accel_deg_s2}); σ/σ_unloaded {min(ratios):.4f} … {max(ratios):.4f}"
            )
    return 0 if aborts == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
