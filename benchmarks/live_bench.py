"""A live simulated bench, for the run layer's end-to-end tests and the benchmarks that measure
the same bench (benchmarks/rtu_vs_tcp.py): the real simulators (a Modbus server on
TCP or RTU over a pty, an instrument on a pty speaking CANopen over slcan or NMEA 0183), and a
bench config file pointing the real drivers at them. The test process hosts the simulators, so
a test can read the true stand state and inject faults while ``benchctl run`` (in-process or as
a child process) drives them over the real protocols."""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from benchctl.channels import free_name, register, unregister
from benchctl.clock import REAL, Clock
from benchctl.config import (
    BenchConfig,
    InstrumentConfig,
    SimInstrumentConfig,
    SimStandConfig,
    StandLimits,
    load_config,
)
from benchctl.sim.instrument import SimInstrument
from benchctl.sim.instrument_model import InstrumentModel
from benchctl.sim.stand import SimStand

#: the repository: its drivers/ (the register map, the EDS)
ROOT = Path(__file__).resolve().parents[1]
LIMITS = {"angle_deg": 25.0, "rate_deg_s": 40.0, "accel_deg_s2": 200.0}
#: run settings for a real-time test about something else than the prechecks (a signal, a kill,
#: a stall): the mounting check's tilt (about 9 s) and the host check (2 s) left out — each has
#: its own tests, and the README's command runs both
FOCUSED = {"mounting_check": {"enabled": False}, "host_check": {"enabled": False}}

# short profiles for the run layer's end-to-end tests
TWO_AXIS = """
name: e2e_two_axis
description: short two-axis roll and pitch for the run layer's end-to-end tests
reference: exp-cos roll model (as ci_short), two axes, shortened
kind: roll_spectrum
duration_s: 20
fade_in_s: 2
fade_out_s: 2
seed: 5
band_hz: [0.1, 0.5]
axes:
  roll: {model: exp_cos, sigma_deg: 2.0, period_s: 6.0, damping: 0.2}
  pitch: {model: exp_cos, sigma_deg: 1.0, period_s: 4.0, damping: 0.3}
"""
ROLL = TWO_AXIS.replace("e2e_two_axis", "e2e_roll").split("  pitch:")[0]


@dataclass
class LiveBench:
    config_path: Path
    cfg: BenchConfig
    stand: SimStand
    instrument: SimInstrument

    def stand_at_rest(self, tol_deg: float = 0.05) -> bool:
        a0 = self.stand.true_angles(self.stand.clock.monotonic())
        return all(abs(v) <= tol_deg for v in a0.values())


def instrument_section(driver: str) -> dict[str, Any]:
    if driver == "canopen":
        return {
            "driver": "canopen",
            "eds": str(ROOT / "drivers/cia410_inclinometer.eds"),
            "interface": "slcan",
            "channel": "x",
        }
    if driver in ("j1939", "nmea2000"):  # as config/sim_j1939.yaml, config/sim_nmea2000.yaml
        dbc = "j1939_slope.dbc" if driver == "j1939" else "nmea2000_attitude.dbc"
        return {"driver": driver, "dbc": str(ROOT / "drivers" / dbc), "interface": "slcan",
                "channel": "x", "bitrate": 250000}
    if driver == "nmea0183":
        return {"driver": "nmea0183", "serial_port": "x", "sentence": "PASHR"}
    raise ValueError(driver)


@contextmanager
def live_bench(
    tmp_path: Path,
    *,
    transport: str = "tcp",
    instrument: str = "canopen",
    model: SimInstrumentConfig | None = None,
    run: dict[str, Any] | None = None,
    stand: dict[str, Any] | None = None,
    sim_stand: dict[str, Any] | None = None,
    clock: Clock = REAL,
    instrument_extra: dict[str, Any] | None = None,
) -> Iterator[LiveBench]:
    """The simulators in this process and a bench config pointed at them. On a virtual
    ``clock`` (the test inside ``clock.running()``, e.g. the ``vclock`` fixture) they run on
    simulated time over in-process links, and the run must be given the same clock.
    ``instrument_extra``: further fields of the config's ``instrument`` section (its
    ``axes`` mapping…)."""
    model = model or SimInstrumentConfig(lag_s=0.05, noise_deg=0.01, rate_hz=100.0)
    limits = StandLimits(**LIMITS)
    framing: Any = "rtu" if transport == "rtu" else "tcp"
    sim_stand = SimStand(
        SimStandConfig(**{"watchdog_s": 3.0, **(sim_stand or {})}),
        limits=limits,
        register_map=ROOT / "drivers/stand_generic.yaml",
        transport="channel" if clock.virtual else framing,
        framing=framing,
        port=0,
        clock=clock,
    )
    sim_stand.start()
    stand_url = None
    if sim_stand.client_endpoint is not None:
        stand_url = register(free_name("sim-stand"), sim_stand.client_endpoint)
    try:
        icfg = InstrumentConfig(**instrument_section(instrument))
        sim_instr = SimInstrument(
            model, icfg, sim_stand, clock=clock,
            channel=free_name("sim-instrument") if clock.virtual else None,
        )
        sim_instr.start()
        try:
            stand_sec: dict[str, Any] = {
                "driver": f"modbus-{transport}",
                "register_map": str(ROOT / "drivers/stand_generic.yaml"),
                "timeout_s": 2.0,  # generous: the simulators share a loaded machine
                "limits": LIMITS,
                **(stand or {}),
            }
            if stand_url is not None:
                stand_sec["serial_port" if transport == "rtu" else "host"] = stand_url
            elif transport == "rtu":
                stand_sec["serial_port"] = sim_stand.serial_port
            else:
                stand_sec["host"], stand_sec["port"] = "127.0.0.1", sim_stand.port
            inst = instrument_section(instrument)
            live = sim_instr.instrument_config()
            if instrument == "nmea0183":
                inst["serial_port"] = live.serial_port
            else:
                inst["channel"] = live.channel
            # generous: the simulators share a loaded machine with the test and the run
            inst["silence_timeout_s"] = 3.0
            inst.update(instrument_extra or {})
            data = {
                "station": "e2e",
                "stand": stand_sec,
                "instrument": inst,
                "run": {
                    "limit_sigma_deg": 0.4,
                    "output_dir": str(tmp_path / "runs"),
                    "precheck_window_s": 0.5,
                    # no figures (about 1-3 s per axis of every run): the report's own tests
                    # and the end-to-end ones (run={"figures": True}) draw them
                    "figures": False,
                    **(run or {}),
                },
            }
            path = tmp_path / "bench.yaml"
            path.write_text(yaml.safe_dump(data))
            yield LiveBench(path, load_config(path), sim_stand, sim_instr)
        finally:
            sim_instr.stop()
            if sim_instr.channel_name is not None:
                unregister(sim_instr.channel_name)
    finally:
        sim_stand.stop()
        if stand_url is not None:
            unregister(stand_url)


def expected_sigma(bench: LiveBench, motion: Any, axis: str) -> float:
    """σ the simulated instrument must show for this motion: its stated transfer function applied
    to the stand's true motion (profile lines × the servo's response), plus its noise and the
    wire quantisation. Over whole periods of the lines this is exact (steady state).

    On an in-process link (simulated time) the host has each output its bytes' time after its
    instant, as over a real serial line (a pty has no byte time): that delay is the
    instrument's too, added to its latency (``SimInstrument.wire_delay_s``)."""
    tab = motion.tables[axis]
    hs = np.array([abs(bench.stand.servo_response(f)) for f in tab.freq_hz])
    model = bench.instrument.model
    if bench.instrument.wire_delay_s > 0:
        cfg = model.cfg.model_copy(
            update={"latency_s": model.cfg.latency_s + bench.instrument.wire_delay_s})
        model = InstrumentModel(cfg)
    var = model.expected_error_variance(
        tab.amp_deg * hs, tab.freq_hz, resolution_deg=bench.instrument.wire_resolution_deg
    )
    return math.sqrt(var)


def recording_in(runs: Path) -> Path | None:
    """The recording a child run made in ``runs`` (None until its meta.json exists)."""
    found = [p.parent for p in runs.glob("*/meta.json")]
    return found[0] if found else None


def motion_for(runs: Path, seconds: float, clock: Clock = REAL) -> Callable[[], bool]:
    """True once the recording a run (a child's, or on ``clock`` one in this process) made in
    ``runs`` shows ``seconds`` of motion on ``clock`` (from its own events)."""

    def cond() -> bool:
        rec = recording_in(runs)
        if rec is None or not (rec / "events.jsonl").is_file():
            return False
        for line in (rec / "events.jsonl").read_text().splitlines():
            if '"motion_start"' in line:
                return bool(clock.monotonic() - json.loads(line)["t_host"] >= seconds)
        return False

    return cond
