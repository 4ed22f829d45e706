"""``benchctl predict`` of a two-axis recording: every axis the other profile moves is
predicted, each from its own lines; an axis of the recording the profile does not move is named
with the reason, in the text and in the JSON (before, a roll-only profile gave roll alone and
said nothing of pitch)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from predict_cases import NOISE, closed_form, lag_response

from benchctl.cli import main
from benchctl.profiles import load_profile, synthesize

TWO_AXES = """
name: flat_two_axes
description: flat roll and pitch multisines for prediction tests
reference: synthetic
kind: roll_spectrum
duration_s: 58
fade_in_s: 4
fade_out_s: 4
seed: 3
band_hz: [0.04, 0.6]
axes:
  roll: {model: table, freq_hz: [0.02, 0.65], density_deg2_hz: [5.0, 5.0]}
  pitch: {model: table, freq_hz: [0.02, 0.65], density_deg2_hz: [2.0, 2.0]}
"""
ROLL_ONLY = """
name: harmonics_roll
description: two roll lines
reference: synthetic
kind: harmonics
duration_s: 30
fade_in_s: 2
fade_out_s: 2
seed: 1
axes:
  roll:
    lines:
      - {amplitude_deg: 3.0, freq_hz: 0.15}
      - {amplitude_deg: 2.0, freq_hz: 0.32}
"""
BOTH = ROLL_ONLY.replace("name: harmonics_roll", "name: harmonics_both") + """  pitch:
    lines:
      - {amplitude_deg: 1.5, freq_hz: 0.2}
      - {amplitude_deg: 1.0, freq_hz: 0.4}
"""
AXES = ("roll", "pitch")


def make_two_axis_recording(folder: Path, profile_path: Path) -> Path:
    """A closed recording of the two-axis ``profile_path`` (steady 50 s): each axis through
    ``lag_response`` with white noise ``NOISE``, independently."""
    from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
    from benchctl.recording import RecordingWriter

    profile = load_profile(profile_path)
    tables = synthesize(profile).tables
    assert tables is not None
    meta = {"serial": "P-2", "profile": profile.to_dict(), "seed": 3, "duration_s": 58.0,
            "fade_in_s": 4.0, "fade_out_s": 4.0}
    w = RecordingWriter(folder, AXES, meta)
    status = StandStatus(ready=True, enabled=True, moving=True, fault=False, estop=False,
                         limit=False)
    rng = np.random.default_rng(5)
    t0 = 100.0
    ts = t0 - 1.0 + np.arange(6000) / 100.0
    stand = {a: tables[a].evaluate(ts - t0).tolist() for a in AXES}
    for i, t in enumerate(ts.tolist()):
        ang = {a: stand[a][i] for a in AXES}
        w.write_stand(StandSample(t_host=t, rtt_s=0.004, angle_deg=ang,
                                  rate_deg_s=dict.fromkeys(AXES, 0.0),
                                  setpoint_deg=dict.fromkeys(AXES, 0.0), status=status))
    ti = t0 + np.arange(2900) / 50.0
    out = {}
    for a in AXES:
        tab = tables[a]
        h = lag_response(tab.freq_hz)
        arg = 2 * np.pi * tab.freq_hz[:, None] * (ti - t0) + tab.phase_rad[:, None]
        y = (tab.amp_deg[:, None] * np.abs(h)[:, None]
             * np.cos(arg + np.angle(h)[:, None])).sum(0)
        out[a] = (y + rng.normal(0.0, NOISE, ti.size)).tolist()
    for i, t in enumerate(ti.tolist()):
        w.write_instrument(InstrumentSample(t_host=t, angle_deg={a: out[a][i] for a in AXES},
                                            counter=i))
    w.close("done", analysis_window=[t0 + 4.0, t0 + 54.0])
    return folder


@pytest.fixture(scope="module")
def two_axes(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    tmp = tmp_path_factory.mktemp("predict_axes")
    (tmp / "a.yaml").write_text(TWO_AXES)
    (tmp / "roll.yaml").write_text(ROLL_ONLY)
    (tmp / "both.yaml").write_text(BOTH)
    return make_two_axis_recording(tmp / "rec", tmp / "a.yaml"), tmp / "roll.yaml", \
        tmp / "both.yaml"


def test_a_two_axis_profile_is_predicted_on_both_axes(
    two_axes: tuple[Path, Path, Path], capsys: pytest.CaptureFixture[str],
) -> None:
    rec, _, both = two_axes
    assert main(["predict", str(rec), "--profile", str(both), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert list(d["axes"]) == ["roll", "pitch"] and d["not_predicted"] == {}
    lines = {"roll": ([0.15, 0.32], [3.0, 2.0]), "pitch": ([0.2, 0.4], [1.5, 1.0])}
    for axis, (f, a) in lines.items():
        got = d["axes"][axis]
        truth = closed_form(np.array(f), np.array(a), NOISE)
        assert got["axis"] == axis and got["lines"]["freq"] == pytest.approx(f)
        assert got["sigma"] == pytest.approx(math.sqrt(truth), rel=0.01)
    assert main(["predict", str(rec), "--profile", str(both)]) == 0
    text = capsys.readouterr().out.splitlines()
    assert text[0] == f"benchctl predict: {rec}: axes roll, pitch; predicted roll, pitch"
    heads = [ln for ln in text if ln.startswith("benchctl predict: ") and "→" in ln]
    assert [h.split("[")[1].split("]")[0] for h in heads] == ["roll", "pitch"]


def test_an_axis_the_profile_does_not_move_is_named_not_dropped(
    two_axes: tuple[Path, Path, Path], capsys: pytest.CaptureFixture[str],
) -> None:
    rec, roll_only, _ = two_axes
    assert main(["predict", str(rec), "--profile", str(roll_only), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    assert list(d["axes"]) == ["roll"]
    assert list(d["not_predicted"]) == ["pitch"]
    assert d["not_predicted"]["pitch"].startswith(
        "the profile harmonics_roll moves roll only; with pitch held at zero")
    assert main(["predict", str(rec), "--profile", str(roll_only)]) == 0
    text = capsys.readouterr().out.splitlines()
    assert text[0] == (f"benchctl predict: {rec}: axes roll, pitch; predicted roll; not "
                       "predicted pitch")
    assert text[-1].startswith(f"benchctl predict: {rec}  [pitch]  not predicted: the profile "
                               "harmonics_roll moves roll only")
    # asked for that axis alone: an error naming what the profile moves
    assert main(["predict", str(rec), "--profile", str(roll_only), "--axis", "pitch"]) == 2
    assert "moves roll, none of the recording's pitch" in capsys.readouterr().err
