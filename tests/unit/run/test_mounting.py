"""The mounting check (``run.mounting_check``; ``benchctl.run.mounting``): before the motion,
each axis tilted to a few degrees and back, the instrument's response fitted, a unit mounted
reversed or with roll and pitch swapped refused with what was seen and how to fix it.

- the pure half: the response fit against exact synthetic data (closed form), the verdict's
  classification for random gains and offsets (a property test), the tilt's points within the
  stand's limits;
- the config: ``instrument.axes`` as a list or as a mapping with outputs and signs, the
  check's fields validated;
- whole runs on simulated time over the real protocols (``benchmarks/live_bench.py``, the ``vclock``
  fixture): a correct mount passes and the run proceeds; a reversed roll and a swapped unit are
  refused before the motion, the stand back at rest at zero; a reversed unit read with
  ``instrument.axes.roll.sign: -1`` measures the σ of the correctly mounted one.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from live_bench import ROLL, TWO_AXIS, LiveBench, live_bench
from run_fakes import FakeSensor, FakeStand, bench_config, sine_motion

from benchctl.clock.virtual import VirtualClock
from benchctl.config import SimInstrumentConfig, axis_map, parse_config
from benchctl.errors import ConfigError, DataError, LimitError
from benchctl.kinematics import Limits, profile_peaks
from benchctl.recording import load_recording
from benchctl.run import RunOptions, run_test
from benchctl.run import mounting as mt
from benchctl.run.prepare import prepare_motion
from benchctl.run.session import RunResult, Session

IDENTITY = {"roll": ("roll", 1), "pitch": ("pitch", 1)}
LIMITS = Limits(30.0, 30.0, 60.0)
PERIOD = 0.01


def _stand() -> dict[str, np.ndarray]:
    return mt.tilt_points(("roll", "pitch"), 2.0, 1.0, LIMITS, PERIOD)


# ------------------------------------------------------------------------------ the pure half
def test_fit_recovers_exact_gains_cross_and_offsets() -> None:
    """instrument = g·stand + cross·other + offset, exactly: every coefficient recovered to
    1e-9, nothing left over."""
    x = _stand()
    y = {"roll": 0.97 * x["roll"] + 0.04 * x["pitch"] + 0.3,
         "pitch": -1.02 * x["pitch"] - 0.06 * x["roll"] - 1.5}
    r = mt.fit_response(x, y)
    assert r.n == x["roll"].size
    assert abs(r.gain["roll"]["roll"] - 0.97) < 1e-9 and abs(r.gain["roll"]["pitch"] - 0.04) < 1e-9
    assert abs(r.gain["pitch"]["pitch"] + 1.02) < 1e-9
    assert abs(r.gain["pitch"]["roll"] + 0.06) < 1e-9
    assert abs(r.offset_deg["roll"] - 0.3) < 1e-9 and abs(r.offset_deg["pitch"] + 1.5) < 1e-9
    assert max(r.residual_deg.values()) < 1e-9


def test_fit_sampled_takes_the_instrument_delay_out() -> None:
    """Readings 90 ms late (the stand at 100 Hz, the instrument at 50 Hz on instants of its
    own): the delay found on its 5 ms grid, the gains exact again."""
    x = _stand()
    ts = np.arange(x["roll"].size) * PERIOD
    ti = np.arange(0.003, ts[-1], 0.02)

    def late(a: str) -> np.ndarray:
        return np.interp(ti - 0.09, ts, x[a])

    y = {"roll": 0.98 * late("roll") + 0.2, "pitch": -late("pitch")}
    r, d = mt.fit_sampled(ts, x, ti, y)
    assert d == pytest.approx(0.09, abs=1e-9)
    assert abs(r.gain["roll"]["roll"] - 0.98) < 1e-9 and abs(r.gain["pitch"]["pitch"] + 1) < 1e-9
    assert abs(r.gain["roll"]["pitch"]) < 1e-9 and abs(r.offset_deg["roll"] - 0.2) < 1e-9
    r0 = mt.fit_response({a: np.interp(ti, ts, v) for a, v in x.items()}, y)
    assert r0.gain["roll"]["roll"] < 0.98 - 0.005  # without the delay: lowered on the ramps


def test_fit_refuses_a_stand_that_did_not_move() -> None:
    x = _stand()
    with pytest.raises(DataError, match="the stand's pitch did not move"):
        mt.fit_response({"roll": x["roll"], "pitch": np.zeros_like(x["roll"])}, {"roll": x["roll"]})


def test_tilt_points_within_the_limits() -> None:
    """Each axis in turn to +tilt and back, from rest at zero to rest at zero, the others at
    zero meanwhile; rate and acceleration (by differences, as the stand plays the points)
    within the tilt's own caps and the limits."""
    x = _stand()
    n = x["roll"].size
    for i, a in enumerate(("roll", "pitch")):
        v = x[a]
        assert v[0] == 0.0 and v[-1] == 0.0 and v.max() == pytest.approx(2.0) and v.min() >= -1e-9
        own = v[i * n // 2:(i + 1) * n // 2]
        assert np.all(np.delete(v, np.arange(i * n // 2, (i + 1) * n // 2)) == 0.0)
        assert own.max() == 2.0
        rate, acc = profile_peaks(v, PERIOD)
        assert rate <= mt.TILT_RATE_DEG_S * (1 + 1e-9) and acc <= mt.TILT_ACCEL_DEG_S2 * (1 + 1e-6)
    # a few seconds per axis
    assert 2.0 < n * PERIOD / 2 < 6.0
    # a slow stand: its own limits (a share of them) bound the tilt
    slow = Limits(30.0, 1.0, 2.0)
    v = mt.tilt_points(("roll",), 2.0, 1.0, slow, PERIOD)["roll"]
    rate, acc = profile_peaks(v, PERIOD)
    assert rate <= 0.8 * 1.0 * (1 + 1e-9) and acc <= 0.8 * 2.0 * (1 + 1e-6)
    with pytest.raises(LimitError, match=r"allowed 1\.5°"):
        mt.tilt_points(("roll",), 2.0, 1.0, Limits(1.5, 30.0, 60.0), PERIOD)


def _readings(x: dict[str, np.ndarray], swap: bool, signs: dict[str, int], gain: float,
              cross: float, offsets: dict[str, float]) -> dict[str, np.ndarray]:
    """A unit mounted ``swap``ped and with ``signs``, of ``gain`` and ``cross``-axis
    sensitivity, reading with ``offsets``."""
    src = {"roll": "pitch", "pitch": "roll"} if swap else {"roll": "roll", "pitch": "pitch"}
    other = {"roll": "pitch", "pitch": "roll"}
    return {r: signs[r] * (gain * x[src[r]] + cross * x[other[src[r]]]) + offsets[r]
            for r in ("roll", "pitch")}


@settings(max_examples=50)
@given(
    swap=st.booleans(),
    roll_sign=st.sampled_from([1, -1]),
    pitch_sign=st.sampled_from([1, -1]),
    gain=st.floats(0.85, 1.15),
    cross=st.floats(-0.1, 0.1),
    off_r=st.floats(-5, 5),
    off_p=st.floats(-5, 5),
    noise_seed=st.integers(0, 2**32 - 1),
)
def test_verdict_classifies_sign_swap_and_gain(
    swap: bool, roll_sign: int, pitch_sign: int, gain: float, cross: float, off_r: float,
    off_p: float, noise_seed: int,
) -> None:
    """For any gain near 1, small cross-axis sensitivity, any offsets and a little noise: a
    correct mount passes; a reversed axis is REVERSED, with the sign that reads it right; a
    swapped unit is SWAPPED on both readings, with the outputs (and signs) that read it right —
    and the fix, applied to the readings, passes."""
    x = _stand()
    rng = np.random.default_rng(noise_seed)
    signs = {"roll": roll_sign, "pitch": pitch_sign}
    y = _readings(x, swap, signs, gain, cross, {"roll": off_r, "pitch": off_p})
    y = {r: v + 0.02 * rng.standard_normal(v.size) for r, v in y.items()}
    v = mt.judge(mt.fit_response(x, y), ["roll", "pitch"], IDENTITY, 0.3, 0.3, "B.yaml")
    kinds = {f.reading: f.kind for f in v.findings}
    if swap:
        assert kinds == {"roll": mt.SWAPPED, "pitch": mt.SWAPPED}
        assert not v.ok and len(v.messages) == 1 and "roll and pitch swapped?" in v.messages[0]
        assert "instrument.axes.roll.output: pitch" in v.messages[0]
        assert "instrument.axes.pitch.output: roll" in v.messages[0]
    else:
        for r in ("roll", "pitch"):
            assert kinds[r] == (mt.OK if signs[r] == 1 else mt.REVERSED)
        assert v.ok == (roll_sign == pitch_sign == 1)
        for r in ("roll", "pitch"):
            if signs[r] == -1:
                assert any(f"{r} reads −" in m and f"instrument.axes.{r}.sign: -1 in B.yaml" in m
                           and "mounted reversed?" in m for m in v.messages)
    # the fixes, read as instrument.axes does: the unit then passes
    fix: dict[str, tuple[str, int]] = dict(IDENTITY)
    for f in v.findings:
        fix.update(f.fix)
    if swap:  # each reading's fix names the other stand axis
        assert {o for o, _ in fix.values()} == {"roll", "pitch"}
    fixed = {a: s * y[o] for a, (o, s) in fix.items()}
    again = mt.judge(mt.fit_response(x, fixed), ["roll", "pitch"], fix, 0.3, 0.3)
    assert again.ok, again.detail
    # a gain far from 1 (a correct mount otherwise) is a GAIN finding, not a mounting error
    low = _readings(x, False, {"roll": 1, "pitch": 1}, 0.5, cross, {"roll": off_r, "pitch": 0})
    g = mt.judge(mt.fit_response(x, low), ["roll", "pitch"], IDENTITY, 0.3, 0.3)
    assert {f.kind for f in g.findings} == {mt.GAIN}


def test_one_axis_stand_with_a_two_axis_instrument() -> None:
    """A roll-only stand: roll must follow, pitch must not respond; a unit turned so that its
    pitch follows the stand's roll is named swapped (a fix through instrument.axes)."""
    x = {"roll": mt.tilt_points(("roll",), 2.0, 1.0, LIMITS, PERIOD)["roll"]}
    good = mt.judge(mt.fit_response(x, {"roll": x["roll"], "pitch": 0.0 * x["roll"] + 0.1}),
                    ["roll"], IDENTITY, 0.3, 0.3)
    assert good.ok, good.detail
    noise = np.random.default_rng(1).standard_normal(x["roll"].size) * 0.01
    turned = mt.judge(mt.fit_response(x, {"roll": noise, "pitch": x["roll"]}), ["roll"],
                      IDENTITY, 0.3, 0.3, "B.yaml")
    assert not turned.ok
    assert turned.messages == [
        "mounting check: roll does not follow the stand's roll (0.00×, expected 1 ± 0.3), "
        "pitch reads the stand's roll (1.00×): roll and pitch swapped? Remount the unit, or set "
        "instrument.axes.roll.output: pitch and instrument.axes.pitch.output: roll in B.yaml"
    ]
    # pitch responding to roll as well as roll: turned about the vertical
    yawed = mt.judge(mt.fit_response(x, {"roll": 0.8 * x["roll"], "pitch": 0.6 * x["roll"]}),
                     ["roll"], IDENTITY, 0.3, 0.3)
    assert not yawed.ok and "pitch reads 0.60× the stand's roll" in yawed.detail
    assert "turned about the vertical?" in yawed.detail


# ------------------------------------------------------------------------------ the config
def _cfg(tmp_path: Path, instrument: dict[str, Any] | None = None,
         run: dict[str, Any] | None = None) -> Any:
    data: dict[str, Any] = {
        "stand": {"driver": "modbus-tcp",
                  "limits": {"angle_deg": 20.0, "rate_deg_s": 50.0, "accel_deg_s2": 300.0}},
        "instrument": {"driver": "nmea0183", "serial_port": "/dev/null", **(instrument or {})},
        "run": {"limit_sigma_deg": 0.4, **(run or {})},
    }
    return parse_config(data, tmp_path / "bench.yaml")


def test_config_axes_list_or_mapping(tmp_path: Path) -> None:
    assert axis_map(_cfg(tmp_path).instrument.axes) == IDENTITY
    assert axis_map(_cfg(tmp_path, {"axes": ["roll"]}).instrument.axes) == {"roll": ("roll", 1)}
    cfg = _cfg(tmp_path, {"axes": {"roll": {"output": "pitch", "sign": -1},
                                   "pitch": {"output": "roll"}}})
    assert axis_map(cfg.instrument.axes) == {"roll": ("pitch", -1), "pitch": ("roll", 1)}
    assert cfg.instrument.outputs == ("pitch", "roll")
    assert axis_map(_cfg(tmp_path, {"axes": {"roll": {"sign": -1}, "pitch": None}})
                    .instrument.axes) == {"roll": ("roll", -1), "pitch": ("pitch", 1)}
    dumped = cfg.model_dump(mode="json")["instrument"]["axes"]
    assert dumped == {"roll": {"output": "pitch", "sign": -1}, "pitch": {"output": "roll",
                                                                         "sign": 1}}
    mc = _cfg(tmp_path).run.mounting_check
    assert mc.enabled and mc.tilt_deg == 2.0 and mc.gain_tolerance == mc.cross_tolerance == 0.3


@pytest.mark.parametrize(("instrument", "run", "match"), [
    ({"axes": {"roll": {"output": "pitch"}, "pitch": {}}}, None,
     r"field instrument.axes: .*all read the instrument's output 'pitch'"),
    ({"axes": {"roll": {"sign": 2}}}, None, r"field instrument.axes.roll.sign = 2"),
    ({"axes": {"yaw": {}}}, None, r"field instrument.axes.yaw"),
    ({"axes": {}}, None, r"field instrument.axes.*at least one axis"),
    (None, {"mounting_check": {"tilt_deg": 25.0}}, r"field run.mounting_check.tilt_deg = 25"),
    (None, {"mounting_check": {"gain_tolerance": 0.6, "cross_tolerance": 0.5}},
     r"expected a sum below 1"),
    (None, {"mounting_check": {"enabled": "maybe"}}, r"field run.mounting_check.enabled"),
])
def test_config_refuses(tmp_path: Path, instrument: dict[str, Any] | None,
                        run: dict[str, Any] | None, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        _cfg(tmp_path, instrument, run)


def test_tilt_beyond_the_stand_angle_limit_refused_before_anything_opens(
    tmp_path: Path,
) -> None:
    """Checked with the profile (``prepare_motion``), before anything opens: a LimitError
    naming the field, what the tilt needs and what the stand allows."""
    data: dict[str, Any] = {
        "stand": {"driver": "modbus-tcp",
                  "limits": {"angle_deg": 1.5, "rate_deg_s": 50.0, "accel_deg_s2": 300.0}},
        "instrument": {"driver": "nmea0183", "serial_port": "/dev/null"},
        "run": {"limit_sigma_deg": 0.4, "output_dir": str(tmp_path / "runs")},
    }
    cfg = parse_config(data, tmp_path / "bench.yaml")
    opts = RunOptions("M-1", "ci", scale_to_fit=True)  # the profile scaled into the 1.5°
    with pytest.raises(LimitError, match=r"bench\.yaml: field run\.mounting_check\.tilt_deg = "
                       r"2°: setpoint roll = .*needs \|angle\| .*allowed 1\.5° \(field "
                       r"stand\.limits\); expected a smaller tilt, or "
                       r"run\.mounting_check\.enabled: false"):
        prepare_motion(cfg, _profile(tmp_path, ROLL), opts)
    assert not (tmp_path / "runs").exists()
    data["run"]["mounting_check"] = {"tilt_deg": 1.0}
    prep = prepare_motion(parse_config(data, tmp_path / "bench.yaml"), tmp_path / "profile.yaml",
                          opts)
    assert prep.tilt is not None and float(np.max(prep.tilt.values["roll"])) == 1.0
    data["run"]["mounting_check"] = {"enabled": False}
    assert prepare_motion(parse_config(data, tmp_path / "bench.yaml"),
                          tmp_path / "profile.yaml", opts).tilt is None


# ------------------------------------------------------------------------------ on the fakes
def _fake_run(tmp_path: Path, stand: FakeStand, sensor: FakeSensor, mode: str) -> RunResult:
    cfg = bench_config(tmp_path, mounting_check={"enabled": True})
    prep = sine_motion(stand.axes, duration_s=3.0, mode=mode, fade_s=0.5)
    return Session(cfg, prep, RunOptions("SN-1", "tester"),
                   device_factory=lambda c, p: (stand, sensor), clock=stand.clock).run()


def test_fakes_table_mode_tilts_by_setpoints_then_plays_the_table(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    """A stand that plays tables takes the tilt as setpoints (as its ramp to zero); the table
    is uploaded after the check, and the run goes on."""
    stand = FakeStand(("roll", "pitch"), clock=vclock)
    res = _fake_run(tmp_path, stand, FakeSensor(stand, gain=1.02, bias=0.1), "table")
    assert res.state == "done" and res.exit_code == 0, res.reason
    ev = load_recording(res.recording).events  # type: ignore[arg-type]
    kinds = [e["kind"] for e in ev]
    assert kinds.index("mounting_start") < kinds.index("mounting_motion_start") < kinds.index(
        "table_uploaded") < kinds.index("motion_start")
    m = next(e for e in ev if e["kind"] == "precheck" and e["name"] == "mounting")
    assert m["ok"] and m["detail"].startswith("mounted as configured: roll 1.020× the stand's "
                                              "roll, pitch 1.020× the stand's pitch")
    assert stand.calls.index("upload_table") > stand.calls.index("enable")
    assert max(abs(v["roll"]) for _, v in stand.sent) == pytest.approx(2.0)


def test_fakes_reversed_refused_in_stream_mode(tmp_path: Path, vclock: VirtualClock) -> None:
    stand = FakeStand(("roll",), clock=vclock)
    res = _fake_run(tmp_path, stand, FakeSensor(stand, gain=-1.0), "stream")
    assert res.state == "aborted" and res.exit_code == 2
    assert "roll reads −1.00× the stand's roll: mounted reversed?" in res.reason
    assert res.abort is not None and res.abort["kind"] == "equipment"
    assert res.abort["stand"]["at_zero"] and res.abort["stand"]["at_rest"]
    assert stand.enabled is False and stand.true_angle() == {"roll": 0.0}


def test_fakes_fault_during_the_tilt_takes_the_one_cleanup_path(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    """A stand fault 1 s into the tilt (up at about 1°): the run aborts from its prechecks
    through the one cleanup path — the tilt's loop stopped, the stand ramped to zero and
    disabled — and the profile never starts."""
    stand = FakeStand(("roll",), clock=vclock)
    stand.fault_at = 1.0  # the fake's motion time: from its first setpoint, the tilt's
    res = _fake_run(tmp_path, stand, FakeSensor(stand), "stream")
    assert res.state == "aborted" and res.exit_code == 2 and "fault code 7" in res.reason
    ev = load_recording(res.recording).events  # type: ignore[arg-type]
    kinds = [e["kind"] for e in ev]
    assert "mounting_motion_start" in kinds and "motion_start" not in kinds
    assert [e["to"] for e in ev if e["kind"] == "state"] == ["prechecks", "aborted"]
    assert stand.ramped and stand.enabled is False and stand.true_angle() == {"roll": 0.0}
    steps = [s["step"] for s in res.shutdown]
    assert "ramp to zero" in steps and "stop table" not in steps


# ------------------------------------------------------------------------------ whole runs
def _profile(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "profile.yaml"
    p.write_text(text)
    return p


def _model(noise_deg: float = 0.01, **mounting: Any) -> SimInstrumentConfig:
    return SimInstrumentConfig(lag_s=0.05, noise_deg=noise_deg, rate_hz=100.0,
                               mounting=mounting)


def _run(tmp_path: Path, vclock: VirtualClock, text: str, *, mounting: dict[str, Any] | None = None,
         axes: dict[str, Any] | None = None, noise_deg: float = 0.01,
         **bench: Any) -> tuple[RunResult, LiveBench, list[dict[str, Any]]]:
    extra = {"axes": axes} if axes is not None else None
    tmp_path.mkdir(parents=True, exist_ok=True)
    with live_bench(tmp_path, model=_model(noise_deg, **(mounting or {})), clock=vclock,
                    instrument_extra=extra, **bench) as b:
        res = run_test(b.cfg, _profile(tmp_path, text), RunOptions("M-1", "ci"), clock=vclock)
        assert b.stand_at_rest()
    assert res.recording is not None
    return res, b, load_recording(res.recording).events


GAIN_SHOWN = r"(0\.99|1\.00|1\.01)×"  # the gain as shown: the instrument's lag, its wire


def _refused(res: RunResult, events: list[dict[str, Any]], message: str) -> None:
    """Refused by the mounting precheck (``message``: a regular expression of its detail),
    before the motion; the stand at rest at zero."""
    assert res.state == "aborted" and res.exit_code == 2
    assert re.fullmatch(f"run: precheck 'mounting' failed: {message}", res.reason), res.reason
    kinds = [e["kind"] for e in events]
    assert "mounting_motion_start" in kinds and "motion_start" not in kinds
    pre = [e for e in events if e["kind"] == "precheck" and e["name"] == "mounting"]
    assert len(pre) == 1 and not pre[0]["ok"] and re.fullmatch(message, pre[0]["detail"])
    assert res.abort is not None and res.abort["kind"] == "equipment"
    assert res.abort["stand"]["at_zero"] and res.abort["stand"]["at_rest"]
    assert res.abort["stand"]["known"] and res.abort["stand"]["commands"] == []
    assert res.record is not None
    record = json.loads(res.record.read_text())
    assert record["outcome"] == "ABORTED" and record["exit_code"] == 2
    m = next(m for m in record["measurements"] if m["name"] == "precheck: mounting")
    assert m["outcome"] == "FAIL" and re.fullmatch(message, m["note"])
    assert "mounting check:" in (res.recording / "report.html").read_text()  # type: ignore[operator]


@pytest.mark.slow
def test_correct_mount_passes_and_reversed_read_with_sign_measures_the_same_sigma(
    tmp_path: Path,
) -> None:
    """Table mode over Modbus TCP and CANopen: the correct unit passes the check and the run
    goes on (PASS); the same unit mounted with its roll reversed, read with
    ``instrument.axes.roll.sign: -1``, passes too, and its σ is the correct one's (the same
    simulated time, no noise: a noise drawn alike would enter with the other sign) to 1e-6; the
    tilt is recorded and left out of the analysis; the tilt's commanded motion
    is within the stand's limits."""
    # each run on a simulated time of its own, from the same start: the same instants
    with (vclock := VirtualClock(hang_s=120.0)).running():
        good, b, ev = _run(tmp_path / "good", vclock, TWO_AXIS, stand={"mode": "table"},
                           noise_deg=0.0)
    assert good.state == "done" and good.exit_code == 0, good.reason
    kinds = [e["kind"] for e in ev]
    assert kinds.index("mounting_start") < kinds.index("mounting_motion_start") < kinds.index(
        "motion_start")
    pre = next(e for e in ev if e["kind"] == "precheck" and e["name"] == "mounting")
    assert pre["ok"] and pre["values"]["findings"] == {"roll": "ok", "pitch": "ok"}
    gains = pre["values"]["response"]["gain"]
    assert gains["roll"]["roll"] == pytest.approx(1.0, abs=0.02)
    assert abs(gains["roll"]["pitch"]) < 0.02 and abs(gains["pitch"]["roll"]) < 0.02
    rec = load_recording(good.recording)  # type: ignore[arg-type]
    t_tilt = next(e["t_host"] for e in ev if e["kind"] == "mounting_motion_start")
    t_motion = next(e["t_host"] for e in ev if e["kind"] == "motion_start")
    sp = rec.streams["setpoints"]
    tilt = (sp["t_send"] >= t_tilt) & (sp["t_send"] < t_motion)
    for a in ("roll", "pitch"):  # the commanded tilt: within the limits (benchmarks/live_bench.py)
        v = sp[f"{a}_deg"][tilt]
        assert v.size > 300 and np.nanmax(np.abs(v)) == pytest.approx(2.0)
        rate, acc = profile_peaks(v[np.isfinite(v)], 0.01)
        assert rate <= 40.0 and acc <= 200.0 and rate <= mt.TILT_RATE_DEG_S * 1.001
    st = rec.streams["stand"]
    kept = (st["t_host"] > t_tilt) & (st["t_host"] < t_motion)
    assert kept.sum() > 300  # the tilt's samples kept in the recording …
    lo, _hi = good.report.window  # type: ignore[union-attr]
    assert lo > t_motion  # … and outside the analysis window
    rec_json = json.loads(good.record.read_text())  # type: ignore[union-attr]
    assert rec_json["instruments"][0]["axes"] == {"roll": {"output": "roll", "sign": 1},
                                                  "pitch": {"output": "pitch", "sign": 1}}
    assert any(m["name"] == "precheck: mounting" and m["outcome"] == "PASS"
               for m in rec_json["measurements"])

    with (vclock := VirtualClock(hang_s=120.0)).running():
        fixed, _, _ev = _run(tmp_path / "fixed", vclock, TWO_AXIS, stand={"mode": "table"},
                             mounting={"roll_sign": -1}, noise_deg=0.0,
                             axes={"roll": {"sign": -1}, "pitch": {}})
    assert fixed.state == "done" and fixed.exit_code == 0, fixed.reason
    assert good.report is not None and fixed.report is not None
    for a in ("roll", "pitch"):
        assert fixed.report.axes[a].sigma_deg == pytest.approx(
            good.report.axes[a].sigma_deg, rel=1e-6), a
    rec_json = json.loads(fixed.record.read_text())  # type: ignore[union-attr]
    assert rec_json["instruments"][0]["axes"]["roll"] == {"output": "roll", "sign": -1}
    del b


def test_reversed_roll_refused(tmp_path: Path, vclock: VirtualClock) -> None:
    """Modbus RTU and NMEA 0183, the buffered stand, a roll profile: roll mounted reversed is
    refused with what was seen and the fix."""
    res, b, ev = _run(tmp_path, vclock, ROLL, mounting={"roll_sign": -1}, transport="rtu",
                      instrument="nmea0183", stand={"mode": "buffered", "baudrate": 460800},
                      sim_stand={"baudrate": 460800})
    _refused(res, ev, f"mounting check: roll reads −{GAIN_SHOWN} the stand's roll: mounted "
             "reversed\\? Remount the unit, or set instrument\\.axes\\.roll\\.sign: -1 in "
             + re.escape(str(b.config_path)))


def test_swapped_refused(tmp_path: Path, vclock: VirtualClock) -> None:
    """Modbus TCP and CANopen, stream mode, two axes: roll and pitch swapped is refused."""
    res, b, ev = _run(tmp_path, vclock, TWO_AXIS, mounting={"swap_axes": True},
                      stand={"mode": "stream"})
    _refused(res, ev, re.escape("mounting check: roll reads the stand's pitch (")
             + GAIN_SHOWN + re.escape(") and not its roll, pitch reads the stand's roll (")
             + GAIN_SHOWN + re.escape(") and not its pitch: roll and pitch swapped? Remount the "
                                      "unit, or set instrument.axes.roll.output: pitch and "
                                      f"instrument.axes.pitch.output: roll in {b.config_path}"))


def test_one_axis_stand_checks_the_other_reading_does_not_respond(
    tmp_path: Path, vclock: VirtualClock
) -> None:
    """A roll-only stand (``stand.axes: [roll]``) and a two-axis CANopen unit: mounted right,
    roll follows and pitch does not respond (the run goes on to its verdict); swapped, roll
    follows nothing and pitch follows roll — refused, with the mapping that reads it."""
    stand = {"axes": ["roll"], "mode": "stream"}
    good, _, ev = _run(tmp_path / "good", vclock, ROLL, stand=stand)
    assert good.state == "done" and good.exit_code in (0, 3), good.reason
    pre = next(e for e in ev if e["kind"] == "precheck" and e["name"] == "mounting")
    assert pre["ok"] and pre["values"]["findings"] == {"roll": "ok", "pitch": "ok"}
    assert list(pre["values"]["response"]["gain"]["pitch"]) == ["roll"]  # roll tilted only
    res, b, ev = _run(tmp_path / "swapped", vclock, ROLL, stand=stand,
                      mounting={"swap_axes": True})
    _refused(res, ev, re.escape("mounting check: roll does not follow the stand's roll (")
             + r"−?0\.0\d×" + re.escape(", expected 1 ± 0.3), pitch reads the stand's roll (")
             + GAIN_SHOWN + re.escape("): roll and pitch swapped? Remount the unit, or set "
                                      "instrument.axes.roll.output: pitch and "
                                      f"instrument.axes.pitch.output: roll in {b.config_path}"))
