"""The simulated bench on simulated time: the whole run in one process on a VirtualClock.

Two runs with the same inputs write the same bytes (the recorded data, and the event log once
the two fields that cannot be fixed — the recording's path and the software version — are set
aside); a seeded disturbance replays exactly; the stamps are simulated time from the config's
epoch, never the host's."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from repo_paths import ROOT

from benchctl.cli import main
from benchctl.recording.digest import file_digest

DATA = ("stand.csv", "instrument.csv", "setpoints.csv")


def _config(tmp_path: Path, disturb: dict[str, Any] | None = None) -> Path:
    data = yaml.safe_load((ROOT / "config/sim_virtual.yaml").read_text())
    data["stand"]["register_map"] = str(ROOT / "drivers/stand_generic.yaml")
    data["instrument"]["eds"] = str(ROOT / "drivers/cia410_inclinometer.eds")
    data["run"]["output_dir"] = str(tmp_path / "runs")
    # no report figures (matplotlib, seconds of each run, drawn after the verdict): the runs
    # here are compared by their recorded data and event log, which the figures are not in
    data["run"]["figures"] = False
    if disturb is not None:
        data["sim"]["disturb"] = disturb
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / "bench.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _run(cfg: Path, out: Path, *extra: str) -> tuple[int, Path]:
    code = main([
        "run", "--config", str(cfg), "--profile", str(ROOT / "profiles/ci_short.yaml"),
        "--serial", "20260001", "--operator", "ci", "--out", str(out), "--duration", "20",
        *extra,
    ])
    (rec,) = [p.parent for p in out.glob("*/meta.json")]
    return code, rec


def _digest(rec: Path, name: str) -> str | None:
    return file_digest(rec / name)  # the two fields that cannot be fixed left out


@pytest.fixture(scope="module")
def undisturbed(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int, Path]:
    """The undisturbed run of ``_config`` (its config file, exit code, recording), made once for
    the module: the first of the two same-input runs below, and the disturbed runs' twin."""
    tmp = tmp_path_factory.mktemp("undisturbed")
    cfg = _config(tmp)
    code, rec = _run(cfg, tmp / "a")
    return cfg, code, rec


@pytest.mark.slow
def test_two_runs_with_the_same_inputs_record_the_same_bytes(
        tmp_path: Path, undisturbed: tuple[Path, int, Path]) -> None:
    cfg, code1, rec1 = undisturbed  # the first run; the second one here, the same config file
    code2, rec2 = _run(cfg, tmp_path / "b")
    assert code1 == code2 == 0
    for name in (*DATA, "events.jsonl"):
        assert _digest(rec1, name) == _digest(rec2, name), name
    meta = json.loads((rec1 / "meta.json").read_text())
    # simulated time from the config's epoch: no stamp of the host's
    assert meta["start_utc"].startswith("2026-01-01T00:00:0")
    assert rec1.name.startswith("20260101T0000")
    ev = [json.loads(x) for x in (rec1 / "events.jsonl").read_text().splitlines()]
    assert all(e["utc"].startswith("2026-01-01T00:0") for e in ev)
    disk = next(e for e in ev if e.get("name") == "disk space")
    assert "free_mb" not in disk["values"]  # the host's free space stays out of the data


DISTURB = {
    "host_stalls_per_min": 30, "host_stall_s": [0.05, 0.6], "send_jitter_s": 0.002,
    "slow_reply_p": 0.02, "slow_reply_s": [0.005, 0.3], "lost_reply_p": 0.002,
    "lost_frame_p": 0.002, "garbled_frame_p": 0.002,
}


@pytest.mark.slow
def test_a_seed_replays_exactly_and_another_seed_differs(tmp_path: Path) -> None:
    recs = {}
    for name, seed in (("a", 11), ("b", 11), ("c", 12)):
        cfg = _config(tmp_path / name, {"seed": seed, **DISTURB})
        _code, recs[name] = _run(cfg, tmp_path / name / "out")
    for name in (*DATA, "events.jsonl"):
        assert _digest(recs["a"], name) == _digest(recs["b"], name), name
    assert _digest(recs["a"], "stand.csv") != _digest(recs["c"], "stand.csv")
    ev = [json.loads(x) for x in (recs["a"] / "events.jsonl").read_text().splitlines()]
    (d,) = [e for e in ev if e["kind"] == "disturbances"]
    assert d["seed"] == 11 and d["host_stalls"]  # recorded, to be replayed
    meta = json.loads((recs["a"] / "meta.json").read_text())
    assert meta["disturbances"]["seed"] == 11


def test_a_virtual_config_refuses_a_callers_real_time_supervisor(tmp_path: Path) -> None:
    from benchctl.config import load_config
    from benchctl.errors import ConfigError
    from benchctl.run.prepare import RunOptions
    from benchctl.run.session import run_test
    from benchctl.run.supervisor import Supervisor

    cfg = load_config(_config(tmp_path))
    with pytest.raises(ConfigError, match=r"sim\.clock = virtual"):
        run_test(cfg, ROOT / "profiles/ci_short.yaml",
                 RunOptions(serial="x", operator="y"), supervisor=Supervisor())


def test_the_simulated_time_config_is_the_default_one_on_a_virtual_clock() -> None:
    """config/sim_virtual.yaml is config/sim.yaml with sim.clock: virtual (and its epoch): the
    second README command runs the first one's bench — each with the timing calibration of the
    clock it runs on (the host's adds its own latency through the pseudo-terminals)."""
    real = yaml.safe_load((ROOT / "config/sim.yaml").read_text())
    virtual = yaml.safe_load((ROOT / "config/sim_virtual.yaml").read_text())
    assert virtual["sim"].pop("clock") == "virtual"
    virtual["sim"].pop("epoch_utc")
    t_real, t_virtual = real.pop("timing"), virtual.pop("timing")
    assert virtual == real
    assert "host's clock" in t_real["reference"] and "host's clock" not in t_virtual["reference"]
    assert 0 < t_real["offset_s"] - t_virtual["offset_s"] < 0.0005


def _events(rec: Path) -> list[dict[str, Any]]:
    return [json.loads(x) for x in (rec / "events.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_disturbed_from_the_motions_start_the_motion_starts_in_step(
        tmp_path: Path, undisturbed: tuple[Path, int, Path]) -> None:
    """``sim.disturb.from_s`` at the undisturbed twin's fade-in: before it nothing is disturbed,
    so the motion starts at the same simulated instant and the instrument's samples (its
    instants and values, noise included) are the twin's; disturbed from the start, the motion
    starts later and the noise falls on other instants of it."""
    _cfg, code, twin = undisturbed  # the undisturbed twin (the module's run)
    assert code == 0
    fade = next(e["t_state"] for e in _events(twin) if e.get("to") == "fade-in")
    recs = {}
    for name, extra in (("late", {"from_s": round(fade - 1000.0 + 0.001, 6)}), ("early", {})):
        cfg = _config(tmp_path / name, {"seed": 5, **DISTURB, "lost_frame_p": 0.0,
                                        "garbled_frame_p": 0.0, "lost_reply_p": 0.0, **extra})
        _code, recs[name] = _run(cfg, tmp_path / name / "out")
    ev = _events(recs["late"])
    assert next(e["t_state"] for e in ev if e.get("to") == "fade-in") == fade
    (d,) = [e for e in ev if e["kind"] == "disturbances"]
    assert d["host_stalls"] and min(t for t, _d in d["host_stalls"]) >= fade - 1000.0
    # the instrument's samples — its instants (the adapter's stamps) and values — are the
    # twin's (the disturbed run goes on a little longer: its stalls delayed the end)
    def samples(rec: Path) -> list[list[str]]:
        rows = (rec / "instrument.csv").read_text().splitlines()
        return [r.split(",")[1:] for r in rows]

    twin_rows, late_rows = samples(twin), samples(recs["late"])
    assert len(twin_rows) > 1500 and late_rows[:len(twin_rows)] == twin_rows
    assert _digest(recs["late"], "stand.csv") != _digest(twin, "stand.csv")  # disturbed
    early = next(e["t_state"] for e in _events(recs["early"]) if e.get("to") == "fade-in")
    assert early > fade
