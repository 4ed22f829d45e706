"""``benchctl analyze`` on two CSVs, no option about time: an instrument clock fast by 200 ppm
and 1 ms rms jitter on both streams' stamps.

The reference (100 Hz, host clock) and the instrument (50 Hz, gain 0.995, 80 ms lag, 10 ms
delay, 0.05° noise; its stamps from its own clock, 200 ppm fast) over 900 s of a multisine
with lines k/100 s; both files' stamps jittered by 1 ms rms and written to the microsecond.
With the default options the analysis must choose the fitted time base for both (the jitter
is the stamps'), measure the skew (within 1 ppm), take it out and state it (JSON, the summary,
a warning), and read σ within 1 % of the closed form (the goal), here 0.3 %.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from timing_drift import skewed

from benchctl.cli import main


def test_skewed_jittered_csv_pair_by_default(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    (tr, x, td, y), truth = skewed(200.0)
    rng = np.random.default_rng(5)
    tr = tr + rng.normal(0.0, 1e-3, tr.size)
    td = td + rng.normal(0.0, 1e-3, td.size)
    for name, t, v in (("ref", tr, x), ("dev", td, y)):
        np.savetxt(tmp_path / f"{name}.csv", np.column_stack([t, v]), delimiter=",",
                   header="time,angle", comments="", fmt="%.6f")
    args = ["analyze", "--reference", str(tmp_path / "ref.csv"), "--device",
            str(tmp_path / "dev.csv")]
    assert main([*args, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    tm = out["timing"]
    assert tm["timebase_choice"]["device"]["used"] == "fitted"
    assert tm["timebase_choice"]["reference"]["used"] == "fitted"
    assert tm["skew_corrected"] is True
    assert tm["skew_ppm"] == pytest.approx(200.0, abs=1.0)
    assert out["sigma"] == pytest.approx(truth, rel=0.003)
    assert out["sigma_ci95"][0] <= truth <= out["sigma_ci95"][1]
    said = [re.search(r"stamps drift against the reference's by \+([0-9.]+) ppm", w)
            for w in out["warnings"]]
    assert any(m and float(m.group(1)) == pytest.approx(200.0, abs=1.0) for m in said)
    # the correction's own uncertainty is in σ's interval, and the warning states the offset
    assert tm["timing_in_interval"] is True
    off = [re.search(r"an offset of ±([0-9.]+) ms between the streams", w) for w in out["warnings"]]
    assert any(m and float(m.group(1)) == pytest.approx(1e3 * tm["timing_offset_u_s"], rel=0.01)
               for m in off)
    assert main(args) == 0
    text = capsys.readouterr().out
    m = re.search(r"clock skew: \+([0-9.]+) ppm .*, corrected", text)
    assert m and float(m.group(1)) == pytest.approx(200.0, abs=1.0)
    assert "timing: device fitted" in text and "auto:" in text
