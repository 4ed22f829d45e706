"""Measurements, decision rules, outcomes and the run's record.

- decision rules: examples, and properties (guarded never PASSes with the upper bound over the
  limit, never FAILs with the lower bound within it; simple and guarded agree when the
  interval is on one side of the limit);
- a report's verdict and exit code under each rule (INCONCLUSIVE → exit 3);
- runs against the in-process fakes: record.json valid for a PASS, and for aborts by the
  operator (SIGINT), the equipment (a stand fault) and the software (an exception in a driver);
- a real simulated run through the CLI: record.json valid, part number and rule in it;
- ``benchctl schema record``; the strict JSON encoder; the version from package metadata.

One file (about 630 lines): the record is where measurements, rules and outcomes meet, and its
cases share the same fakes.
"""

from __future__ import annotations

import json
import math
import subprocess
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from live_bench import ROOT
from run_fakes import FakeSensor, FakeStand, bench_config, sine_motion

from benchctl.cli import main
from benchctl.clock.virtual import VirtualClock
from benchctl.config import BenchConfig, UnitConfig, parse_config
from benchctl.errors import AnalysisError, DataError, DeviceTimeout, SafetyAbort, StandFault
from benchctl.jsonout import dumps, loads_strict, plain
from benchctl.recording import load_recording
from benchctl.results.measurements import (
    FAIL,
    INCONCLUSIVE,
    NOT_JUDGED,
    PASS,
    WARNING,
    Limits,
    axis_measurements,
    decide,
    judge,
    overall,
    serial_match,
    serial_measurement,
)
from benchctl.results.record import (
    RECORD_JSON,
    abort_kind,
    build_record,
    load_record,
    record_schema,
    validate_record,
    write_record,
)
from benchctl.run.prepare import RunOptions, prepare_motion
from benchctl.run.report import AxisVerdict, Report
from benchctl.run.session import RunResult, Session
from benchctl.run.supervisor import Supervisor

finite = st.floats(min_value=-1e6, max_value=1e6, allow_nan=False, allow_infinity=False)
positive = st.floats(min_value=1e-6, max_value=1e3, allow_nan=False, allow_infinity=False)


# ------------------------------------------------------------------------------ decision rules
@pytest.mark.parametrize(
    ("value", "ci", "rule", "expect"),
    [
        (0.30, (0.28, 0.32), "simple", PASS),
        (0.30, (0.28, 0.32), "guarded", PASS),
        (0.39, (0.37, 0.42), "simple", PASS),  # value within, interval straddles the limit
        (0.39, (0.37, 0.42), "guarded", INCONCLUSIVE),
        (0.41, (0.38, 0.44), "simple", FAIL),
        (0.41, (0.38, 0.44), "guarded", INCONCLUSIVE),
        (0.45, (0.41, 0.49), "guarded", FAIL),
        (0.40, (0.40, 0.40), "guarded", PASS),  # on the limit: within
        (math.nan, (0.1, 0.2), "simple", FAIL),  # no value is no pass
        (0.30, (0.28, math.inf), "guarded", INCONCLUSIVE),  # an open upper bound never passes
    ],
)
def test_decision_rule_examples(value: float, ci: tuple[float, float], rule: str,
                                expect: str) -> None:
    assert decide(value, None, 0.4, ci, rule) == expect


def test_two_sided_limits_and_no_limit() -> None:
    assert decide(1.02, 0.95, 1.05, (1.00, 1.04), "guarded") == PASS
    assert decide(1.02, 0.95, 1.05, (1.00, 1.06), "guarded") == INCONCLUSIVE
    assert decide(0.90, 0.95, 1.05, (0.88, 0.93), "guarded") == FAIL  # wholly below
    assert decide(0.90, 0.95, 1.05, None, "guarded") == FAIL  # no interval: simple
    assert decide(0.90, None, None, (0.8, 1.0), "guarded") == NOT_JUDGED
    with pytest.raises(ValueError, match="expected one of simple, guarded"):
        decide(0.1, None, 0.4, None, "lenient")


@given(value=finite, a=finite, b=finite, limit=finite)
def test_guarded_never_passes_over_nor_fails_within(value: float, a: float, b: float,
                                                    limit: float) -> None:
    lo, hi = min(a, b), max(a, b)
    out = decide(value, None, limit, (lo, hi), "guarded")
    if hi > limit:
        assert out != PASS
    if lo <= limit:
        assert out != FAIL
    # and it is decided whenever the interval is on one side
    if hi <= limit:
        assert out == PASS
    if lo > limit:
        assert out == FAIL


@given(half=positive, limit=positive, rel=st.floats(min_value=-3, max_value=3))
def test_simple_and_guarded_agree_off_the_limit(half: float, limit: float, rel: float) -> None:
    """An interval wholly on one side of the limit: both rules say the same; straddling, the
    guarded rule says INCONCLUSIVE where the simple one decides by the value."""
    value = limit + rel * half
    ci = (value - half, value + half)
    simple, guarded = decide(value, None, limit, ci, "simple"), decide(
        value, None, limit, ci, "guarded")
    if ci[1] <= limit or ci[0] > limit:
        assert simple == guarded
    else:
        assert guarded == INCONCLUSIVE and simple in (PASS, FAIL)


def _verdict(sigma: float, ci: tuple[float, float], rule: str) -> AxisVerdict:
    return AxisVerdict("roll", sigma, ci, 100.0, 0.0, sigma, 0.01, 0.4, rule=rule)


@pytest.mark.parametrize(
    ("rule", "ci", "verdict", "code"),
    [
        ("simple", (0.37, 0.42), PASS, 0),
        ("guarded", (0.37, 0.42), INCONCLUSIVE, 3),
        ("guarded", (0.30, 0.35), PASS, 0),
        ("guarded", (0.41, 0.45), FAIL, 1),
    ],
)
def test_report_verdict_and_exit_code_by_rule(tmp_path: Path, rule: str, ci: tuple[float, float],
                                              verdict: str, code: int) -> None:
    sigma = 0.5 * (ci[0] + ci[1]) if rule != "simple" else 0.39
    v = _verdict(sigma, ci, rule)
    ms = axis_measurements("roll", v.to_dict(), Limits(sigma_deg=0.4), rule)
    rep = Report({"roll": v}, tmp_path, {}, {}, (0.0, 1.0), decision_rule=rule, measurements=ms)
    assert rep.verdict == verdict and rep.exit_code == code
    assert v.to_dict()["sigma_verdict"] == verdict
    d = rep.to_dict()
    assert d["decision_rule"]["name"] == rule and rule in d["decision_rule"]["text"]
    # the same report without measurements: the axes decide alike
    assert Report({"roll": v}, tmp_path, {}, {}, (0.0, 1.0)).verdict == verdict


def test_plan_limits_judge_gain_at_periods() -> None:
    """A plan's own limits: the gain at the periods it excites decides, the rest not judged."""
    axis = {
        "sigma": 0.2, "sigma_ci95": [0.19, 0.21], "mean_error": 0.001, "delay": 0.01,
        "analysis": {"periods": [
            {"period_s": 5.0, "excited": True, "gain": 1.03, "gain_ci95": [1.025, 1.035],
             "phase_deg": -2.0, "phase_ci95_deg": [-2.5, -1.5]},
            {"period_s": 10.0, "excited": False, "gain": None},
        ]},
    }
    ms = judge({"roll": axis}, Limits(sigma_deg=0.4, gain=(0.98, 1.02), delay_s=0.05), "guarded")
    by = {m.name: m for m in ms}
    assert by["gain at 5 s"].outcome == FAIL and by["gain at 5 s"].decisive
    assert by["gain at 10 s"].outcome == NOT_JUDGED and not by["gain at 10 s"].decisive
    assert by["gain at 3 s"].note == "not analysed"
    assert by["delay"].outcome == PASS and by["delay"].rule == "simple"  # no interval
    assert by["phase at 5 s"].outcome == NOT_JUDGED  # no phase limit
    assert overall(ms) == FAIL
    ms = judge({"roll": axis}, Limits(sigma_deg=0.4, gain=(0.98, 1.05)), "guarded")
    assert overall(ms) == PASS


def test_serial_match() -> None:
    assert serial_match("sn 0042", "SN 0042") is True
    assert serial_match("0042", "42") is True  # a numeric serial's leading zeros
    assert serial_match("SN-1", "I1") is False
    assert serial_match("SN-1", None) is None
    m = serial_measurement("SN-1", "I1")
    assert m.outcome == WARNING and not m.decisive and "I1" in (m.note or "")
    assert serial_measurement("SN-1", "sn-1").outcome == PASS
    assert serial_measurement("SN-1", None).outcome == NOT_JUDGED


def test_informative_measurements_are_never_fail() -> None:
    """The excitation fidelity beyond its alarm level is informative: a WARNING, never FAIL,
    and it does not touch the run's outcome."""
    axis = {"sigma": 0.2, "sigma_ci95": [0.19, 0.21], "mean_error": 0.0, "delay": 0.01,
            "analysis": {"periods": []},
            "excitation": {"judgement": "alarm", "rms_error_db": 2.4,
                           "worst_band": {"error_db": -3.1, "centre_hz": 0.2}}}
    ms = axis_measurements("roll", axis, Limits(sigma_deg=0.4, excitation_db=1.5))
    exc = [m for m in ms if m.name.startswith("excitation")]
    assert [m.outcome for m in exc] == [WARNING, WARNING]
    assert all(not m.decisive for m in exc)
    assert all(m.outcome != FAIL for m in ms if not m.decisive)
    assert overall(ms) == PASS
    within = {**axis, "excitation": {"judgement": "ok", "rms_error_db": 0.2,
                                     "worst_band": {"error_db": 0.4, "centre_hz": 0.2}}}
    assert [m.outcome for m in axis_measurements("roll", within, Limits(sigma_deg=0.4))
            if m.name.startswith("excitation")] == [PASS, PASS]


@pytest.mark.parametrize(
    ("error", "source", "kind"),
    [
        (SafetyAbort("interrupted by SIGTERM"), "signal", "operator"),
        (KeyboardInterrupt(), "run", "operator"),
        (StandFault("stand fault code 7", 7), "stand loop", "equipment"),
        (DeviceTimeout("no answer"), "instrument reader", "equipment"),
        (DataError("too few samples"), "analysis", "equipment"),
        (AnalysisError("Parseval check failed"), "analysis", "software"),
        (RuntimeError("driver bug"), "run (exception)", "software"),
    ],
)
def test_abort_kind(error: BaseException, source: str, kind: str) -> None:
    assert abort_kind(error, source) == kind


# ------------------------------------------------------------------------------ strict JSON
def test_strict_json_nan_to_null_and_numpy() -> None:
    obj = {"a": math.nan, "b": [np.float64(np.inf), np.float32(1.5), np.int64(3)],
           "c": np.array([1.0, np.nan]), "d": (Path("/x"), {1: -math.inf}), "e": np.bool_(True)}
    text = dumps(obj)
    assert "NaN" not in text and "Infinity" not in text
    assert loads_strict(text) == {"a": None, "b": [None, 1.5, 3], "c": [1.0, None],
                                  "d": ["/x", {"1": None}], "e": True}
    with pytest.raises(ValueError, match="NaN"):
        loads_strict('{"x": NaN}')
    assert plain({"k": float("nan")}) == {"k": None}


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=50),
       st.sampled_from(["float64", "float32", "int64", "uint8", "bool"]))
def test_an_array_is_plain_as_its_elements_are(values: list[float], dtype: str) -> None:
    """A flat numeric array made plain in one step is what its elements made plain one by
    one are (the fast path of ``plain``: Python numbers, non-finite floats None)."""
    src = np.array(values, dtype=float)
    if dtype != "float64" and dtype != "float32":
        src = np.nan_to_num(src, nan=0.0, posinf=1.0, neginf=-1.0)
        src = np.clip(src, 0, 1) if dtype in ("uint8", "bool") else np.clip(src, -1e9, 1e9)
    with np.errstate(over="ignore", invalid="ignore"):
        a = src.astype(dtype)
    by_element = [plain(v) for v in a.tolist()]
    assert plain(a) == by_element
    assert dumps(a) == dumps(by_element)
    # and a list of Python floats, the same way (a list of floats is made plain in one step)
    assert plain(values) == [v if math.isfinite(v) else None for v in values]


def test_no_bare_json_dump_in_the_package() -> None:
    """Every output goes through benchctl.jsonout (json.dumps only with allow_nan=False)."""
    offenders = []
    for p in (ROOT / "benchctl").rglob("*.py"):
        if p.name == "jsonout.py":
            continue
        for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1):
            if ("json.dump(" in line or "json.dumps(" in line) and "allow_nan=False" not in line:
                offenders.append(f"{p.relative_to(ROOT)}:{i}: {line.strip()}")
    assert not offenders, "\n".join(offenders)


def test_plots_without_global_backend_switch() -> None:
    for p in (ROOT / "benchctl").rglob("*.py"):
        text = p.read_text(encoding="utf-8")
        assert "matplotlib.use(" not in text, p
        assert "import matplotlib.pyplot" not in text, p


# ------------------------------------------------------------------------------ schema, version
def test_schema_command_prints_a_valid_json_schema(capsys: pytest.CaptureFixture[str]) -> None:
    from jsonschema import Draft202012Validator

    assert main(["schema", "record"]) == 0
    schema = json.loads(capsys.readouterr().out)
    Draft202012Validator.check_schema(schema)
    assert schema == record_schema()
    assert schema["properties"]["schema"]["const"] == "benchctl-record/1"


def test_version_from_package_metadata_not_a_constant() -> None:
    import benchctl

    assert benchctl.__version__ == metadata.version("benchctl")
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    project = text.split("[project]", 1)[1].split("\n[", 1)[0]
    assert 'dynamic = ["version"]' in project
    assert not any(line.strip().startswith("version") for line in project.splitlines())
    assert "setuptools-scm" in text.split("[build-system]", 1)[1].split("\n[", 1)[0]
    init = (ROOT / "benchctl/__init__.py").read_text(encoding="utf-8")
    assert 'version("benchctl")' in init


def test_invalid_record_names_the_key(tmp_path: Path) -> None:
    rec = build_record({"serial": "SN", "operator": "o", "station": "s"},
                       recording=tmp_path, outcome="PASS")
    validate_record(rec)
    bad = dict(rec, outcome="MAYBE")
    with pytest.raises(DataError, match="outcome"):
        validate_record(bad)
    (tmp_path / RECORD_JSON).write_text(json.dumps(rec).replace('"PASS"', "NaN"))
    with pytest.raises(DataError, match="not valid JSON"):
        load_record(tmp_path)
    assert load_record(write_record(tmp_path, rec)) == rec


# ------------------------------------------------------------------------------ runs (fakes)
DURATION, FADE = 5.0, 0.5


def _run(tmp_path: Path, stand: FakeStand, sensor: FakeSensor, cfg: BenchConfig | None = None,
         supervisor: Supervisor | None = None, **opts: Any) -> RunResult:
    """The session on the fakes' clock (the tests': simulated time, the ``vclock`` fixture)."""
    cfg = cfg or bench_config(tmp_path)
    # table mode: a streaming stand on a busy host holds and rejoins, and a window the
    # departures spoil is not judged (INCONCLUSIVE); the record is the subject here
    prep = sine_motion(stand.axes, duration_s=DURATION, mode="table", fade_s=FADE)
    sess = Session(cfg, prep, RunOptions("SN-1", "tester", **opts),
                   device_factory=lambda c, p: (stand, sensor), supervisor=supervisor,
                   clock=stand.clock)
    return sess.run()


def test_record_of_a_passing_run(tmp_path: Path, vclock: VirtualClock) -> None:
    cfg = bench_config(tmp_path, decision_rule="guarded")
    stand = FakeStand(clock=vclock)
    res = _run(tmp_path, stand, FakeSensor(stand, gain=1.05), cfg, part_number="PN-7")
    assert res.state == "done" and res.exit_code == 0, res.reason
    assert res.recording is not None and res.record == res.recording / RECORD_JSON
    rec = load_record(res.recording)
    assert rec["outcome"] == "PASS" and rec["abort"] is None and rec["exit_code"] == 0
    assert rec["decision_rule"]["name"] == "guarded"
    assert rec["unit"] == {"serial": "SN-1", "part_number": "PN-7", "reported_serial": "I1",
                           "serial_match": False}
    assert any("serial mismatch" in w for w in rec["warnings"])
    _check_data_hashes(res.recording, rec)
    # unit.serial_check: warn (the default): the mismatch is a WARNING, the run PASSes
    sm = [m for m in rec["measurements"] if m["name"] == "serial match"]
    assert len(sm) == 1 and sm[0]["outcome"] == WARNING and sm[0]["decisive"] is False
    assert all(m["outcome"] != FAIL for m in rec["measurements"])
    assert rec["stand"]["identity"]["serial"] == "S1"
    assert rec["instruments"][0]["identity"]["serial"] == "I1"
    assert rec["run_id"] == res.recording.name and rec["operator"] == "tester"
    sig = [m for m in rec["measurements"] if m["name"] == "sigma"]
    assert len(sig) == 1 and sig[0]["outcome"] == "PASS" and sig[0]["rule"] == "guarded"
    assert sig[0]["ci95"][0] <= sig[0]["value"] <= sig[0]["ci95"][1] <= 0.4
    names = {m["name"] for m in rec["measurements"]}
    assert {"precheck: static agreement", "mean error", "delay", "gain at 5 s",
            "serial match"} <= names
    rj = rec["files"]["report_json"]
    import hashlib

    assert hashlib.sha256(Path(rj["path"]).read_bytes()).hexdigest() == rj["sha256"]
    report = json.loads((res.recording / "report.json").read_text())
    assert report["decision_rule"]["name"] == "guarded"
    assert "decision rule: guarded" in (res.recording / "report.txt").read_text()


def _aborted(res: RunResult, kind: str) -> dict[str, Any]:
    assert res.state == "aborted" and res.exit_code == 2, res.reason
    assert res.abort is not None and res.abort["kind"] == kind, res.abort
    assert res.recording is not None
    rec = load_record(res.recording)
    assert rec["outcome"] == "ABORTED" and rec["abort"]["kind"] == kind
    assert rec["abort"]["reason"] == res.reason and rec["files"]["report_json"] is None
    assert res.to_dict()["abort"]["kind"] == kind
    return rec


def test_record_of_an_operator_stop(tmp_path: Path, vclock: VirtualClock) -> None:
    """The operator's SIGINT at 1 s of motion, as its handler reports it (``Supervisor.signals``:
    a fault from ``signal``), on simulated time (a real SIGINT: test_run_session.py)."""
    stand = FakeStand(clock=vclock)
    sup = Supervisor(clock=vclock)
    sent: list[float] = []

    def kill(tm: float) -> None:
        if tm >= 1.0 and not sent:
            sent.append(tm)
            sup.fault(SafetyAbort("interrupted by SIGINT"), "signal")

    stand.on_motion_time = kill
    rec = _aborted(_run(tmp_path, stand, FakeSensor(stand), supervisor=sup), "operator")
    assert "SIGINT" in rec["abort"]["reason"]
    assert all(m["outcome"] == PASS for m in rec["measurements"])  # its prechecks


def test_record_of_an_equipment_fault(tmp_path: Path, vclock: VirtualClock) -> None:
    stand = FakeStand(clock=vclock)
    stand.fault_at = 1.0
    res = _run(tmp_path, stand, FakeSensor(stand))
    rec = _aborted(res, "equipment")
    assert "fault code 7" in rec["abort"]["reason"]
    assert res.recording is not None
    _check_data_hashes(res.recording, rec)  # an aborted run's recording: hashed as closed


def test_recording_hash_changes_with_any_data_file(tmp_path: Path) -> None:
    from benchctl.results.record import data_hashes

    for name, body in (("meta.json", b"{}"), ("stand.csv", b"t\n1\n"),
                       ("events.jsonl", b"{}\n"), ("benchctl.log", b"log")):
        (tmp_path / name).write_bytes(body)
    a = data_hashes(tmp_path)
    assert [f["name"] for f in a["files"]] == ["events.jsonl", "meta.json", "stand.csv"]
    (tmp_path / "benchctl.log").write_bytes(b"more log")  # not a data file
    assert data_hashes(tmp_path)["recording_sha256"] == a["recording_sha256"]
    (tmp_path / "stand.csv").write_bytes(b"t\n2\n")
    assert data_hashes(tmp_path)["recording_sha256"] != a["recording_sha256"]
    # the CAN log under the name the config gives it (a CAN instrument only)
    (tmp_path / "frames.asc").write_bytes(b"frame")
    meta = {"config": {"instrument": {"driver": "canopen", "can_log": "frames.asc"}}}
    assert "frames.asc" in [f["name"] for f in data_hashes(tmp_path, meta)["files"]]
    meta["config"]["instrument"]["driver"] = "nmea0183"
    assert "frames.asc" not in [f["name"] for f in data_hashes(tmp_path, meta)["files"]]


def test_record_of_a_failed_precheck(tmp_path: Path, vclock: VirtualClock) -> None:
    stand = FakeStand(clock=vclock)
    rec = _aborted(_run(tmp_path, stand, FakeSensor(stand, bias=1.0)), "equipment")
    last = rec["measurements"][-1]
    assert last["name"] == "precheck: static agreement" and last["outcome"] == FAIL


def _require_serial(tmp_path: Path) -> BenchConfig:
    cfg = bench_config(tmp_path)
    return cfg.model_copy(update={"unit": UnitConfig(serial_check="require")})


def test_serial_check_require_refuses_another_unit_before_motion(
        tmp_path: Path, vclock: VirtualClock) -> None:
    """unit.serial_check: require — a unit whose reported serial is not the one typed is
    refused as a failed precheck: aborted (exit 2) before the stand is enabled or moved."""
    stand = FakeStand(clock=vclock)
    res = _run(tmp_path, stand, FakeSensor(stand), _require_serial(tmp_path))
    rec = _aborted(res, "equipment")
    assert "precheck 'serial match' failed" in res.reason
    assert "'SN-1' typed, the instrument reports 'I1'" in res.reason
    assert "enable" not in stand.calls and stand.sent == [] and stand.table is None
    last = rec["measurements"][-1]
    assert last["name"] == "precheck: serial match" and last["outcome"] == FAIL
    assert last["decisive"] is True
    assert res.recording is not None
    kinds = [e["kind"] for e in load_recording(res.recording).events]
    assert "precheck" in kinds and "motion_start" not in kinds


def test_serial_check_require_runs_the_unit_named(tmp_path: Path, vclock: VirtualClock) -> None:
    stand = FakeStand(clock=vclock)
    cfg = _require_serial(tmp_path)
    prep = sine_motion(stand.axes, duration_s=DURATION, mode="table", fade_s=FADE)
    sensor = FakeSensor(stand)
    res = Session(cfg, prep, RunOptions("i1", "tester"), device_factory=lambda c, p: (
        stand, sensor), clock=stand.clock).run()
    assert res.state == "done" and res.exit_code == 0, res.reason
    assert res.recording is not None
    rec = load_record(res.recording)
    names = [m["name"] for m in rec["measurements"]]
    assert "precheck: serial match" in names and "serial match" not in names
    assert not any("serial mismatch" in w for w in rec["warnings"])


def test_record_of_a_software_error(tmp_path: Path, vclock: VirtualClock) -> None:
    stand = FakeStand(clock=vclock)
    stand.raise_at = 1.0
    rec = _aborted(_run(tmp_path, stand, FakeSensor(stand)), "software")
    assert "RuntimeError" in rec["abort"]["reason"] and rec["abort"]["error"] == "RuntimeError"


def test_scaled_to_fit_is_a_deviation(tmp_path: Path) -> None:
    data = bench_config(tmp_path).model_dump(mode="json")
    data["stand"]["limits"] = {"angle_deg": 1.0, "rate_deg_s": 50.0, "accel_deg_s2": 300.0}
    cfg = parse_config(data, tmp_path / "bench.yaml")
    opts = RunOptions("SN-1", "tester", scale_to_fit=True, duration_s=20.0)
    prep = prepare_motion(cfg, ROOT / "profiles/ci_short.yaml", opts)
    assert prep.meta["scale"] < 1.0
    sess = Session(cfg, prep, opts)
    dev = sess._deviations()
    assert len(dev) == 1 and "scaled by" in dev[0] and "--scale-to-fit" in dev[0]
    unscaled = Session(bench_config(tmp_path), prepare_motion(
        bench_config(tmp_path), ROOT / "profiles/ci_short.yaml",
        RunOptions("SN-1", "t", duration_s=20.0)), opts)
    assert unscaled._deviations() == []


# ------------------------------------------------------------------------------ a simulated run
@pytest.mark.slow
def test_record_of_a_simulated_run_through_the_cli(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """config/sim.yaml's bench (its simulators started by the run), through the CLI in this
    process on simulated time (config/sim_virtual.yaml); the record is valid and says what
    ran."""
    cfg_src = yaml.safe_load((ROOT / "config/sim_virtual.yaml").read_text(encoding="utf-8"))
    cfg_src["stand"]["calibration_due"] = "2027-03-31"
    cfg_src["run"]["figures"] = False  # the record is checked here, not the report's figures
    for section, key in (("stand", "register_map"), ("instrument", "eds")):
        cfg_src[section][key] = str((ROOT / "config" / cfg_src[section][key]).resolve())
    cfg_path = tmp_path / "sim.yaml"
    cfg_path.write_text(yaml.safe_dump(cfg_src), encoding="utf-8")
    capsys.readouterr()
    code = main(["run", "--config", str(cfg_path),
                 "--profile", str(ROOT / "profiles/ci_short.yaml"), "--duration", "20",
                 "--serial", "DEMO-1", "--operator", "ci", "--part-number", "PN-42",
                 "--out", str(tmp_path / "runs"), "--json", "--quiet"])
    captured = capsys.readouterr()
    assert code in (0, 1, 3), captured.err[-3000:]
    proc = subprocess.CompletedProcess(["benchctl", "run"], code, captured.out, captured.err)
    out = loads_strict(proc.stdout)
    rec = load_record(out["record"])
    assert rec["outcome"] == out["verdict"] and rec["exit_code"] == proc.returncode
    assert rec["outcome"] == "PASS", [m for m in rec["measurements"] if m["outcome"] == FAIL]
    assert rec["unit"]["part_number"] == "PN-42" and rec["station"] == "sim-bench"
    assert rec["stand"]["calibration_due"] == "2027-03-31"
    assert rec["stand"]["identity"] and rec["instruments"][0]["identity"]
    assert rec["profile"]["kind"] == "roll_spectrum" and len(rec["profile"]["sha256"]) == 64
    assert len(rec["config_sha256"]) == 64 and rec["software"]["version"] == metadata.version(
        "benchctl")
    assert any(m["name"] == "sigma" and m["axis"] == "roll" for m in rec["measurements"])
    # the CAN log is a data file of the recording: hashed with the others
    folder = Path(rec["files"]["recording"])
    names = [f["name"] for f in rec["data"]["files"]]
    assert "can.blf" in names and (folder / "can.blf").stat().st_size > 0
    _check_data_hashes(folder, rec)


def _check_data_hashes(folder: Path, rec: dict[str, Any]) -> None:
    """record.json's ``data``: every data file with its size and SHA-256 as on the disk, sorted
    by name, and the recording's SHA-256 as the README defines it — recomputed here with
    sha256sum, as a QA engineer would."""
    import hashlib

    data = rec["data"]
    names = [f["name"] for f in data["files"]]
    assert names == sorted(names)
    assert {"meta.json", "stand.csv", "instrument.csv", "setpoints.csv", "events.jsonl",
            "end.json"} <= set(names)
    assert not {"benchctl.log", "sim.log", "record.json", "report.html"} & set(names)
    for f in data["files"]:
        body = (folder / f["name"]).read_bytes()
        assert f["sha256"] == hashlib.sha256(body).hexdigest() and f["bytes"] == len(body)
    listing = subprocess.run(["sha256sum", *names], cwd=folder, capture_output=True,
                             check=True).stdout
    assert data["recording_sha256"] == hashlib.sha256(listing).hexdigest()
    # the writer's own hashes (end.json's integrity, taken as it wrote) agree
    integrity = json.loads((folder / "end.json").read_text())["integrity"]["files"]
    by_name = {f["name"]: f["sha256"] for f in data["files"]}
    for name, entry in integrity.items():
        assert by_name[name] == entry["sha256"], name


# ------------------------------------------------------------------------------ CLI and config
def test_cli_passes_the_rule_and_part_number_and_names_the_abort_kind(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """`benchctl run --decision-rule guarded --part-number PN`: into RunOptions; an aborted
    run's summary names who ended it under its ABORTED line."""
    import benchctl.run as run_pkg

    seen: list[RunOptions] = []

    def fake_run_test(cfg: Any, profile: Any, opts: RunOptions, display: Any = None) -> RunResult:
        seen.append(opts)
        return RunResult("aborted", "stand loop: StandFault: fault code 7", 2, tmp_path,
                         abort={"kind": "equipment", "reason": "x"},
                         record=tmp_path / RECORD_JSON)

    monkeypatch.setattr(run_pkg, "run_test", fake_run_test)
    code = main(["run", "--config", str(ROOT / "config/sim.yaml"), "--profile",
                 str(ROOT / "profiles/ci_short.yaml"), "--serial", "SN", "--operator", "me",
                 "--decision-rule", "guarded", "--part-number", "PN-9", "--quiet"])
    out = capsys.readouterr().out
    assert code == 2
    assert seen[0].decision_rule == "guarded" and seen[0].part_number == "PN-9"
    lines = out.splitlines()
    assert lines[0] == "ABORTED: stand loop: StandFault: fault code 7"
    assert "  abort: equipment fault" in lines and f"  record {tmp_path / RECORD_JSON}" in lines
    with pytest.raises(SystemExit) as e:  # argparse: a usage error, exit 2
        main(["run", "--config", "x.yaml", "--profile", "p.yaml", "--decision-rule", "lenient"])
    assert e.value.code == 2


@pytest.mark.parametrize(
    ("where", "value", "match"),
    [
        (("run", "decision_rule"), "lenient", "run.decision_rule"),
        (("run", "limits"), {"gain_min": 1.1, "gain_max": 1.0}, "expected below gain_max"),
        (("run", "limits"), {"delay": 0.1}, "run.limits.delay"),
        (("stand", "calibration_due"), "31.12.2027", "stand.calibration_due"),
        (("unit",), {"part_number": "PN", "serial": "x"}, "unit.serial"),
        (("unit", "serial_check"), "block", "unit.serial_check"),
    ],
)
def test_config_fields_refused_with_their_path(tmp_path: Path, where: tuple[str, ...],
                                               value: Any, match: str) -> None:
    from benchctl.errors import ConfigError

    data = bench_config(tmp_path).model_dump(mode="json")
    target = data
    for k in where[:-1]:
        target = target[k]
    target[where[-1]] = value
    with pytest.raises(ConfigError, match=match):
        parse_config(data, tmp_path / "bench.yaml")


def test_record_and_report_rewritten_together_or_not_at_all(
        tmp_path: Path, vclock: VirtualClock, monkeypatch: pytest.MonkeyPatch) -> None:
    """Once the recording is closed, record.json and report.html are written again with the
    data files' SHA-256; when the record cannot be (a full disk), the earlier pair stays and
    still names each other: the report's hash in the record is the report's on the disk."""
    import errno
    import hashlib

    import benchctl.run.session as session_mod

    calls: list[Path] = []
    real = session_mod.write_record

    def failing_second(folder: Path, record: dict[str, Any]) -> Path:
        calls.append(folder)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(folder, record)

    monkeypatch.setattr(session_mod, "write_record", failing_second)
    stand = FakeStand(clock=vclock)
    res = _run(tmp_path, stand, FakeSensor(stand))
    assert res.state == "done" and res.exit_code == 0 and len(calls) == 2, res.reason
    assert res.recording is not None
    rec = load_record(res.recording)
    assert "data" not in rec  # the first record stands
    html = res.recording / "report.html"
    assert rec["files"]["report_html"]["sha256"] == hashlib.sha256(html.read_bytes()).hexdigest()
    assert "The data files' SHA-256 are not in this run's record." in html.read_text(
        encoding="utf-8")
    assert not (res.recording / "report.html.prev").exists()
