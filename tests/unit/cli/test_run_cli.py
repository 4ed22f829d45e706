"""`benchctl run` refuses bad input before anything opens or moves; `benchctl recording`."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import yaml
from repo_paths import ROOT

from benchctl.cli import main
from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
from benchctl.recording import RecordingWriter, load_recording


def _cfg(tmp_path: Path, **patch: Any) -> dict[str, Any]:
    data: dict[str, Any] = {
        "station": "cli-test",
        "stand": {
            "driver": "modbus-tcp",
            "host": "127.0.0.1",
            "port": 1,  # nothing listens: a run that tried to open it would fail differently
            "limits": {"angle_deg": 20.0, "rate_deg_s": 30.0, "accel_deg_s2": 100.0},
        },
        "instrument": {"driver": "nmea0183", "serial_port": "/nonexistent/tty"},
        "run": {"limit_sigma_deg": 0.4, "output_dir": str(tmp_path / "runs")},
    }
    for dotted, value in patch.items():
        node = data
        *path, last = dotted.split(".")
        for k in path:
            node = node[k]
        if value is None:
            node.pop(last)
        else:
            node[last] = value
    return data


def _write(tmp_path: Path, data: dict[str, Any]) -> Path:
    p = tmp_path / "bench.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _run(tmp_path: Path, cfg: Path, *extra: str, profile: str = "profiles/ci_short.yaml") -> int:
    root = ROOT
    return main(
        [
            "run",
            "--config",
            str(cfg),
            "--profile",
            str(root / profile),
            "--serial",
            "S",
            "--operator",
            "O",
            *extra,
        ]
    )


@pytest.mark.parametrize(
    ("patch", "expect"),
    [
        (
            {"stand.driver": "profibus"},
            ["field stand.driver = 'profibus'", "'modbus-tcp' or 'modbus-rtu'"],
        ),
        ({"stand.driver": "modbus-rtu"}, ["field stand", "needs serial_port"]),
        ({"instrument.serial_port": None}, ["field instrument", "nmea0183 needs serial_port"]),
        ({"stand.limits": None}, ["field stand.limits", "Field required"]),
        ({"stand.limits.rate_deg_s": -5}, ["field stand.limits.rate_deg_s = -5", "greater than 0"]),
        ({"stand.limits.angle_deg": 1.0}, ["needed", "allowed 1.0"]),
    ],
)
def test_bad_config_refused_before_anything_moves(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], patch: dict[str, Any], expect: list[str]
) -> None:
    cfg = _write(tmp_path, _cfg(tmp_path, **patch))
    assert _run(tmp_path, cfg) == 2
    err = capsys.readouterr().err
    assert "bench.yaml" in err or "ci_short" in err, err
    for part in expect:
        assert part in err, err
    assert not (tmp_path / "runs").exists()  # no recording: nothing was opened


def test_profile_axes_not_on_the_bench(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = _write(tmp_path, _cfg(tmp_path, **{"stand.axes": ["roll"]}))
    assert _run(tmp_path, cfg, "--duration", "60", profile="profiles/two_axis_roll_pitch.yaml") == 2
    err = capsys.readouterr().err
    assert "field stand.axes = ['roll']" in err and "['pitch']" in err


def test_serial_and_operator_required_without_a_terminal(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = _write(tmp_path, _cfg(tmp_path))
    monkeypatch.setattr("sys.stdin.isatty", lambda: False, raising=False)
    root = ROOT
    code = main(["run", "--config", str(cfg), "--profile", str(root / "profiles/ci_short.yaml")])
    assert code == 2
    assert "--serial is required" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()


def _recording(path: Path) -> Path:
    w = RecordingWriter(
        path, ("roll",), {"serial": "SN9", "operator": "op", "profile_name": "p", "seed": 3}
    )
    st = StandStatus(True, True, False, False, False, False)
    for k in range(50):
        t = 100.0 + 0.01 * k
        w.write_stand(
            StandSample(t, 0.001, {"roll": 0.1 * k}, {"roll": 10.0}, {"roll": 0.1 * k}, st)
        )
        w.write_instrument(InstrumentSample(t + 0.002, {"roll": 0.1 * k + 0.01}, counter=k))
        w.write_setpoint(t - 0.001, {"roll": 0.1 * k}, t_slot=t - 0.0015)
    w.event("state", **{"from": "idle", "to": "prechecks"})
    w.close("aborted", "interrupted by SIGTERM")
    return path


def test_recording_show_and_export(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = _recording(tmp_path / "rec")
    assert main(["recording", "show", str(rec), "--json"]) == 0
    s = json.loads(capsys.readouterr().out)
    assert s["state"] == "aborted" and s["reason"] == "interrupted by SIGTERM"
    assert s["streams"]["stand"]["rows"] == 50 and s["states"] == ["prechecks"]
    assert s["streams"]["stand"]["span_s"] == pytest.approx(0.49)
    assert main(["recording", "show", str(rec)]) == 0
    assert "aborted (interrupted by SIGTERM)" in capsys.readouterr().out
    assert main(["recording", "export", str(rec), "--csv", str(tmp_path / "csv")]) == 0
    back = (tmp_path / "csv" / "instrument.csv").read_text().splitlines()
    assert back[0] == "t_host,device_time_s,counter,adapter_time_s,roll_deg" and len(back) == 51
    assert float(back[3].split(",")[4]) == pytest.approx(0.21)
    assert main(["recording", "export", str(rec), "--mat", str(tmp_path / "r.mat")]) == 0
    from scipy.io import loadmat

    m = loadmat(tmp_path / "r.mat")
    assert m["stand"]["roll_deg"][0, 0].ravel()[10] == pytest.approx(1.0)
    assert json.loads(str(m["meta_json"][0]))["serial"] == "SN9"
    assert load_recording(rec).state == "aborted"


def test_recording_show_refuses_a_non_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["recording", "show", str(tmp_path)]) == 2
    assert "meta.json" in capsys.readouterr().err
