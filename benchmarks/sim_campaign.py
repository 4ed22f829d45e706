"""A safety campaign on simulated time: N seeded runs with seeded disturbances, each one checked.

Each run ``k`` draws from its seed (``--seed0 + k``): the stand mode (buffered, stream, table),
the link (Modbus TCP or RTU), the instrument protocol (CANopen, J1939, NMEA 2000, NMEA 0183),
the profile and its duration, and the disturbances (``benchctl.sim.disturb``): host stalls from
tens of milliseconds to several seconds, send jitter, slow replies, and — in a third of the
runs — up to a few lost replies at random moments, lost and garbled frames, stand and
instrument faults and an operator's Ctrl-C.
Each run's bench has the timing calibration of its link and instrument (``bench_timing``).
The simulators and the run share one VirtualClock in this process; the run is the product's own
(``run_test`` with the drivers on in-process links), the same code a run on hardware takes.

Checked for every run:

1. limits: every commanded point (setpoints.csv: angle, and rate and acceleration between
   consecutive slots; the shutdown ramp's too) and the stand's true motion while it followed
   (the simulator's peaks: while it played its queue or table in buffered and table runs;
   everything in stream runs) within the stand's angle, rate and acceleration limits;
2. the way out: the stand at rest at zero when the run ended, or — when it could not be brought
   there (a fault, a lost link) — its final state reported in end.json;
3. no abort in a buffered or table run whose only disturbances were host stalls shorter than
   the stand's buffer (and jitter, and replies slower than usual but within the reply timeout);
   a stream-mode stand holds its last setpoint on every missed slot, by design;
4. σ: in such a run, without an underrun or a rejoin, σ within the 95 % interval of the same
   configuration's undisturbed run. Such a run's stalls, jitter and slow replies act from its
   motion's start on (``sim.disturb.from_s``, the undisturbed twin's fade-in): its motion then
   begins at the same simulated instant, the instrument's samples and noise in step with it,
   and σ differs only by what the disturbances did (disturbed from the start, the motion
   began a few milliseconds later, the noise fell on other instants of the motion, and σ moved
   by its own sampling spread: seeds 1015 and 1029 of the first draw). Faulty runs are
   disturbed from the start.

Prints one line per run (seed, what it drew, verdict, the checks) and the totals: runs,
simulated hours, violations by check, the failing seeds. A failing seed replays exactly:
``--seed0 S --runs 1``.

The undisturbed runs are the same bytes for the same code and configuration: ``--ref-cache DIR``
keeps their σ by code version (``code_version``: the files a run executes, the checks and the
libraries' versions) and configuration, so a campaign in several parts runs each once.
``--summarize F.jsonl ...`` adds up the parts.

Usage: python benchmarks/sim_campaign.py --runs 1000 [--seed0 1] [--jobs 2]
       [--durations 120,300,600,900] [--modes buffered,stream,table] [--keep DIR] [--json F]
       [--ref-cache DIR] [--append] [--hours H]
       python benchmarks/sim_campaign.py --summarize F.jsonl [F2.jsonl ...]
       python benchmarks/sim_campaign.py --replay F.jsonl [--sample 20] [--jobs 2]

``--append`` adds to ``--json``'s file and skips the seeds it holds (a campaign stopped and
resumed); ``--hours H`` stops once the runs done hold H simulated hours.

Each run's line carries the digest of what it recorded (``benchctl.recording.digest``: the
streams and the events, but for the recording's path and the software version).
``--replay F.jsonl`` runs again every seed of ``F`` that had a violation and ``--sample`` of the
others, and compares each new line with the old: the same draw, verdict, violations, simulated
time and digest — the same run, byte for byte — or exit 1 naming what differs.

One file (about 730 lines) on purpose: the draws, the run, its checks and the replay all read
and write one run line, and the campaign's code version hashes this file whole (its checks are
part of what a version's figures mean).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import multiprocessing
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchctl.clock.virtual import VirtualClock  # noqa: E402
from benchctl.config import BenchConfig, load_config  # noqa: E402
from benchctl.errors import BenchError, SafetyAbort  # noqa: E402
from benchctl.recording.digest import combined_digest  # noqa: E402
from benchctl.run.devices import open_devices  # noqa: E402
from benchctl.run.display import NullDisplay  # noqa: E402
from benchctl.run.prepare import RunOptions  # noqa: E402
from benchctl.run.session import run_test  # noqa: E402
from benchctl.run.supervisor import Supervisor  # noqa: E402
from benchctl.sim.bench import SimBench  # noqa: E402
from benchctl.sim.disturb import Disturbances  # noqa: E402

MODES = ("buffered", "stream", "table")
LINKS = ("tcp", "rtu")
PROTOCOLS = {
    # the default bench on simulated time (config/sim.yaml's twin: its timing calibration is
    # the simulated-time one, where sim.yaml's is measured on the host's clock it runs on)
    "canopen": "sim_virtual.yaml",
    "j1939": "sim_j1939.yaml",
    "nmea2000": "sim_nmea2000.yaml",
    "nmea0183": "sim_nmea0183.yaml",
}
PROFILES = (
    "paper_vessel_roll.yaml",
    "sea_state_3_small_vessel.yaml",
    "sea_state_4_small_vessel.yaml",
    "sea_state_5_small_vessel.yaml",
    "fast_craft_roll.yaml",
    "two_axis_roll_pitch.yaml",
)
#: slack on the commanded points' finite differences (rounding of the recorded values)
SLACK = 1.001
#: a VirtualClock's monotonic() when it is made
CLOCK_START = 1000.0
#: the share of runs with lost or garbled frames and replies, device faults, an operator's stop
FAULTY_SHARE = 0.35
#: the share of table-mode runs drawn at the shortest duration (a table of at most 64 lines)
TABLE_SHORT = 0.9
#: the most lost stand replies a faulty run expects (drawn uniformly from 0 to this)
LOST_REPLIES = 3.0
#: the stand exchanges per second of a run (a 100 Hz loop, heartbeats, writes), roughly
EXCHANGES_PER_S = 120.0
#: the share of runs whose host stalls may exceed the stand's buffer (up to 3 s)
LONG_STALL_SHARE = 0.3


def _abs_paths(data: dict[str, Any], base: Path) -> None:
    for sec, key in (("stand", "register_map"), ("instrument", "eds"), ("instrument", "dbc")):
        v = data.get(sec, {}).get(key)
        if isinstance(v, str) and not Path(v).is_absolute():
            data[sec][key] = str((base / v).resolve())


def config_for(draw: dict[str, Any], out: Path, disturb: dict[str, Any] | None) -> Path:
    """The bench config for a draw: sim_virtual.yaml (or sim_rtu.yaml) with the protocol's
    instrument."""
    base = yaml.safe_load((ROOT / "config" / ("sim_rtu.yaml" if draw["link"] == "rtu"
                                              else "sim_virtual.yaml")).read_text())
    proto = yaml.safe_load((ROOT / "config" / PROTOCOLS[draw["protocol"]]).read_text())
    base["instrument"] = proto["instrument"]
    base["sim"]["instrument"] = proto.get("sim", {}).get("instrument", base["sim"]["instrument"])
    base["timing"] = bench_timing(draw["link"], draw["protocol"])
    base["stand"]["mode"] = draw["mode"]
    # stream mode: the stand's own drive is set to the stand's limits, as a real stand's is:
    # when commands stop (a missed slot) it brakes within them, not at the servo's physical
    # maximum. Buffered and table modes keep the simulated servo's own (higher) maxima, so a
    # step in what the stand is told to follow shows as motion beyond the limits.
    if draw["mode"] == "stream":
        lim = base["stand"]["limits"]
        base["sim"]["stand"]["accel_limit_deg_s2"] = lim["accel_deg_s2"]
        base["sim"]["stand"]["rate_limit_deg_s"] = lim["rate_deg_s"]
    else:
        # the shutdown ramp of a buffered or table run is streamed: the drive interpolates
        # between the setpoints (cyclic synchronous position), so a staircase of setpoints
        # within the limits moves the stand within them; a step still shows
        base["sim"]["stand"]["stream_interpolation"] = True
    base["sim"]["clock"] = "virtual"
    base["sim"].pop("disturb", None)
    if disturb is not None:
        base["sim"]["disturb"] = disturb
    base["run"]["output_dir"] = str(out / "runs")
    base["run"]["figures"] = False  # the checks read the data, not the report's figures
    _abs_paths(base, ROOT / "config")
    out.mkdir(parents=True, exist_ok=True)
    path = out / "bench.yaml"
    path.write_text(yaml.safe_dump(base))
    return path


def bench_timing(link: str, protocol: str) -> dict[str, Any]:
    """The bench's timing calibration for a link and an instrument protocol: the protocol's
    shipped config's (calibrated over Modbus TCP); over RTU, plus what the RTU link adds to the
    CANopen bench's (``sim_rtu.yaml`` less ``sim_virtual.yaml``), the uncertainties in
    quadrature. All of them measured on simulated time, where the campaign runs."""
    def timing(name: str) -> dict[str, Any]:
        doc: dict[str, Any] = yaml.safe_load((ROOT / "config" / name).read_text())["timing"]
        return doc

    own = timing(PROTOCOLS[protocol])
    if link == "tcp":
        return own
    if protocol == "canopen":
        return timing("sim_rtu.yaml")
    rtu, tcp = timing("sim_rtu.yaml"), timing("sim_virtual.yaml")
    return {**own,
            "offset_s": round(own["offset_s"] + rtu["offset_s"] - tcp["offset_s"], 9),
            "uncertainty_s": round(math.hypot(own["uncertainty_s"], rtu["uncertainty_s"],
                                              tcp["uncertainty_s"]), 9),
            "reference": f"{own.get('reference')}; plus the RTU link's share (sim_rtu.yaml "
                         "less sim_virtual.yaml)"}


def draw_run(seed: int, durations: list[int], modes: tuple[str, ...] = MODES) -> dict[str, Any]:
    rng = random.Random(f"campaign:{seed}")
    draw: dict[str, Any] = {
        "seed": seed,
        "mode": rng.choice(modes),
        "link": rng.choice(LINKS),
        "protocol": rng.choice(sorted(PROTOCOLS)),
        "profile": rng.choice(PROFILES),
        "duration": rng.choice(durations),
    }
    if draw["mode"] == "table" and rng.random() < TABLE_SHORT:
        # a stand's table holds 64 lines: at 2 min most profiles fit, at 15 min none does
        # (refused before anything moves, which the other tenth still checks)
        draw["duration"] = min(durations)
    faulty = rng.random() < FAULTY_SHARE
    # host stalls: in most runs all shorter than the stand's 1 s buffer (the run must then go
    # through: check 3), in the rest up to several seconds, rarer (a stall longer than the
    # stand's watchdog trips it, as on a real stand: the run's way out is then what is checked)
    long_stalls = rng.random() < LONG_STALL_SHARE
    disturb: dict[str, Any] = {
        "seed": seed,
        "host_stalls_per_min": round(rng.uniform(0.0, 1.5 if long_stalls else 4.0), 3),
        "host_stall_s": [0.02, round(rng.uniform(1.0, 3.0) if long_stalls
                                     else rng.uniform(0.1, 0.95), 3)],
        "send_jitter_s": round(rng.uniform(0.0, 0.005), 5),
        "slow_reply_p": round(rng.uniform(0.0, 0.02), 4),
        "slow_reply_s": [0.005, round(rng.uniform(0.01, 0.2), 3)],
    }
    if faulty:
        exchanges = draw["duration"] * EXCHANGES_PER_S
        disturb.update({
            # a lost reply is drawn per exchange: at most a few in the whole run, at random
            # moments (more would end nearly every faulty run at its first seconds)
            "lost_reply_p": float(f"{rng.uniform(0.0, LOST_REPLIES) / exchanges:.3g}"),
            "lost_frame_p": round(rng.uniform(0.0, 0.01), 5),
            "garbled_frame_p": round(rng.uniform(0.0, 0.01), 5),
            "faults": rng.choice([0, 1, 1, 2]),
            "fault_kinds": ["stand:stall", "stand:stand_fault", "stand:estop",
                            "stand:modbus_exception", "instrument:silent",
                            "instrument:garbled"],
            "operator_stop_p": 0.2,
        })
    draw["faulty"] = faulty
    draw["disturb"] = disturb
    return draw


class _StopAtMotion(NullDisplay):
    """A run's display that ends the run (the operator's path, through its supervisor) as it
    enters its fade-in: an undisturbed twin run only to learn when its motion starts."""

    def __init__(self, sup: Supervisor) -> None:
        self.sup = sup

    def state(self, state: str, reason: str = "") -> None:
        if state == "fade-in":
            self.sup.fault(SafetyAbort("campaign: the twin stops where its motion starts"),
                           "signal")


def _run(cfg: BenchConfig, draw: dict[str, Any], out: Path,
         plan: Disturbances | None, *, to_motion: bool = False) -> dict[str, Any]:
    """One run on its own VirtualClock, the simulators beside it; what the checks need.
    ``to_motion``: the run ends as its motion starts (``_StopAtMotion``)."""
    assert cfg.sim is not None
    clock = VirtualClock(epoch=cfg.sim.epoch_utc)
    assert clock.monotonic() == CLOCK_START
    with clock.running():
        if plan is not None:
            cfg = plan.with_faults(cfg)
        bench = SimBench(cfg, private=True, clock=clock).start()
        try:
            if plan is not None:
                bench.disturb(plan)
            run_cfg = bench.config().model_copy(update={"sim": None})
            sup = Supervisor(clock=clock)
            if plan is not None and plan.operator_stop_s is not None:
                sup.interrupt_after(plan.operator_stop_s)
            opts = RunOptions(serial="20260001", operator="campaign", out_dir=out / "runs",
                              duration_s=float(draw["duration"]))
            try:
                res = run_test(run_cfg, ROOT / "profiles" / draw["profile"], opts,
                               display=_StopAtMotion(sup) if to_motion else None,
                               device_factory=lambda c, rec: open_devices(c, rec, clock=clock),
                               supervisor=sup, clock=clock)
            except BenchError as e:  # refused before anything moved (a profile over a limit)
                return {"refused": str(e), "t_sim": clock.monotonic() - CLOCK_START}
            now = clock.monotonic()
            true = bench.stand.true_angles(now)
            with bench.stand._lock:
                moving = any(abs(s.rate_deg_s) > 1e-3 for s in bench.stand._state.values())
                enabled = bench.stand._enabled
            return {
                # buffered and table: the motion the stand played from its queue or table (a
                # streamed shutdown ramp is judged by its commanded points; how a servo meets
                # a host's jittered setpoints is the stand's drive's business); stream mode:
                # everything (its drive is set to the stand's limits, config_for)
                "result": res, "true": true, "moving": moving,
                "peaks": bench.stand.peaks(
                    following="any" if draw["mode"] == "stream" else "profile"),
                "enabled": enabled, "t_sim": now - CLOCK_START,
            }
        finally:
            bench.stop()


def check_run(draw: dict[str, Any], got: dict[str, Any], cfg: BenchConfig,
              reference: dict[str, Any] | None) -> list[str]:
    """The violations of one run (empty: it held)."""
    if "refused" in got:
        return []
    res = got["result"]
    lim = cfg.stand.limits
    bad: list[str] = []
    # 1. limits: the stand's true motion while following, and every commanded point
    for axis, p in got["peaks"].items():
        if p["rate_deg_s"] > lim.rate_deg_s * SLACK:
            bad.append(f"limits: {axis} moved at {p['rate_deg_s']:.3f} deg/s "
                       f"(limit {lim.rate_deg_s})")
        if p["accel_deg_s2"] > lim.accel_deg_s2 * SLACK:
            bad.append(f"limits: {axis} accelerated at {p['accel_deg_s2']:.3f} deg/s2 "
                       f"(limit {lim.accel_deg_s2})")
    rec = res.recording
    if rec is not None and (rec / "setpoints.csv").is_file():
        with (rec / "setpoints.csv").open() as f:
            rows = list(csv.DictReader(f))
        # the profile's points (a slot each) and the shutdown ramp's (no slot: planned from the
        # stand's measured state, so its first point continues the stand, not the last slot)
        # (the ramp's points are judged in runs of consecutive periods: after a gap the ramp
        # starts again from where the stand was then)
        ramp = [r for r in rows if not r["t_slot"]]
        slotted = [r for r in rows if r["t_slot"]]
        segments: list[list[dict[str, str]]] = [slotted]
        if draw["mode"] != "stream" and len(slotted) > 2:
            # buffered/table: after an underrun the stand stopped itself within its limits
            # (it does not hold the last point): the rejoin is planned from where it then
            # is, so the points after a gap are judged as a motion of their own (the stand's
            # stop between them is judged by its measured motion, check 1's peaks)
            ts = np.array([float(r["t_slot"]) for r in slotted])
            per = float(np.median(np.diff(ts)))
            cut = np.flatnonzero(np.diff(ts) > 1.5 * per) + 1
            segments = [list(x) for x in np.split(np.array(slotted, dtype=object), cut)]
        n_motion = len(segments)
        t_ramp = [float(r["t_send"]) for r in ramp]
        ramp_period = float(np.median(np.diff(t_ramp))) if len(t_ramp) > 2 else 0.0
        for r in ramp:
            if (len(segments) == n_motion or not segments[-1]
                    or float(r["t_send"]) - float(segments[-1][-1]["t_send"])
                    > 1.2 * ramp_period):
                segments.append([])
            segments[-1].append(r)
        for n_seg, seg in enumerate(segments):
            if len(seg) < 3:
                continue
            cols = [c for c in seg[0] if c.endswith("_deg")]
            t_raw = np.array([float(r["t_slot"] or r["t_send"]) for r in seg])
            period = float(np.median(np.diff(t_raw)))
            if n_seg >= n_motion:
                # a ramp's points have no slot: the driver sends them one period apart, and
                # judges them so; their send times carry the host's jitter (0.4 ms late on
                # 10 ms reads 48 deg/s2 as 69), which the stand's measured motion answers for
                t_raw = t_raw[0] + period * np.arange(len(t_raw))
            for c in cols:
                x_raw = np.array([float(r[c]) for r in seg])
                # slots never sent (missed, or a gap before a rejoin): the stand held the last
                # point until the next one's slot came — the commanded motion holds, then moves
                # (stream mode: that hold is the stand's documented behaviour on a missed slot,
                # an abrupt stop its drive makes within its own limits; the step into a hold is
                # counted as a hold, not judged; the rejoin from the held point is judged)
                t_l, x_l, hold_at = [t_raw[0]], [x_raw[0]], set()
                for i in range(1, len(t_raw)):
                    if n_seg == 0 and t_raw[i] - t_raw[i - 1] > 1.5 * period:
                        hold_at.add(len(t_l) - 1)  # the accel at the last point before the hold
                        t_l.append(t_raw[i] - period)
                        x_l.append(x_raw[i - 1])
                    t_l.append(t_raw[i])
                    x_l.append(x_raw[i])
                t, x = np.array(t_l), np.array(x_l)
                got.setdefault("holds", 0)
                got["holds"] += len(hold_at)
                if np.max(np.abs(x)) > lim.angle_deg * SLACK:
                    bad.append(f"limits: commanded {c} {np.max(np.abs(x)):.3f} deg")
                dt = np.diff(t)
                ok = dt > 1e-9
                v = np.diff(x)[ok] / dt[ok]
                if v.size and np.max(np.abs(v)) > lim.rate_deg_s * SLACK:
                    bad.append(f"limits: commanded {c} rate {np.max(np.abs(v)):.3f} deg/s")
                if v.size > 1:
                    tv = t[1:][ok]
                    dtv = np.diff(tv)
                    okv = dtv > 1e-9
                    # a[j] is the acceleration at point j+1 of the series (between v[j], v[j+1])
                    idx = np.nonzero(ok)[0][1:][okv]
                    judged = np.array([i not in hold_at for i in idx], dtype=bool)
                    a = (np.diff(v)[okv] / dtv[okv])[judged] if idx.size else np.array([])
                    if a.size and np.max(np.abs(a)) > lim.accel_deg_s2 * SLACK:
                        where = "the ramp to zero" if n_seg >= n_motion else "the motion"
                        j = int(np.argmax(np.abs(a)))
                        bad.append(f"limits: commanded {c} accel {np.max(np.abs(a)):.3f} deg/s2 "
                                   f"in {where} (point {j + 1} of {len(x)})")
    # 2. the way out: at rest at zero, or the final state reported
    at_zero = (not got["moving"] and all(abs(v) <= cfg.stand.zero_tolerance_deg
                                          for v in got["true"].values()))
    if not at_zero:
        reported = any(s["step"] == "final angle" and s["ok"] for s in res.shutdown)
        if not reported:
            where = ", ".join(f"{a}={v:+.3f}" for a, v in got["true"].items())
            bad.append(f"way out: stand left at {where} (moving={got['moving']}) and its "
                       "final state not reported")
    # 3. no abort when only short stalls happened
    stalls = draw["plan_stalls"]
    short = all(d < cfg.stand.buffer_s for _, d in stalls)
    # (buffered and table modes: a stream-mode stand holds on every missed slot by design)
    if draw["mode"] != "stream" and not draw["faulty"] and short and res.state == "aborted":
        bad.append(f"abort with every stall shorter than the buffer "
                   f"(longest {max((d for _, d in stalls), default=0):.3f} s): {res.reason}")
    # 4. σ against the undisturbed run of the same configuration
    if reference is not None and check4_applies(draw, got):
        for axis, ref in reference.items():
            got_axis = res.report.axes.get(axis) if hasattr(res.report, "axes") else None
            if got_axis is None:
                continue
            s = got_axis.sigma_deg
            lo, hi = ref["ci95"]
            if not lo <= s <= hi:
                bad.append(f"sigma: {axis} {s:.5f} deg outside the undisturbed run's "
                           f"[{lo:.5f}, {hi:.5f}]")
    return bad


def check4_applies(draw: dict[str, Any], got: dict[str, Any]) -> bool:
    """Check 4 judges this run (and needs its undisturbed twin's σ): not faulty, not refused,
    done with a report, and without an underrun or a rejoin."""
    if draw["faulty"] or "refused" in got:
        return False
    res = got["result"]
    stats = res.stats or {}
    clean = stats.get("underruns", 0) == 0 and stats.get("rejoins", 0) == 0
    return bool(res.state == "done" and clean and res.report is not None)


def _sigmas(res: Any) -> dict[str, Any] | None:
    if res is None or res.report is None or not hasattr(res.report, "axes"):
        return None
    return {a: {"sigma": v.sigma_deg, "ci95": list(v.sigma_ci95_deg)}
            for a, v in res.report.axes.items()}


#: packages outside the campaign's code version: a run never imports them (checked after each)
OUTSIDE = ("benchctl.cli", "benchctl.web")
#: the libraries whose versions are part of the code version
LIBRARIES = ("pymodbus", "python-can", "canopen", "cantools", "pynmea2", "pyserial", "numpy",
             "scipy", "pydantic", "PyYAML", "matplotlib", "Jinja2")


def code_version() -> str:
    """The code a campaign's runs execute, as it is on disk: a hash of the files under
    benchctl/ (but the packages in OUTSIDE), config/, profiles/ and drivers/, of this script
    (the checks), and of the libraries' versions. A commit that changes none of them (tests,
    documentation, a command-line front end) keeps the version, so a campaign in several
    parts adds up to one version's figures; the key of the reference cache too (an undisturbed
    run is the same bytes for the same code and configuration)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as lib_version

    outside = tuple(p.replace(".", "/") + "/" for p in OUTSIDE)
    listed = subprocess.run(
        ["git", "ls-files", "-co", "--exclude-standard", "--", "benchctl", "config", "profiles",
         "drivers"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    h = hashlib.sha256()
    for rel in sorted({*listed, "benchmarks/sim_campaign.py"}):
        path = ROOT / rel
        if rel.startswith(outside) or "__pycache__" in rel or not path.is_file():
            continue
        h.update(rel.encode() + b"\0" + hashlib.sha256(path.read_bytes()).digest())
    for lib in LIBRARIES:
        try:
            h.update(f"{lib}=={lib_version(lib)}".encode())
        except PackageNotFoundError:
            h.update(f"{lib} missing".encode())
    return "code:" + h.hexdigest()[:16]


def _outside_imported() -> list[str]:
    """Modules of the packages outside the code version that this process has imported."""
    return sorted(m for m in sys.modules if m.startswith(tuple(p + "." for p in OUTSIDE))
                  or m in OUTSIDE)


def _reference(draw: dict[str, Any], out: Path, cache: str | None,
               version: str, *, full: bool) -> dict[str, Any]:
    """The configuration's undisturbed run (cached by code version and configuration): the
    simulated second its motion began (``motion_start_s``, None when it did not) and, with
    ``full``, σ and its interval per axis (``sigmas``, None unless it ended done).

    Without ``full`` the twin runs only up to its motion's start (its fade-in; the run is the
    same up to there, whatever follows): a run whose check 4 does not apply (it aborted, it
    underran, it was refused) never pays for a whole undisturbed run."""
    cfg_path = config_for(draw, out / "u", None)
    text = cfg_path.read_text().replace(str(out / "u"), "OUT")
    key = hashlib.sha256(json.dumps([version, text, draw["profile"], draw["duration"]])
                         .encode()).hexdigest()[:24]
    hit = Path(cache) / f"{key}.json" if cache else None
    doc: dict[str, Any] = {}
    if hit is not None and hit.is_file():
        doc = json.loads(hit.read_text())
    if "motion_start_s" in doc and (not full or "sigmas" in doc):
        return doc
    ref = _run(load_config(cfg_path), draw, out / "u", None, to_motion=not full)
    res = ref.get("result")
    start = _motion_start(res)
    if "motion_start_s" in doc and doc["motion_start_s"] != start:
        # the same run up to its motion, stopped there or run in full: a harness fault
        raise RuntimeError(f"the undisturbed twin's motion began at {start} s run in full, at "
                           f"{doc['motion_start_s']} s stopped there")
    doc.update({"version": version, "motion_start_s": start})
    if full:
        doc.update({"t_sim_s": ref.get("t_sim"),
                    "sigmas": (_sigmas(res) if res is not None and res.state == "done"
                               else None)})
    if hit is not None:
        hit.parent.mkdir(parents=True, exist_ok=True)
        tmp = hit.with_suffix(f".{os.getpid()}.tmp")
        tmp.write_text(json.dumps(doc))
        os.replace(tmp, hit)
    return doc


def _motion_start(res: Any) -> float | None:
    """Seconds of simulated time from the simulators' start to the run's fade-in (its events)."""
    if res is None or res.recording is None:
        return None
    events = Path(res.recording) / "events.jsonl"
    if not events.is_file():
        return None
    for line in events.read_text().splitlines():
        e = json.loads(line)
        if e.get("kind") == "state" and e.get("to") == "fade-in":
            return float(e["t_state"]) - CLOCK_START
    return None


def one(args: tuple[int, list[int], str, str | None, tuple[str, ...], str | None, str]
        ) -> dict[str, Any]:
    seed, durations, work, keep, modes, cache, version = args
    draw = draw_run(seed, durations, modes)
    out = Path(work) / f"seed{seed}"
    t0 = time.perf_counter()
    try:
        ref: dict[str, Any] | None = None
        if not draw["faulty"]:
            # the undisturbed twin first: disturbed from its motion's start on, the run begins
            # its motion at the same simulated instant, the instrument's samples (and their
            # noise) in step with it — σ then differs only by what the disturbances did
            ref = _reference(draw, out, cache, version, full=False)
            if ref["motion_start_s"] is not None:
                draw["disturb"]["from_s"] = round(ref["motion_start_s"] + 0.001, 6)
        cfg_path = config_for(draw, out / "d", draw["disturb"])
        cfg = load_config(cfg_path)
        assert cfg.sim is not None and cfg.sim.disturb is not None
        plan = Disturbances(cfg.sim.disturb, float(draw["duration"]) + 600.0)
        draw["plan_stalls"] = plan.stalls
        got = _run(cfg, draw, out / "d", plan)
        reference = None
        if ref is not None and check4_applies(draw, got):
            reference = _reference(draw, out, cache, version, full=True)["sigmas"]
        bad = check_run(draw, got, cfg, reference)
        res = got.get("result")
        line = {
            "seed": seed, "mode": draw["mode"], "link": draw["link"],
            "protocol": draw["protocol"], "profile": draw["profile"],
            "duration": draw["duration"], "faulty": draw["faulty"],
            "stalls": len(plan.stalls),
            "longest_stall_s": round(max((d for _, d in plan.stalls), default=0.0), 3),
            "faults": [f"{f.target}:{f.kind}" for f in plan.faults],
            "operator_stop_s": plan.operator_stop_s,
            "verdict": ("REFUSED" if res is None else
                        (res.report.verdict if res.report is not None else "ABORTED")),
            "reason": got.get("refused") or (res.reason if res is not None else ""),
            "underruns": (res.stats or {}).get("underruns") if res is not None else None,
            "rejoins": (res.stats or {}).get("rejoins") if res is not None else None,
            "t_sim_s": round(got["t_sim"], 3),
            "violations": bad,
            # what the run recorded, as one digest (benchctl.recording.digest): a replay of the
            # seed, or another code version, recorded the same run exactly when it is equal
            "digest": (combined_digest(res.recording, ROOT)
                       if res is not None and res.recording is not None else None),
        }
    except Exception as e:  # a crash of the harness or the product is a violation too
        import traceback

        line = {"seed": seed, "violations": [f"crash: {type(e).__name__}: {e}"], "t_sim_s": 0.0,
                "traceback": traceback.format_exc(),
                **{k: draw[k] for k in ("mode", "link", "protocol", "profile", "duration")}}
    stray = _outside_imported()
    if stray:
        line["violations"] = [*line["violations"],
                              f"harness: the run imported {', '.join(stray)}, outside the code "
                              "version (OUTSIDE)"]
    line["wall_s"] = round(time.perf_counter() - t0, 2)
    line["version"] = version
    if line["violations"] and keep:
        shutil.copytree(out, Path(keep) / f"seed{seed}", dirs_exist_ok=True)
    shutil.rmtree(out, ignore_errors=True)
    return line


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--seed0", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--durations", default="120,300,600,900")
    ap.add_argument("--json", type=Path, help="write every run's line here (JSON lines)")
    ap.add_argument("--keep", type=Path, help="copy each failing run's recordings here")
    ap.add_argument("--modes", default=",".join(MODES), help="stand modes to draw from")
    ap.add_argument("--ref-cache", type=Path,
                    help="keep the undisturbed runs' σ here, by code version and configuration")
    ap.add_argument("--summarize", type=Path, nargs="+", metavar="JSONL",
                    help="print the totals of earlier campaigns' --json files (per code "
                         "version, then all) and exit")
    ap.add_argument("--append", action="store_true",
                    help="--json: add to the file, and skip the seeds it holds already (a "
                         "campaign resumed)")
    ap.add_argument("--hours", type=float,
                    help="stop once the runs done hold this many simulated hours")
    ap.add_argument("--replay", type=Path, metavar="JSONL",
                    help="run again seeds of an earlier campaign's --json file (every seed with "
                         "a violation, and --sample others spread over it) with this code, and "
                         "compare each run's line: what it drew, its verdict, its violations "
                         "and its recording's digest; exit 1 on any difference")
    ap.add_argument("--sample", type=int, default=20,
                    help="--replay: how many seeds without a violation to replay")
    a = ap.parse_args()
    if a.replay:
        return replay(a)
    if a.summarize:
        saved = [json.loads(x) for f in a.summarize for x in f.read_text().splitlines() if x]
        versions = sorted({str(x.get("version")) for x in saved})
        worst = 0
        if len(versions) > 1:
            for v in versions:
                print(f"\n== code version {v}")
                part = [x for x in saved if str(x.get("version")) == v]
                worst = max(worst, totals(part, sum(x.get("wall_s", 0.0) for x in part),
                                          "summed per run"))
            print("\n== all versions")
        else:
            print(f"code version: {', '.join(versions)}")
        return max(worst, totals(saved, sum(x.get("wall_s", 0.0) for x in saved),
                                 "summed per run"))
    durations = [int(x) for x in a.durations.split(",")]
    work = tempfile.mkdtemp(prefix="benchctl-campaign-")
    keep = str(a.keep) if a.keep else None
    modes = tuple(a.modes.split(","))
    cache = str(a.ref_cache) if a.ref_cache else None
    version = code_version()
    print(f"code version {version}", flush=True)
    done: set[int] = set()
    if a.append and a.json is not None and a.json.is_file():
        done = {int(json.loads(x)["seed"]) for x in a.json.read_text().splitlines() if x}
    jobs = [(a.seed0 + k, durations, work, keep, modes, cache, version) for k in range(a.runs)
            if a.seed0 + k not in done]
    t0 = time.perf_counter()
    lines: list[dict[str, Any]] = []
    sink = a.json.open("a" if a.append else "w") if a.json else None

    def enough() -> bool:
        return a.hours is not None and sum(x["t_sim_s"] for x in lines) >= 3600.0 * a.hours
    try:
        # runs in worker processes, even one at a time: the product's signal handling (a
        # SIGTERM to a run ends it through its cleanup) stays out of the campaign's own process,
        # so stopping the campaign never records a run it cut short as an abort
        if a.runs > 1 or a.jobs > 1:
            with multiprocessing.get_context("spawn").Pool(a.jobs) as pool:
                it = pool.imap_unordered(one, jobs)
                for line in it:
                    lines.append(line)
                    _print(line, sink)
                    if enough():
                        pool.terminate()  # the runs under way are left out, not half-counted
                        break
        else:
            for j in jobs:
                line = one(j)
                lines.append(line)
                _print(line, sink)
                if enough():
                    break
    finally:
        if sink is not None:
            sink.close()
        shutil.rmtree(work, ignore_errors=True)
    return totals(lines, time.perf_counter() - t0, "wall")


#: the fields of a run's line a replay must reproduce (wall_s and version may differ)
REPLAYED = ("mode", "link", "protocol", "profile", "duration", "faulty", "stalls", "faults",
            "verdict", "reason", "underruns", "rejoins", "t_sim_s", "violations", "digest")


def replay(a: argparse.Namespace) -> int:
    """``--replay``: the chosen seeds of an earlier campaign run again, each compared with its
    line (:data:`REPLAYED`); the campaign's ``--durations`` and ``--modes`` must be the
    earlier ones (a seed's draw depends on them). Exit 0 when every line is reproduced."""
    saved = [json.loads(x) for x in a.replay.read_text().splitlines() if x]
    failing = [x for x in saved if x.get("violations")]
    clean = [x for x in saved if not x.get("violations")]
    step = max(1, len(clean) // max(1, a.sample))
    chosen = failing + clean[::step][:a.sample]
    durations = [int(x) for x in a.durations.split(",")]
    modes = tuple(a.modes.split(","))
    version = code_version()
    old = sorted({str(x.get("version")) for x in chosen})
    print(f"replaying {len(chosen)} of {len(saved)} runs ({len(failing)} with a violation) of "
          f"{', '.join(old)} with {version}", flush=True)
    work = tempfile.mkdtemp(prefix="benchctl-replay-")
    cache = str(a.ref_cache) if a.ref_cache else None
    jobs = [(int(x["seed"]), durations, work, None, modes, cache, version) for x in chosen]
    by_seed = {int(x["seed"]): x for x in chosen}
    differ = 0
    try:
        with multiprocessing.get_context("spawn").Pool(max(1, a.jobs)) as pool:
            for line in pool.imap_unordered(one, jobs):
                was = by_seed[int(line["seed"])]
                diff = [k for k in REPLAYED if k in was and was.get(k) != line.get(k)]
                differ += bool(diff)
                print(f"seed {line['seed']}: " + (
                    "the same run" + (" (no digest in the earlier line)"
                                      if "digest" not in was else "")
                    if not diff else "DIFFERS in " + ", ".join(
                        f"{k} ({was.get(k)!r} -> {line.get(k)!r})" for k in diff)), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(f"{len(chosen) - differ} of {len(chosen)} runs reproduced exactly")
    return 1 if differ else 0


def totals(lines: list[dict[str, Any]], wall: float, what: str) -> int:
    """Print the campaign's totals; 1 when any run broke a check."""
    failing = sorted(x["seed"] for x in lines if x["violations"])
    by_check: dict[str, int] = {}
    for x in lines:
        for v in x["violations"]:
            k = v.split(":", 1)[0]
            by_check[k] = by_check.get(k, 0) + 1
    hours = sum(x["t_sim_s"] for x in lines) / 3600.0
    verdicts: dict[str, int] = {}
    for x in lines:
        verdicts[str(x.get("verdict"))] = verdicts.get(str(x.get("verdict")), 0) + 1
    print(f"\nruns {len(lines)}  simulated {hours:.2f} h  {what} {wall / 60:.1f} min  "
          f"(x{hours * 3600 / max(wall, 1e-9):.1f} real time)")
    print(f"verdicts {verdicts}")
    print(f"violations {sum(by_check.values())} {by_check}")
    print(f"failing seeds {failing}")
    return 1 if failing else 0


def _print(line: dict[str, Any], sink: Any) -> None:
    v = line["violations"]
    print(f"seed {line['seed']:5d} {line.get('mode', '?'):8s} {line.get('link', '?'):3s} "
          f"{line.get('protocol', '?'):8s} {str(line.get('profile', '?'))[:22]:22s} "
          f"{line.get('duration', 0):4}s {'F' if line.get('faulty') else '-'} "
          f"stalls {line.get('stalls', 0):3d}/{line.get('longest_stall_s', 0):5.2f}s "
          f"{line.get('verdict')!s:12s} {line['wall_s']:6.1f}s "
          + ("OK" if not v else "VIOLATION " + " | ".join(v)), flush=True)
    if sink is not None:
        sink.write(json.dumps(line, default=str) + "\n")
        sink.flush()


if __name__ == "__main__":
    sys.exit(main())
