"""``benchctl profile show|synth|plot``: reproducible CSVs, JSON, exit codes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from repo_paths import ROOT

from benchctl.cli import main

CI = str(ROOT / "profiles" / "ci_short.yaml")


def config(tmp_path: Path, angle: float = 30, rate: float = 30, accel: float = 60) -> str:
    cfg = {
        "stand": {
            "driver": "modbus-tcp",
            "setpoint_rate_hz": 50,
            "limits": {"angle_deg": angle, "rate_deg_s": rate, "accel_deg_s2": accel},
        },
        "instrument": {"driver": "nmea0183", "serial_port": "/dev/null"},
        "run": {"limit_sigma_deg": 0.5},
    }
    p = tmp_path / "bench.yaml"
    p.write_text(yaml.safe_dump(cfg), encoding="utf-8")
    return str(p)


def test_synth_is_byte_identical_for_one_seed_and_differs_for_another(tmp_path: Path) -> None:
    outs = []
    for name, seed in (("a", "1"), ("b", "1"), ("c", "2")):
        out = tmp_path / f"{name}.csv"
        assert (
            main(["profile", "synth", CI, "--out", str(out), "--rate", "100", "--seed", seed]) == 0
        )
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]
    assert outs[0] != outs[2]
    header = outs[0].split(b"\n", 1)[0]
    assert header == b"time_s,roll_deg"
    a = np.loadtxt(tmp_path / "a.csv", delimiter=",", skiprows=1)
    c = np.loadtxt(tmp_path / "c.csv", delimiter=",", skiprows=1)
    assert a.shape == (2501, 2) and a[-1, 0] == pytest.approx(25.0)
    # same spectrum: the steady part (3 s … 22 s = one period) has the same line variances
    sel = (a[:, 0] >= 3.0) & (a[:, 0] < 22.0)
    pa = np.abs(np.fft.rfft(a[sel, 1])) ** 2
    pc = np.abs(np.fft.rfft(c[sel, 1])) ** 2
    lines = np.arange(2, 10)  # k/19 s in 0.08 … 0.5 Hz
    np.testing.assert_allclose(pa[lines], pc[lines], rtol=1e-3)


def test_synth_writes_a_harmonic_table_and_json(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out, table = tmp_path / "m.csv", tmp_path / "t.csv"
    code = main(
        ["profile", "synth", CI, "--out", str(out), "--table", str(table), "--rate", "20", "--json"]
    )
    assert code == 0
    r = json.loads(capsys.readouterr().out)
    assert r["n_samples"] == 501 and r["out"] == str(out) and r["seed"] == 1
    rows = [ln for ln in table.read_text().splitlines() if not ln.startswith("#")]
    assert rows[0] == "axis,freq_hz,period_s,amplitude_deg,phase_rad" and len(rows) == 1 + 8


def test_show_json_reports_what_the_issue_lists(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["profile", "show", CI, "--json", "--config", config(tmp_path)]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["kind"] == "roll_spectrum" and r["duration_s"] == 25 and r["rate_hz"] == 50
    pa = r["per_axis"]["roll"]
    for key in ("n_lines", "period_s", "band_hz", "sigma_deg", "crest_factor", "target_sigma_deg"):
        assert key in pa
    assert set(r["peaks"]["roll"]) == {"angle_deg", "rate_deg_s", "accel_deg_s2"}
    assert r["check"]["scale"] == 1.0


def test_show_text(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["profile", "show", str(ROOT / "profiles" / "linearity_sine_steps.yaml")]) == 0
    out = capsys.readouterr().out
    assert "sine_steps" in out and "peak angle 10.000 deg" in out


def test_limits_exceeded_exit_2_and_scale_to_fit(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cfg = config(tmp_path, angle=2.0)
    assert main(["profile", "synth", CI, "--out", str(tmp_path / "x.csv"), "--config", cfg]) == 2
    err = capsys.readouterr().err
    assert "peak angle needed" in err and "allowed 2.000 deg" in err
    assert not (tmp_path / "x.csv").exists()  # refused before anything is written
    code = main(["profile", "show", CI, "--config", cfg, "--scale-to-fit", "--json"])
    assert code == 0
    r = json.loads(capsys.readouterr().out)
    assert 0 < r["check"]["scale"] < 1 and r["peaks"]["roll"]["angle_deg"] <= 2.0


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        ({"kind": "nonsense", "name": "x", "seed": 1}, "field kind = 'nonsense'"),
        (
            {
                "kind": "sea_state",
                "name": "x",
                "seed": 1,
                "duration_s": 60,
                "band_hz": [0.05, 0.5],
                "sea": {"spectrum": "jonswap", "hs_m": -1, "tp_s": 8},
                "axes": {"roll": {"natural_period_s": 6, "damping_ratio": 0.1}},
            },
            "field sea.hs_m = -1",
        ),
        (
            {
                "kind": "roll_spectrum",
                "name": "x",
                "seed": 1,
                "duration_s": 30,
                "band_hz": [0.01, 0.5],
                "axes": {
                    "roll": {"model": "exp_cos", "sigma_deg": 2, "period_s": 6, "damping": 0.2}
                },
            },
            "below the resolution",
        ),
        (
            {
                "kind": "recorded",
                "name": "x",
                "seed": 1,
                "duration_s": 60,
                "band_hz": [0.1, 0.3],
                "axes": {"roll": {"csv": "gone.csv", "angle_column": "roll_deg"}},
            },
            "file not found",
        ),
    ],
)
def test_bad_profiles_exit_2_with_a_clear_message(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], data: dict[str, object], needle: str
) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(data), encoding="utf-8")
    assert main(["profile", "show", str(p)]) == 2
    err = capsys.readouterr().err
    assert str(p) in err and needle in err


def test_plot_writes_an_image(tmp_path: Path) -> None:
    out = tmp_path / "p.png"
    assert main(["profile", "plot", CI, "--out", str(out), "--rate", "20", "--window", "20"]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out2 = tmp_path / "h.png"
    assert (
        main(
            [
                "profile",
                "plot",
                str(ROOT / "profiles" / "harmonics_example.yaml"),
                "--out",
                str(out2),
            ]
        )
        == 0
    )
    assert out2.stat().st_size > 1000


def test_sine_steps_have_no_table_and_no_duration_override(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    steps = str(ROOT / "profiles" / "linearity_sine_steps.yaml")
    out, table = str(tmp_path / "s.csv"), str(tmp_path / "t.csv")
    assert main(["profile", "synth", steps, "--out", out, "--table", table, "--rate", "10"]) == 2
    assert "no --table export" in capsys.readouterr().err
    assert not Path(out).exists()
    assert main(["profile", "show", steps, "--duration", "120"]) == 2
    assert "lasts 701 s" in capsys.readouterr().err
