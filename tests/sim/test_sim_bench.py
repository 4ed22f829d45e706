"""`benchctl sim` and the simulated bench: both simulators from one config, the real drivers
talking to them, the fault schedule, and the child process used by `benchctl run`."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from repo_paths import ROOT

from benchctl.clock.virtual import VirtualClock
from benchctl.config import load_config, parse_config
from benchctl.devices.base import InstrumentSample
from benchctl.devices.instrument import open_instrument
from benchctl.devices.modbus.stand import open_stand
from benchctl.errors import StandFault
from benchctl.sim.bench import SimBench
from benchctl.sim.launch import start_simulators


def _config(tmp_path: Path, name: str = "sim.yaml", **sim_extra: object) -> Path:
    """A copy of a shipped config with its device paths moved into tmp_path and port 0."""
    data = yaml.safe_load((ROOT / "config" / name).read_text())
    data["stand"]["port"] = 0
    if data["stand"].get("serial_port"):
        data["stand"]["serial_port"] = str(tmp_path / "stand-rtu")
    key = "serial_port" if data["instrument"]["driver"] == "nmea0183" else "channel"
    data["instrument"][key] = str(tmp_path / "instrument")
    for k in ("register_map", "eds", "dbc"):
        for section in ("stand", "instrument"):
            if k in data[section]:
                data[section][k] = str((ROOT / "config" / data[section][k]).resolve())
    data["run"]["output_dir"] = str(tmp_path / "runs")
    data["sim"].update(sim_extra)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def _collect(sensor: object, seconds: float) -> list[InstrumentSample]:
    got: list[InstrumentSample] = []
    errors: list[BaseException] = []
    sensor.start(got.append, errors.append)  # type: ignore[attr-defined]
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and not errors:
        time.sleep(0.05)
    sensor.stop()  # type: ignore[attr-defined]
    assert not errors, errors
    return got


@pytest.mark.realtime  # ptys linked at the config's paths, a TCP port: the host's transports
# each way a device is placed, once: the stand's RTU pty and the CAN adapter's (sim_rtu.yaml),
# the stand's TCP port and the NMEA 0183 line's pty (sim_nmea0183.yaml); config/sim.yaml's
# (TCP and the CAN adapter) are the same two ways again
@pytest.mark.parametrize("name", ["sim_rtu.yaml", "sim_nmea0183.yaml"])
def test_sim_bench_where_the_config_says(tmp_path: Path, name: str) -> None:
    """Standalone placement: the ptys are linked at the config's own paths, so the config
    (a 'hardware' config pointed at the simulators) works unchanged."""
    cfg = load_config(_config(tmp_path, name))
    with SimBench(cfg) as bench:
        # generous reply timeout: the simulators share a loaded machine with this test
        cfg = cfg.model_copy(update={"stand": cfg.stand.model_copy(update={"timeout_s": 2.0})})
        assert (tmp_path / "instrument").is_symlink()
        if cfg.stand.driver == "modbus-rtu":
            assert (tmp_path / "stand-rtu").is_symlink()
        else:
            cfg = cfg.model_copy(
                update={"stand": cfg.stand.model_copy(update={"port": bench.stand.port})}
            )
        stand = open_stand(cfg.stand)
        sensor = open_instrument(cfg.instrument)
        try:
            ident = stand.connect()
            assert ident.model
            sensor.connect()
            samples = _collect(sensor, 1.0)
        finally:
            sensor.close()
            stand.close()
    rate = cfg.sim.instrument.rate_hz if cfg.sim else 0.0
    assert len(samples) >= 0.5 * rate  # about one second of samples at the model's rate
    # at rest: the instrument reads its bias (0.05°) plus noise (0.05° σ), far from anything else
    roll = [s.angle_deg["roll"] for s in samples]
    assert abs(sum(roll) / len(roll) - 0.05) < 0.05


def test_fault_schedule_counts_from_first_motion(tmp_path: Path, vclock: VirtualClock) -> None:
    """On simulated time: the simulators in this process over in-process links, the real
    stand driver talking to them on the same clock."""
    path = _config(
        tmp_path,
        clock="virtual",
        faults=[
            {
                "target": "stand",
                "kind": "stand_fault",
                "after_motion_s": 0.3,
                "params": {"code": 42},
            }
        ],
    )
    cfg = load_config(path)
    with SimBench(cfg, private=True, clock=vclock) as bench:
        stand = open_stand(bench.config().stand, clock=vclock)
        try:
            stand.connect()
            stand.enable()
            vclock.sleep(0.5)  # nothing moves yet: no fault may come from the schedule
            assert bench.motion_started_at is None and bench.injected == []
            # move: 0.5° over 0.5 s through the stand's queue (within the limits from rest)
            stand.begin_trajectory()
            k = np.arange(52)
            pts = 0.25 * (1 - np.cos(np.pi * np.minimum(k, 50) / 50))
            stand.push_points(0, {"roll": pts[:24]}, read=False)
            stand.push_points(24, {"roll": pts[24:48]}, read=False)
            stand.push_points(48, {"roll": pts[48:]}, read=False)
            stand.start_trajectory()
            deadline = vclock.monotonic() + 5.0
            with pytest.raises(StandFault) as info:
                while vclock.monotonic() < deadline:
                    stand.heartbeat()
                    stand.read_sample()
                    vclock.sleep(0.02)
            assert info.value.code == 42
            assert bench.motion_started_at is not None
            t_fault = bench.injected[0][0]
            # not before 0.3 s of motion (compared as the schedule adds it: on simulated time
            # the fault falls exactly there, and a difference of the two rounds below 0.3)
            assert t_fault >= bench.motion_started_at + 0.3
        finally:
            stand.close()


@pytest.mark.realtime  # a child process, its pty and TCP port
def test_child_process_ready_line_and_exit_on_stdin_close(tmp_path: Path) -> None:
    """What `benchctl run` uses: `benchctl sim --private --ready-json` as a child process."""
    cfg = load_config(_config(tmp_path))
    sim = start_simulators(cfg)
    with sim:
        assert sim.proc is not None
        run_cfg = sim.config
        assert run_cfg.stand.port != 0
        assert run_cfg.instrument.channel != str(tmp_path / "instrument")  # a private pty
        stand = open_stand(run_cfg.stand)
        try:
            assert stand.connect().model
            assert stand.read_status().ready
        finally:
            stand.close()
        proc = sim.proc
    assert proc.returncode == 0  # it exited by itself when its stdin closed


def test_sim_needs_a_sim_section(tmp_path: Path) -> None:
    data = yaml.safe_load((ROOT / "config/hardware_example.yaml").read_text())
    cfg = parse_config(data, tmp_path / "hw.yaml")
    from benchctl.errors import ConfigError

    with pytest.raises(ConfigError, match="sim"):
        SimBench(cfg)
