"""The bench's own timing on the simulated bench, on simulated time.

- The calibration run (``benchctl.run.timing_cal``) of a reference of known latency measures the
  delay the simulated chain adds — the instrument's slcan line at its byte time
  (``SimInstrument.wire_delay_s``: 31 bytes of a J1939 frame with its timestamp at 115200 Bd,
  2.69 ms), the stand's link symmetric — plus a latency injected into the reference and not
  told to the calibration, within 20 µs (``TOLERANCE_S``).
- Every shipped simulated config, run on simulated time with the ``timing:`` its own
  calibration stored: σ's 95 % interval holds the simulated instrument's exact σ (its model as
  configured on the stand's measured motion: ``benchmarks/bench_timing.py``'s ``exact_sigma``),
  over one 40 s period of the paper's roll spectrum (a run's σ without the offset, and the
  figures over 360 s: ``python benchmarks/bench_timing.py``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from bench_timing import CONFIGS, LEVEL, exact_sigma, virtual_config
from live_bench import ROLL, live_bench
from repo_paths import ROOT

from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.config import SimInstrumentConfig, load_config
from benchctl.recording import load_recording
from benchctl.run import RunOptions, run_test
from benchctl.run.timing_cal import calibrate_recording

pytestmark = pytest.mark.slow
#: the calibration's tolerance on the simulated bench (s): its lines' scatter is a few µs
TOLERANCE_S = 20e-6
#: the paper's roll spectrum (profiles/paper_vessel_roll_short120.yaml) repeating every 40 s:
#: one whole period between the fades, 7 lines in 0.1 … 0.33 Hz
PAPER_40 = """
name: paper_vessel_roll_40
description: the paper's vessel roll, one 40 s period
reference: profiles/paper_vessel_roll_short120.yaml with repeat_period_s 40
kind: roll_spectrum
duration_s: 50
fade_in_s: 5
fade_out_s: 5
repeat_period_s: 40
seed: 20230652
band_hz: [0.1, 0.3334]
axes:
  roll: {model: exp_cos, sigma_deg: 3.0, period_s: 6.0, damping: 0.2}
"""


@pytest.mark.parametrize("injected_s", [0.0, 0.0073])
def test_calibration_measures_the_chain_and_an_injected_latency(
    tmp_path: Path, vclock: VirtualClock, capsys: pytest.CaptureFixture[str], injected_s: float
) -> None:
    reference = SimInstrumentConfig(gain=1.0, lag_s=0.0, latency_s=injected_s, noise_deg=0.0,
                                    bias_deg=0.0, rate_hz=100.0)
    profile = tmp_path / "roll.yaml"
    profile.write_text(ROLL)
    # J1939's 0.002° on the wire (CiA 410's 0.01° would leave ~30 µs of scatter on 16 s)
    with live_bench(tmp_path, instrument="j1939", model=reference, clock=vclock) as b:
        res = run_test(b.cfg, profile, RunOptions("REF-1", "ci"), clock=vclock)
        assert res.state == "done", res.reason
        wire = b.instrument.wire_delay_s
    rec = load_recording(res.recording)  # type: ignore[arg-type]
    told = calibrate_recording(rec, 0.0)  # the injected latency not told: it is the bench's
    assert told.offset_s == pytest.approx(wire + injected_s, abs=TOLERANCE_S)
    assert told.uncertainty_s < TOLERANCE_S / 2
    cal = calibrate_recording(rec, injected_s)  # told: the chain's alone
    assert cal.offset_s == pytest.approx(wire, abs=TOLERANCE_S)
    assert wire == pytest.approx(31 * 10 / 115200)  # a 31-byte slcan line at 115200 Bd
    # the command: the same figure, written into a bench config that then loads with it
    cfg = tmp_path / "bench.yaml"
    before = cfg.read_text()
    assert main(["timing", "calibrate", str(rec.path), "--reference-latency-s", str(injected_s),
                 "--reference", "REF-1", "--write", str(cfg), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["offset_s"] == pytest.approx(cal.offset_s, rel=1e-12)
    assert out["written"] == str(cfg) and cfg.read_text().startswith(before)
    timing = load_config(cfg).timing
    assert timing.offset_s == pytest.approx(cal.offset_s, abs=1e-7)
    assert timing.calibrated is not None and timing.reference is not None
    assert timing.reference.startswith("REF-1")


def _stored_timing(name: str) -> dict[str, Any]:
    data = yaml.safe_load((ROOT / "config" / f"{name}.yaml").read_text())
    timing: dict[str, Any] = data["timing"]
    return timing


def _run(cfg: Path, profile: Path, out: Path) -> dict[str, Any]:
    """``benchctl run --json`` on ``cfg`` without the report's figures (about 3 s of each run's
    time, and nothing here looks at them: report.json's σ, its interval and the timing are
    the same with or without them; the figures' own tests are tests/unit/report/)."""
    data = yaml.safe_load(cfg.read_text())
    data["run"]["figures"] = False
    cfg.write_text(yaml.safe_dump(data, sort_keys=False))
    code = main(["run", "--config", str(cfg), "--profile", str(profile), "--serial", "T-1",
                 "--operator", "ci", "--out", str(out), "--json"])
    assert code in (0, 1)
    (rec,) = [p.parent for p in out.glob("*/meta.json")]
    return json.loads((rec / "report.json").read_text())  # type: ignore[no-any-return]


@pytest.mark.parametrize("name", CONFIGS)
def test_every_simulated_config_holds_the_exact_sigma(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    timing = _stored_timing(name)
    assert timing["calibrated"] and timing["offset_s"] > 0
    src = ROOT / "config" / f"{name}.yaml"
    profile = tmp_path / "paper40.yaml"  # the resonant stand at half the level (LEVEL)
    profile.write_text(PAPER_40.replace("sigma_deg: 3.0", f"sigma_deg: {3.0 * LEVEL.get(name, 1)}"))
    rep = _run(virtual_config(src, tmp_path / "bench.yaml", timing=timing), profile,
               tmp_path / "runs")
    capsys.readouterr()
    roll = rep["axes"]["roll"]
    exact = exact_sigma(rep["recording"])
    lo, hi = roll["sigma_ci95"]
    assert lo <= exact <= hi, (name, roll["sigma"], lo, hi, exact)
    assert rep["timing"]["offset_s"] == timing["offset_s"]


def test_without_the_offset_sigma_reads_above_its_interval(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The default bench uncalibrated: the slcan line's 1.56 ms read as the instrument's delay
    puts σ above its interval (about +1.6 %)."""
    profile = tmp_path / "paper40.yaml"
    profile.write_text(PAPER_40)
    src = ROOT / "config/sim_virtual.yaml"
    rep = _run(virtual_config(src, tmp_path / "bench.yaml"), profile, tmp_path / "runs")
    capsys.readouterr()
    roll = rep["axes"]["roll"]
    exact = exact_sigma(rep["recording"])
    assert roll["sigma_ci95"][0] > exact, (roll["sigma"], roll["sigma_ci95"], exact)
    assert roll["sigma"] / exact - 1 == pytest.approx(0.016, abs=0.006)
    assert rep["timing"]["offset_s"] == 0.0
