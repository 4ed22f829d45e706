"""One evaluation path (``benchctl.evaluate``): the five ways a recording becomes σ give the
same σ for the same recording and window — the run's verdict (``run.evaluation.analyse``), the
running precision check (``run.precision.check_window``, here over the verdict's window),
``analyze_recording``, ``benchctl analyze`` and ``benchctl predict``'s measured σ. One short
run of a repeating roll profile (T_p = 12 s, two whole periods) on simulated time."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from live_bench import live_bench

from benchctl.analysis.steps import motion_start
from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.evaluate import EvaluationOptions, EvaluationRequest, RunProfile, analyze_recording
from benchctl.profiles import parse_profile, synthesize
from benchctl.recording import load_recording
from benchctl.run import RunOptions, run_test
from benchctl.run.precision import check_window

pytestmark = pytest.mark.slow
PROFILE = """
name: e2e_one_path
description: short repeating roll, two whole periods between the fades
reference: exp-cos roll model (as ci_short), repeating every 12 s
kind: roll_spectrum
duration_s: 30
fade_in_s: 3
fade_out_s: 3
repeat_period_s: 12
seed: 5
band_hz: [0.16, 0.5]
axes:
  roll: {model: exp_cos, sigma_deg: 2.0, period_s: 6.0, damping: 0.2}
"""


def test_five_paths_one_sigma(tmp_path: Path, vclock: VirtualClock,
                              capsys: pytest.CaptureFixture[str]) -> None:
    profile = tmp_path / "one_path.yaml"
    profile.write_text(PROFILE)
    with live_bench(tmp_path, stand={"mode": "buffered"}, clock=vclock) as bench:
        run = run_test(bench.cfg, profile, RunOptions("ONE-PATH", "op"), clock=vclock)
        assert run.state == "done", run.reason
        cfg = bench.cfg
    assert run.report is not None and run.recording is not None
    verdict = run.report.axes["roll"].sigma_deg
    rec = load_recording(run.recording)
    window = rec.analysis_window
    assert window is not None and tuple(run.report.window) == window

    # the precision check, as the session asks for it, over the verdict's window
    spec = rec.meta["profile"]
    motion = synthesize(parse_profile(spec["spec"], spec.get("source")),
                        duration_s=rec.meta["duration_s"], seed=rec.meta["seed"])
    a = cfg.run.analysis
    request = EvaluationRequest(
        axes=list(rec.axes), window=window, options=EvaluationOptions.of_config(a),
        settle_s=a.departure_settle_s,
        profile=RunProfile.of_run(motion, motion_start(rec.events), cfg),
        require_intact=False, source=str(rec.path))
    check = check_window(rec.path, request)["roll"].sigma

    api = analyze_recording(rec.path, "roll").sigma
    assert main(["analyze", str(rec.path), "--axis", "roll", "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)["sigma"]
    assert main(["predict", str(rec.path), "--profile", str(profile), "--axis", "roll",
                 "--json"]) == 0
    predicted_from = json.loads(capsys.readouterr().out)["measured"]["sigma"]

    sigmas = {"verdict": verdict, "precision check": check, "analyze_recording": api,
              "benchctl analyze": cli, "benchctl predict": predicted_from}
    assert all(s == pytest.approx(verdict, rel=1e-12) for s in sigmas.values()), sigmas


def test_benchctl_analyze_reads_a_recording_with_the_runs_own_options(
        tmp_path: Path, vclock: VirtualClock, capsys: pytest.CaptureFixture[str]) -> None:
    """A bench whose ``run.analysis`` removes the instrument's delay and limits a band: the
    run's verdict and ``benchctl analyze <recording>`` (no option given) read the same σ, the
    same delay removed and the same band; an option given on the command line overrides the
    recording's (``--compensate-delay none``: the delay kept, σ larger — the simulated
    instrument lags 80 ms)."""
    profile = tmp_path / "one_path.yaml"
    profile.write_text(PROFILE)
    analysis = {"compensate_delay": "auto", "band_hz": [0.2, 0.4], "max_lag_s": 2.0}
    with live_bench(tmp_path, stand={"mode": "buffered"}, clock=vclock,
                    run={"analysis": analysis}) as bench:
        run = run_test(bench.cfg, profile, RunOptions("OWN-OPTIONS", "op"), clock=vclock)
        assert run.state == "done", run.reason
    assert run.report is not None and run.recording is not None
    verdict = run.report.axes["roll"].sigma_deg

    assert main(["analyze", str(run.recording), "--axis", "roll", "--json"]) == 0
    own = json.loads(capsys.readouterr().out)
    assert own["sigma"] == pytest.approx(verdict, rel=1e-12)
    assert own["max_lag"] == pytest.approx(2.0, rel=0.02)
    assert (own["band"]["lo"], own["band"]["hi"]) == (0.2, 0.4)
    assert own["uncertainty"]["compensate_delay"] == "auto"

    assert main(["analyze", str(run.recording), "--axis", "roll", "--json",
                 "--compensate-delay", "none"]) == 0
    kept = json.loads(capsys.readouterr().out)
    assert kept["uncertainty"]["compensate_delay"] == "none"
    assert kept["sigma"] > 1.5 * verdict
    assert (kept["band"]["lo"], kept["band"]["hi"]) == (0.2, 0.4)  # the others still the run's
