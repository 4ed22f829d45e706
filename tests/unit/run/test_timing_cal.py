"""The bench's timing calibration stored in a config (``timing:``) and applied to a recording's
analysis: the section written into a config with its comments kept, refused without its date,
the instrument's instants moved by it, stated in the record."""

from __future__ import annotations

import datetime
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from repo_paths import ROOT

from benchctl.analysis.bench_timing import DelayFit
from benchctl.config import load_config
from benchctl.errors import ConfigError
from benchctl.outcomes import Outcome
from benchctl.recording import load_recording
from benchctl.recording.format import FORMAT_NAME
from benchctl.results.record import build_record
from benchctl.run.timing_cal import TimingCalibration, timing_section, write_timing

CAL = TimingCalibration(
    offset_s=0.0015605, uncertainty_s=1.06e-5, measured_delay_s=0.0065605,
    reference_latency_s=0.005, previous_offset_s=0.0, axis="roll",
    fit=DelayFit(0.0065605, 1.06e-5, 1.0, 29, 1e-4), recording="/runs/20260101T000000Z_REF",
    date=datetime.date(2026, 11, 27))


def _config_copy(tmp_path: Path, name: str = "sim_virtual.yaml") -> Path:
    dest = tmp_path / "config"
    dest.mkdir()
    shutil.copytree(ROOT / "drivers", tmp_path / "drivers")
    p = dest / name
    shutil.copy(ROOT / "config" / name, p)
    return p


def test_section_appended_then_replaced_keeping_every_other_line(tmp_path: Path) -> None:
    p = _config_copy(tmp_path)
    text = p.read_text()
    base = text.split("\ntiming:")[0].rstrip("\n") + "\n"  # the shipped file without one
    once = write_timing(base, timing_section(CAL, "REF-1"))
    assert once.startswith(base) and once.count("\ntiming:") == 1
    p.write_text(once)
    cfg = load_config(p)
    assert cfg.timing.offset_s == pytest.approx(0.0015605)
    assert cfg.timing.calibrated == datetime.date(2026, 11, 27)
    assert cfg.timing.reference is not None and cfg.timing.reference.startswith("REF-1")
    # again, with another offset: the section replaced, not added; the rest untouched
    moved = TimingCalibration(**{**CAL.__dict__, "offset_s": 0.002})
    twice = write_timing(once, timing_section(moved))
    assert twice.count("\ntiming:") == 1 and twice.startswith(base)
    p.write_text(twice)
    assert load_config(p).timing.offset_s == pytest.approx(0.002)


def test_section_in_the_middle_replaced_before_the_next_key() -> None:
    text = ("station: a\ntiming:\n  offset_s: 0.1\n  calibrated: 2026-01-01\n# run's comment\n"
            "run:\n  x: 1\n")
    out = write_timing(text, "timing:\n  offset_s: 0.2\n")
    assert out == "station: a\ntiming:\n  offset_s: 0.2\n# run's comment\nrun:\n  x: 1\n"


def test_an_offset_needs_its_date(tmp_path: Path) -> None:
    p = _config_copy(tmp_path)
    data = yaml.safe_load(p.read_text())
    data["timing"] = {"offset_s": 0.001}
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="timing"):
        load_config(p)
    data["timing"] = {"offset_s": 0.7, "calibrated": "2026-11-27"}
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="offset_s"):
        load_config(p)


def _recording(tmp_path: Path, offset: float | None) -> Path:
    """A small recording folder: a stand stream at 100 Hz and an instrument stream of receipts
    (no adapter or device clock), the config's timing section as given."""
    rec = tmp_path / f"rec{offset}"
    rec.mkdir()
    t = 1000.0 + np.arange(0, 30, 0.01)
    x = 2 * np.sin(2 * np.pi * 0.2 * t)
    cfg: dict[str, object] = {"stand": {"driver": "modbus-tcp"}, "instrument": {"driver": "j1939"}}
    if offset is not None:
        cfg["timing"] = {"offset_s": offset, "uncertainty_s": 1e-5, "calibrated": "2026-11-27",
                         "reference": "REF"}
    meta = {"format": FORMAT_NAME, "version": 1, "axes": ["roll"], "config": cfg}
    (rec / "meta.json").write_text(json.dumps(meta))
    rows = "\n".join(f"{a:.9f},0.001,{b:.9f},0,0,1,0" for a, b in zip(t, x, strict=True))
    (rec / "stand.csv").write_text("t_host,rtt_s,roll_deg,roll_rate_deg_s,roll_setpoint_deg,"
                                   "status,fault_code\n" + rows + "\n")
    td = t + 0.002
    rows = "\n".join(f"{a:.9f},,,,{b:.9f}" for a, b in zip(td, x, strict=True))
    (rec / "instrument.csv").write_text("t_host,device_time_s,counter,adapter_time_s,roll_deg\n"
                                        + rows + "\n")
    return rec


def test_the_offset_moves_the_instrument_instants_and_is_labelled(tmp_path: Path) -> None:
    plain = load_recording(_recording(tmp_path, None))
    cal = load_recording(_recording(tmp_path, 0.0015))
    assert plain.timing_offset_s == 0.0 and cal.timing_offset_s == 0.0015
    _, _, td0, _ = plain.pair("roll")
    _, _, td1, _ = cal.pair("roll")
    assert np.allclose(np.asarray(td0) - np.asarray(td1), 0.0015, atol=1e-12)
    assert td1.info["timing_offset_s"] == 0.0015 and "timing_offset_s" not in td0.info
    assert td1.timebase == td0.timebase


def test_the_record_states_the_timing_it_was_analysed_with(tmp_path: Path) -> None:
    rec = load_recording(_recording(tmp_path, 0.0015))
    r = build_record(rec.meta, recording=rec.path, outcome=Outcome.PASS)
    assert r["timing"] == {"offset_s": 0.0015, "uncertainty_s": 1e-5,
                           "calibrated": "2026-11-27", "reference": "REF"}
    old = load_recording(_recording(tmp_path, None))
    assert build_record(old.meta, recording=old.path, outcome=Outcome.PASS)["timing"] is None


def test_the_report_states_the_offset_it_applied(tmp_path: Path) -> None:
    from benchctl.run.report import Report, format_report

    timing = {"offset_s": 0.0015605, "uncertainty_s": 1.06e-5, "calibrated": "2026-11-27",
              "reference": "REF"}
    rep = Report({}, tmp_path, {"serial": "S", "timing": timing}, {}, (0.0, 60.0))
    assert rep.to_dict()["timing"] == timing
    assert ("bench timing offset +1.5605 ms (± 0.0106 ms, calibrated 2026-11-27) subtracted "
            "from the instrument's instants") in format_report(rep)
    none = Report({}, tmp_path, {"serial": "S", "timing": {**timing, "offset_s": 0.0}}, {},
                  (0.0, 60.0))
    assert "bench timing offset" not in format_report(none)


def test_the_calibrations_uncertainty_reaches_the_analysis(tmp_path: Path) -> None:
    """The stated uncertainty travels with the offset into the analysis's offset budget."""
    cal = load_recording(_recording(tmp_path, 0.0015))
    assert cal.timing_offset_u_s == 1e-5
    _, _, td, _ = cal.pair("roll")
    assert td.info["timing_offset_u_s"] == 1e-5
    assert load_recording(_recording(tmp_path, None)).timing_offset_u_s == 0.0
