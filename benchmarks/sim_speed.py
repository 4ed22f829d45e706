"""How fast a run on simulated time goes: simulated seconds per wall second, phase by phase.

One `run_test` of a profile on the simulated bench (``config/sim_virtual.yaml``; with ``--link
rtu`` ``config/sim_rtu.yaml``, with ``--protocol`` another instrument's config, all on simulated
time) — the product's own path: the run makes its VirtualClock and starts its simulators
itself — in a child process; each state transition is stamped with the host's time and CPU
time. Printed per run:

- ``pre``: from the start to the motion (loading, simulators, prechecks), wall seconds;
- ``motion``: fade-in → analysing: simulated seconds, wall seconds and their ratio (× real
  time), the clock's hand-overs and the process's context switches per simulated second, and
  its CPU time (user, system);
- ``after``: analysing → done (the analysis, the figures, the HTML report, the archive).

``--against DIR``: the same measurement of another checkout (e.g. a ``git worktree`` of the
baseline commit), its runs interleaved with this tree's so that both see the same load; then
the ratio of the medians, and whether the two recorded the same bytes (``stand.csv``,
``instrument.csv``, ``setpoints.csv`` and ``events.jsonl`` but for the recording's path and the
software version, as tests/sim/test_sim_virtual.py compares two runs). The machine's load average
is printed before and after: this is a measurement on a shared machine.

Usage: python benchmarks/sim_speed.py [--profile profiles/paper_vessel_roll_short120.yaml]
       [--duration SEC] [--link tcp|rtu] [--protocol canopen|j1939|nmea2000|nmea0183]
       [--mode buffered|stream|table] [--disturb-seed N [--faults]] [--repeat N]
       [--against DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
PROTOCOLS = {"canopen": "sim.yaml", "j1939": "sim_j1939.yaml", "nmea2000": "sim_nmea2000.yaml",
             "nmea0183": "sim_nmea0183.yaml"}
#: --disturb-seed: tests/sim/test_sim_virtual.py's disturbances (stalls, jitter, slow and lost
#: replies, lost and garbled frames)
DISTURB = {
    "host_stalls_per_min": 30, "host_stall_s": [0.05, 0.6], "send_jitter_s": 0.002,
    "slow_reply_p": 0.02, "slow_reply_s": [0.005, 0.3], "lost_reply_p": 0.002,
    "lost_frame_p": 0.002, "garbled_frame_p": 0.002,
}
#: --faults: the campaign's faulty draws add these (stand and instrument faults at random
#: moments, an operator's Ctrl-C)
FAULTS = {
    "faults": 2, "fault_kinds": ["stand:stall", "stand:stand_fault", "stand:estop",
                                 "stand:modbus_exception", "instrument:silent",
                                 "instrument:garbled"],
    "operator_stop_p": 0.2,
}


def bench_config(tree: Path, args: argparse.Namespace, out: Path) -> Path:
    import yaml

    base = yaml.safe_load((tree / "config" / ("sim_rtu.yaml" if args.link == "rtu"
                                              else "sim_virtual.yaml")).read_text())
    proto = yaml.safe_load((tree / "config" / PROTOCOLS[args.protocol]).read_text())
    base["instrument"] = proto["instrument"]
    base["sim"]["instrument"] = proto.get("sim", {}).get("instrument", base["sim"]["instrument"])
    base["sim"]["clock"] = "virtual"
    if args.mode is not None:
        base["stand"]["mode"] = args.mode
    if args.disturb_seed is not None:
        base["sim"]["disturb"] = {"seed": args.disturb_seed, **DISTURB,
                                  **(FAULTS if args.faults else {})}
    for sec, key in (("stand", "register_map"), ("instrument", "eds"), ("instrument", "dbc")):
        v = base.get(sec, {}).get(key)
        if isinstance(v, str) and not Path(v).is_absolute():
            base[sec][key] = str((tree / "config" / v).resolve())
    base["run"]["output_dir"] = str(out / "runs")
    path = out / "bench.yaml"
    path.write_text(yaml.safe_dump(base))
    return path


def child(tree: Path, args: argparse.Namespace) -> None:
    """One run in this process, against the benchctl of ``tree``; prints one JSON line."""
    sys.path.insert(0, str(tree))
    from benchctl.clock import virtual
    from benchctl.config import load_config
    from benchctl.run import RunOptions
    from benchctl.run import state as run_state
    from benchctl.run.session import run_test

    out: Path = args.out
    cfg_path = bench_config(tree, args, out)
    clocks: list[Any] = []
    orig_init = virtual.VirtualClock.__init__

    def init(self: Any, *a: Any, **k: Any) -> None:
        orig_init(self, *a, **k)
        clocks.append(self)

    virtual.VirtualClock.__init__ = init  # type: ignore[method-assign]
    stamps: dict[str, tuple[float, float, int, float, float, int]] = {}
    orig_to = run_state.StateMachine.to

    def to(self: Any, new: Any, reason: str = "") -> None:
        orig_to(self, new, reason)
        ru = resource.getrusage(resource.RUSAGE_SELF)
        stamps.setdefault(str(new), (
            time.perf_counter(), self._clock.monotonic(), clocks[-1].switches if clocks else 0,
            ru.ru_utime, ru.ru_stime, ru.ru_nvcsw + ru.ru_nivcsw))

    run_state.StateMachine.to = to  # type: ignore[method-assign]
    t0 = time.perf_counter()
    res = run_test(load_config(cfg_path), tree / args.profile,
                   RunOptions(serial="20260001", operator="bench", duration_s=args.duration))
    t_end = time.perf_counter()
    first = next((s for s in ("fade-in", "running") if s in stamps), None)
    last = next((s for s in ("analysing", "aborted") if s in stamps), None)
    if first is None or last is None:  # ended before the motion: no motion to time
        a = b = stamps.get(last or "", (t_end, 0.0, 0, 0.0, 0.0, 0))
    else:
        a, b = stamps[first], stamps[last]
    rec = res.recording
    print(json.dumps({
        "state": res.state, "exit": res.exit_code, "recording": str(rec),
        "pre_wall": a[0] - t0, "motion_wall": b[0] - a[0], "motion_sim": b[1] - a[1],
        "motion_switches": b[2] - a[2], "motion_user": b[3] - a[3], "motion_sys": b[4] - a[4],
        "motion_csw": b[5] - a[5], "after_wall": t_end - b[0], "total_wall": t_end - t0,
    }))


def one(tree: Path, args: argparse.Namespace) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="sim-speed-") as tmp:
        cmd = [sys.executable, str(Path(__file__).resolve()), "--child", str(tree),
               "--profile", args.profile, "--link", args.link, "--protocol", args.protocol,
               "--out", tmp]
        for opt in ("duration", "mode", "disturb_seed"):
            if getattr(args, opt) is not None:
                cmd += [f"--{opt.replace('_', '-')}", str(getattr(args, opt))]
        cmd += ["--faults"] if args.faults else []
        env = {**os.environ, "PYTHONPATH": str(tree)}
        proc = subprocess.run(cmd, capture_output=True, text=True, env=env, check=False)
        lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
        if proc.returncode != 0 or not lines:
            raise SystemExit(f"{tree}: exit {proc.returncode}\n{proc.stderr[-3000:]}")
        got: dict[str, Any] = json.loads(lines[-1])
        # this checkout's digest of either tree's recording (a baseline may predate it; imported
        # here, not at the top: a child imports benchctl from the tree it measures)
        if str(ROOT) not in sys.path:  # once: this is called per run
            sys.path.insert(0, str(ROOT))
        from benchctl.recording.digest import data_digest

        rec = got["recording"]
        got["digests"] = {} if rec in (None, "None") else data_digest(rec, tree)
        return got


def show(name: str, r: dict[str, Any]) -> None:
    sim = r["motion_sim"]
    if sim <= 0 or r["motion_wall"] <= 0:
        print(f"  {name:9s} {r['state']:7s} pre {r['pre_wall']:5.2f} s | no motion | after "
              f"{r['after_wall']:5.2f} s | total {r['total_wall']:6.2f} s", flush=True)
        return
    print(f"  {name:9s} {r['state']:7s} pre {r['pre_wall']:5.2f} s | motion {sim:6.1f} s sim "
          f"in {r['motion_wall']:6.2f} s wall = {sim / r['motion_wall']:5.1f}× real time; "
          f"{r['motion_switches'] / sim:4.0f} hand-overs, {r['motion_csw'] / sim:4.0f} context "
          f"switches per sim s; cpu user {r['motion_user']:.2f} s sys {r['motion_sys']:.2f} s"
          f" | after {r['after_wall']:5.2f} s | total {r['total_wall']:6.2f} s", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--profile", default="profiles/paper_vessel_roll_short120.yaml")
    ap.add_argument("--duration", type=float, default=None)
    ap.add_argument("--link", choices=("tcp", "rtu"), default="tcp")
    ap.add_argument("--protocol", choices=sorted(PROTOCOLS), default="canopen")
    ap.add_argument("--mode", choices=("buffered", "stream", "table"), default=None)
    ap.add_argument("--disturb-seed", type=int, default=None)
    ap.add_argument("--faults", action="store_true",
                    help="with --disturb-seed: stand and instrument faults too")
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--against", type=Path, default=None,
                    help="another checkout (the baseline), run interleaved with this one")
    ap.add_argument("--child", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        child(args.child, args)
        return 0
    trees = {"this": ROOT}
    if args.against is not None:
        trees = {"baseline": args.against.resolve(), "this": ROOT}
    what = [args.profile, f"link {args.link}", args.protocol]
    what += [f"mode {args.mode}"] if args.mode else []
    what += [f"disturbances seed {args.disturb_seed}" + (" with faults" if args.faults else "")
             ] if args.disturb_seed is not None else []
    what += [f"duration {args.duration:g} s"] if args.duration is not None else []
    print(f"{', '.join(what)}; load average before: "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    got: dict[str, list[dict[str, Any]]] = {k: [] for k in trees}
    same = True
    for i in range(args.repeat):
        print(f"round {i + 1}/{args.repeat}")
        for name, tree in trees.items():
            r = one(tree, args)
            got[name].append(r)
            show(name, r)
        if len(trees) == 2:
            d0, d1 = got["baseline"][-1]["digests"], got["this"][-1]["digests"]
            diff = [n for n in d1 if d0.get(n) != d1.get(n)]
            same = same and not diff
            print("  recordings: " + (f"DIFFER in {', '.join(diff)}" if diff else
                                      "the same bytes"))
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    med = {}
    for name, rs in got.items():
        rs = [r for r in rs if r["motion_sim"] > 0 and r["motion_wall"] > 0]
        if not rs:
            print(f"{name:9s}: no motion")
            continue
        speed = [r["motion_sim"] / r["motion_wall"] for r in rs]
        cpu = [1000.0 * (r["motion_user"] + r["motion_sys"]) / r["motion_sim"] for r in rs]
        after = statistics.median(r["after_wall"] for r in rs)
        total = statistics.median(r["total_wall"] for r in rs)
        med[name] = (statistics.median(speed), max(speed), min(cpu), after, total)
        print(f"{name:9s}: motion {statistics.median(speed):5.1f}× real time (median; best "
              f"{max(speed):5.1f}×), CPU {min(cpu):5.1f} ms per simulated second (least); "
              f"after the motion {after:5.2f} s, the whole run {total:6.2f} s (medians)")
    if "baseline" in med and "this" in med:
        b, t = med["baseline"], med["this"]
        print(f"this / baseline: motion ×{t[0] / b[0]:.2f} as fast (median; best ×"
              f"{t[1] / b[1]:.2f}), CPU per simulated second ×{b[2] / t[2]:.2f} less; after the "
              f"motion ×{b[3] / t[3]:.2f} as fast; the whole run ×{b[4] / t[4]:.2f} as fast; "
              f"recordings {'the same bytes' if same else 'DIFFER'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
