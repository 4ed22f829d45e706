"""Time bases end to end: a stalled host does not bias σ.

A real run (``run_test``, what ``benchctl run --json`` prints) of the default bench
(config/sim.yaml's instrument model: CANopen over slcan at 100 Hz, buffered Modbus TCP stand)
measures the simulated stand, on simulated time over in-process links, while the host is
stopped for 0.1–0.3 s five times (``VirtualClock.stall_host``: every thread of the run stops as
by SIGSTOP, the simulators run on): the reader then reads a burst of frames late. The run's
line-wise σ must stay within 2 % of the same run unstalled and of the simulated instrument's
stated σ (``live_bench.expected_sigma``) — the instants come from the adapter's timestamps —, and
so must the σ from the receipt stamps alone (the fitted time base).

The stalls are drawn as before (seed 3: 1–2 s apart, 0.1–0.3 s long, from the moment the
motion is seen to start) and, on simulated time, happen exactly so: the same pattern every run.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from live_bench import ROLL, ROOT, LiveBench, expected_sigma, live_bench

from benchctl.analysis import AnalysisResult, analyze
from benchctl.analysis.lines import line_set_from_recording
from benchctl.analysis.steps import motion_start
from benchctl.clock.virtual import VirtualClock
from benchctl.config import load_config
from benchctl.jsonout import dumps
from benchctl.recording import load_recording
from benchctl.run import RunOptions, run_test
from benchctl.run.prepare import prepare_motion

pytestmark = pytest.mark.slow


def _motion_started(runs: Path, before: set[Path]) -> bool:
    """The run's own event: its recording shows ``motion_start``."""
    new = [d for d in set(runs.glob("*")) - before if d.is_dir()]
    ev = new[0] / "events.jsonl" if new else None
    return ev is not None and ev.is_file() and '"motion_start"' in ev.read_text()


def _stall_when_moving(clock: VirtualClock, runs: Path, before: set[Path], stalls: int,
                       drawn: list[tuple[float, float]]) -> None:
    """Once the motion is seen to start, stop the host ``stalls`` times (seed 3: 1–2 s apart,
    0.1–0.3 s long), each stall laid on the clock (``drawn``: its start and length)."""
    deadline = clock.monotonic() + 60
    while clock.monotonic() < deadline and not _motion_started(runs, before):
        clock.sleep(0.05)
    rng = np.random.default_rng(3)
    t = clock.monotonic()
    for _ in range(stalls):
        t += float(rng.uniform(1.0, 2.0))
        length = float(rng.uniform(0.1, 0.3))
        clock.stall_host(t, length)
        drawn.append((t, length))
        t += length


def _run(b: LiveBench, profile: Path, stalls: int, clock: VirtualClock
         ) -> tuple[dict[str, Any], list[tuple[float, float]]]:
    runs = Path(b.cfg.run.output_dir)
    runs.mkdir(parents=True, exist_ok=True)
    before = set(runs.glob("*"))
    drawn: list[tuple[float, float]] = []
    watcher = None
    if stalls:  # the stalls' side: a device thread (sim-…), which the stalls leave running
        watcher = clock.thread(_stall_when_moving, name="sim-host-stalls",
                               args=(clock, runs, before, stalls, drawn))
        watcher.start()
    res = run_test(b.cfg, profile, RunOptions("TB", "ci"), clock=clock)
    if watcher is not None:
        watcher.join()
    result: dict[str, Any] = json.loads(dumps(res.to_dict()))  # what `benchctl run --json` prints
    return result, drawn


def _lines(rec: Any) -> Any:
    ls, why = line_set_from_recording(rec.meta, "roll", rec.analysis_window)
    assert ls is not None, why
    return ls


def test_stalled_run_sigma_as_unstalled(tmp_path: Path, vclock: VirtualClock) -> None:
    default = load_config(ROOT / "config/sim.yaml")
    assert default.sim is not None
    profile = tmp_path / "p.yaml"
    profile.write_text(ROLL)
    with live_bench(tmp_path, model=default.sim.instrument, stand={"mode": "buffered"},
                    clock=vclock) as b:
        prep = prepare_motion(b.cfg, profile, RunOptions("x", "y"))
        expect = expected_sigma(b, prep.motion, "roll")
        calm, _ = _run(b, profile, 0, vclock)
        res, drawn = _run(b, profile, 5, vclock)
    for r in (calm, res):
        assert r["verdict"] == "PASS", r.get("reason")
    rec = load_recording(Path(res["recording"]))
    # the five stalls, as drawn, all inside the motion (its 20 s)
    t0 = motion_start(rec.events)
    assert t0 is not None and len(drawn) == 5, drawn
    assert all(0.1 <= d <= 0.3 and t0 < t and t + d < t0 + 20.0 for t, d in drawn), (t0, drawn)
    # the line-wise σ (a least-squares fit of the profile's lines to the samples present): a
    # loaded host also leaves gaps in the reference that no spline may bridge (0.5 s), whose
    # samples the headline σ leaves out unevenly (it warns); the line-wise σ is unmoved by them
    sigma = res["axes"]["roll"]["analysis"]["lines"]["sigma"]
    sigma_calm = calm["axes"]["roll"]["analysis"]["lines"]["sigma"]
    assert sigma == pytest.approx(sigma_calm, rel=0.02), (sigma, sigma_calm)
    assert sigma == pytest.approx(expect, rel=0.02), (sigma, expect)
    got: dict[str, AnalysisResult] = {}
    for tb in ("adapter", "fitted", "receipt"):
        r = analyze(*rec.pair("roll", timebase=tb), lines=_lines(rec))
        got[tb] = r
        assert r.timing["device_timebase"] == tb
    assert got["adapter"].sigma == pytest.approx(res["axes"]["roll"]["sigma"], rel=1e-9)
    assert got["fitted"].lines is not None
    assert got["fitted"].lines.sigma == pytest.approx(sigma_calm, rel=0.02)
    # the stalls' bursts were there: receipts late by up to the stall, found late and dated
    # by the adapter's clock; as received they would be warned about
    assert got["adapter"].timing["device_late_stamps"] > 20
    assert got["adapter"].gaps["device"]["count"] == 0
    assert got["adapter"].timing["timing_share"] < 0.01
    assert any("timing:" in w for w in got["receipt"].warnings), (
        got["receipt"].timing, got["receipt"].variance, got["receipt"].warnings, drawn)
