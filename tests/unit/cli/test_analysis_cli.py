"""``benchctl analyze`` end to end: CSV, two CSVs, a recording folder, plots, errors → exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from analysis_synthetic import Multisine, first_order, gain, orthogonal_noise

from benchctl.analysis import analyze
from benchctl.cli import main
from benchctl.devices.base import InstrumentSample, StandSample, StandStatus
from benchctl.evaluate import analyze_recording
from benchctl.recording import RecordingWriter

MS = Multisine(period_s=100.0, f_lo=0.05, f_hi=0.6, rms_deg=5.0)
SN = 0.05


def write_csv(path: Path, header: str, *cols: np.ndarray) -> Path:
    with path.open("w", encoding="utf-8") as f:
        f.write(header + "\n")
        np.savetxt(f, np.column_stack(cols), delimiter=",", fmt="%.17g")
    return path


@pytest.fixture
def single_csv(tmp_path: Path) -> Path:
    t = np.arange(6000) / 20.0
    x = MS.reference(t)
    y0 = MS.through(gain(0.98), t)
    y = y0 + orthogonal_noise(np.random.default_rng(1), SN, y0 - x)
    return write_csv(tmp_path / "run.csv", "time,reference,device", t, x, y)


def run_cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(["analyze", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_csv_json(single_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run_cli([str(single_csv), "--json", "--band", "0.05", "0.6"], capsys)
    assert code == 0
    d = json.loads(out)
    truth = np.sqrt(MS.error_variance(gain(0.98)) + SN**2)
    assert d["sigma"] == pytest.approx(truth, rel=1e-9)
    assert d["variance"] == pytest.approx(truth**2, rel=1e-9)
    assert d["sigma_ci95"][0] < d["sigma"] < d["sigma_ci95"][1]
    assert d["n_samples"] == 6000 and d["sample_rate"] == pytest.approx(20.0)
    assert d["duration"] == pytest.approx(300.0) and d["max_lag"] == pytest.approx(30.0)
    assert d["band"]["lo"] == 0.05 and d["delay_compensated"] == 0.0
    assert set(d["frf"]) == {"freq", "gain", "phase_deg", "coherence", "gain_ci95",
                             "phase_ci95_deg", "reliable", "source"}
    assert np.allclose(d["frf"]["gain"], 0.98, atol=0.005)
    assert d["frf"]["source"] == "lines" and d["lines"]["source"] == "detected"
    assert d["lines"]["n_periods"] == 3 and d["lines"]["period_s"] == pytest.approx(100.0)
    assert d["gaps"]["device"]["count"] == 0


def test_csv_summary_and_plot(
    single_csv: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    png = tmp_path / "out.png"
    code, out, _ = run_cli([str(single_csv), "--plot", str(png)], capsys)
    assert code == 0
    assert "σ (dynamic error, about the mean)" in out and "95 % CI" in out
    assert "   3 s  0.98" in out  # the traditional periods' table
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_two_csvs_radians_and_columns(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rng = np.random.default_rng(2)
    tr = np.arange(30000) / 100.0 + rng.uniform(-0.002, 0.002, 30000)
    td = np.arange(1, 5990) / 20.0
    h = first_order(0.1)
    y0 = MS.through(h, td)
    y = y0 + orthogonal_noise(rng, SN, y0 - MS.reference(td))
    ref = write_csv(tmp_path / "stand.csv", "t,encoder", tr, np.radians(MS.reference(tr)))
    dev = write_csv(tmp_path / "imu.csv", "t,roll", td, np.radians(y))
    argv = ["--reference", str(ref), "--device", str(dev), "--time-col", "t",
            "--device-col", "roll", "--units", "rad", "--json"]
    code, out, _ = run_cli(argv, capsys)
    assert code == 0
    d = json.loads(out)
    truth = np.sqrt(MS.error_variance(h) + SN**2)
    assert d["sigma"] == pytest.approx(truth, rel=0.01)
    code, out, _ = run_cli([*argv, "--compensate-delay", "auto"], capsys)
    d2 = json.loads(out)
    assert d2["delay_compensated"] == pytest.approx(d["delay"])
    assert d2["uncertainty"]["compensate_delay"] == "auto" and d2["sigma"] < d["sigma"]


def make_recording(folder: Path) -> Path:
    """A closed recording, two axes: stand 100 Hz at jittery midpoints, instrument 50 Hz."""
    rng = np.random.default_rng(3)
    w = RecordingWriter(folder, ("roll", "pitch"), {"serial": "T-1"})
    status = StandStatus(ready=True, enabled=True, moving=True, fault=False, estop=False,
                         limit=False)
    ts = 100.0 + np.arange(24000) / 100.0 + rng.uniform(-0.002, 0.002, 24000)
    pitch = Multisine(period_s=100.0, f_lo=0.05, f_hi=0.6, rms_deg=2.0, seed=9)
    xr, xp = MS.reference(ts), pitch.reference(ts)
    for t, r, p in zip(ts.tolist(), xr.tolist(), xp.tolist(), strict=True):
        w.write_stand(StandSample(
            t_host=t, rtt_s=0.004, angle_deg={"roll": r, "pitch": p},
            rate_deg_s={"roll": 0.0, "pitch": 0.0}, setpoint_deg={"roll": 0.0, "pitch": 0.0},
            status=status))
    ti = 101.0 + np.arange(11800) / 50.0
    ti = np.delete(ti, [500, 3000, 3001])  # three dropped samples
    roll = MS.through(gain(0.99), ti) + rng.normal(0, SN, ti.size)
    pit = pitch.through(gain(1.02), ti) + rng.normal(0, SN, ti.size)
    for i, (t, r, p) in enumerate(zip(ti.tolist(), roll.tolist(), pit.tolist(), strict=True)):
        w.write_instrument(InstrumentSample(t_host=t, angle_deg={"roll": r, "pitch": p},
                                            counter=i))
    w.close("done")
    return folder


def test_recording_all_axes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rec = make_recording(tmp_path / "rec")
    code, out, _ = run_cli([str(rec), "--json"], capsys)
    assert code == 0
    d = json.loads(out)
    assert set(d["axes"]) == {"roll", "pitch"}
    roll = d["axes"]["roll"]
    assert roll["axis"] == "roll"
    gaps = roll["gaps"]["device"]
    assert gaps == {"count": 2, "missing_samples": 3, "longest_s": pytest.approx(0.06)}
    assert np.median(roll["frf"]["gain"]) == pytest.approx(0.99, abs=0.003)
    assert np.median(d["axes"]["pitch"]["frf"]["gain"]) == pytest.approx(1.02, abs=0.003)
    code, out, _ = run_cli([str(rec), "--json", "--axis", "pitch"], capsys)
    single = json.loads(out)
    assert single["axis"] == "pitch" and single["sigma"] == d["axes"]["pitch"]["sigma"]
    api = analyze_recording(rec, "pitch")
    assert api.sigma == single["sigma"]
    png = tmp_path / "r.png"
    assert run_cli([str(rec), "--plot", str(png)], capsys)[0] == 0
    assert (tmp_path / "r_roll.png").is_file() and (tmp_path / "r_pitch.png").is_file()


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        ([], "nothing to analyse"),
        (["{csv}", "--device", "x.csv"], "--reference and --device together"),
        (["{tmp}/nope.csv"], "no such file"),
        (["{tmp}"], "not a benchctl recording"),
        (["{csv}", "--device-col", "imu"], "no column 'imu'"),
        (["{csv}", "--band", "0.001", "0.5"], "too short for the band"),
        (["{csv}", "--band", "0.5", "0.1"], "expected 0 ≤ lo < hi"),
        (["{csv}", "--compensate-delay", "soon"], "expected seconds or 'auto'"),
        (["{csv}", "--max-lag", "-1"], "positive number of seconds"),
        (["{csv}", "--max-lag", "200"], "record too short"),
    ],
)
def test_bad_input_exits_2(
    argv: list[str], match: str, single_csv: Path, tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    args = [a.format(csv=single_csv, tmp=tmp_path) for a in argv]
    code, _, err = run_cli(args, capsys)
    assert code == 2
    assert match in err and err.startswith("benchctl analyze: error:")


def test_api_matches_cli(single_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = np.loadtxt(single_csv, delimiter=",", skiprows=1)
    r = analyze(data[:, 0], data[:, 1], data[:, 0], data[:, 2])
    d = json.loads(run_cli([str(single_csv), "--json"], capsys)[1])
    assert d == json.loads(json.dumps(r.to_dict() | {"source": d["source"]}))


def test_summary_gain_range_leaves_the_weak_lines_out(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """A multisine whose three lowest lines are 0.002° high (a profile's band edge) through a
    gain of 0.98 with 0.02° of noise: their Ĥ is mostly noise (SNR about 3). The summary's gain
    range is the reliable lines' (0.98 ± their noise), and says how many lines it left out and
    where."""
    tp, fs = 40.0, 10.0
    k = np.arange(2, 25)
    f = k / tp
    amp = np.where(k < 5, 2e-3, 1.0)
    t = np.arange(round(3 * tp * fs)) / fs
    ph = np.random.default_rng(3).uniform(0, 2 * np.pi, k.size)
    x = (amp[:, None] * np.cos(2 * np.pi * f[:, None] * t + ph[:, None])).sum(0)
    y = 0.98 * x + np.random.default_rng(4).normal(0.0, 0.02, t.size)
    path = write_csv(tmp_path / "weak.csv", "time,reference,device", t, x, y)
    code, out, _ = run_cli([str(path), "--period", str(tp)], capsys)
    assert code == 0
    line = next(s for s in out.splitlines() if s.strip().startswith("gain "))
    lo, hi = (float(v) for v in line.split(",")[0].split()[1::2])
    assert 0.95 < lo <= hi < 1.01, line
    assert "(3 lines over 0.05 … 0.1 Hz below SNR 10: not measured reliably, not shown)" in line
