"""A precision stop end to end on the simulated bench (Modbus TCP + CANopen over slcan, the
stand's trajectory queue): a repeating roll profile (T_p = 12 s, three periods) run with
``precision = 0.10`` stops after its first whole periods — faded out from where it was, the
reason and the precision in the report — and its σ agrees with the whole profile's within
their intervals. About 60 s of motion in all."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from live_bench import live_bench

from benchctl.clock.virtual import VirtualClock
from benchctl.run import RunOptions, run_test
from benchctl.run.precision import REASON_COMPLETE, REASON_PRECISION

pytestmark = pytest.mark.slow
SYSTEMATIC = 0.01  # the two records' own motion and time bases: allowed beside the intervals
PERIOD_S = 12.0
REPEATING = f"""
name: e2e_precision
description: short repeating roll for the precision stop
reference: exp-cos roll model (as ci_short), repeating every {PERIOD_S:g} s
kind: roll_spectrum
duration_s: 42
fade_in_s: 3
fade_out_s: 3
repeat_period_s: {PERIOD_S:g}
seed: 5
band_hz: [0.16, 0.5]
axes:
  roll: {{model: exp_cos, sigma_deg: 2.0, period_s: 6.0, damping: 0.2}}
"""


def _events(rec: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in (rec / "events.jsonl").read_text().splitlines()]


def test_precision_stop_end_to_end(tmp_path: Path, vclock: VirtualClock) -> None:
    profile = tmp_path / "repeating.yaml"
    profile.write_text(REPEATING)
    with live_bench(tmp_path, stand={"mode": "buffered"}, clock=vclock) as bench:
        early = run_test(bench.cfg, profile, RunOptions("EARLY", "op", precision=0.10),
                         clock=vclock)
        assert early.state == "done", early.reason
        assert bench.stand_at_rest()
        full = run_test(bench.cfg, profile, RunOptions("FULL", "op"), clock=vclock)
        assert full.state == "done", full.reason
    assert early.report is not None and full.report is not None

    # why it ended, and with what precision
    ended = early.report.ended
    assert ended is not None
    assert ended["reason"] == REASON_PRECISION and ended["requested"] == 0.10
    assert ended["precision"] <= 0.10
    assert 1 <= ended["periods"] < 3 and ended["period_s"] == PERIOD_S
    lo, hi = early.report.window
    assert hi - lo == pytest.approx(ended["periods"] * PERIOD_S, abs=1e-6)  # whole periods
    assert early.recording is not None
    on_disk = json.loads((early.recording / "report.json").read_text())
    assert on_disk["ended"]["reason"] == REASON_PRECISION
    assert "ended: precision reached" in (early.recording / "report.txt").read_text()

    fe = full.report.ended
    assert fe is not None and fe["reason"] == REASON_COMPLETE and fe["requested"] is None
    assert fe["periods"] == 3

    # the recording says it: the checks, the stop, then a fade-out from where the stand was
    ev = _events(early.recording)
    kinds = [e["kind"] for e in ev]
    checks = [e for e in ev if e["kind"] == "precision_check"]
    assert checks and checks[-1]["stop"] and all(not c["stop"] for c in checks[:-1])
    assert all(c["periods"] >= 1 for c in checks)
    stop = next(e for e in ev if e["kind"] == "early_stop")
    assert stop["reason"] == REASON_PRECISION and stop["precision"] <= 0.10
    assert stop["t_profile_s"] >= 3.0 + checks[-1]["periods"] * PERIOD_S  # after the period
    assert stop["t_profile_s"] < 42.0 - 3.0  # before the profile's own fade-out
    i_stop = kinds.index("early_stop")
    fade = [e for e in ev[i_stop:] if e["kind"] == "state" and e["to"] == "fade-out"]
    assert fade, "no fade-out after the early stop"
    assert not any(e["kind"] in ("rejoin", "underrun") for e in ev)

    # the same σ as the whole profile, within the intervals
    a, b = early.report.axes["roll"], full.report.axes["roll"]
    assert b.sigma_ci95_deg[0] * (1 - SYSTEMATIC) <= a.sigma_deg <= b.sigma_ci95_deg[1] * (
        1 + SYSTEMATIC), (a.sigma_deg, b.sigma_ci95_deg)
    assert a.sigma_ci95_deg[0] * (1 - SYSTEMATIC) <= b.sigma_deg <= a.sigma_ci95_deg[1] * (
        1 + SYSTEMATIC), (b.sigma_deg, a.sigma_ci95_deg)
