"""Bad input is refused cleanly before anything opens: CSVs (huge numbers, gaps, any bytes),
numeric options of every subcommand, YAML (duplicate keys, aliases, depth, bytes, sexagesimal,
non-finite numbers), fault schedules, and a taken TCP port. Each is a ``BenchError`` → exit 2
with one line ``benchctl <cmd>: error: …`` naming the file, the field/line/option, the value and
what was expected; never a traceback, a hang or a silent acceptance.

One file (about 700 lines) on purpose: it is a catalogue of refusals, one short case each,
checked against one rule (the one-line error and exit 2); split, the rule would be asserted in
several places."""

from __future__ import annotations

import signal
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from repo_paths import ROOT

from benchctl import faultspec as faults
from benchctl.analysis import analyze
from benchctl.analysis.inputs import load_csv_pair, load_single_csv
from benchctl.cli import main
from benchctl.config import (
    SimStandConfig,
    StandLimits,
    load_config,
    parse_config,
)
from benchctl.devices.modbus.regmap_load import load_register_map
from benchctl.errors import ConfigError, DataError, InputError
from benchctl.profiles import load_profile
from benchctl.yamlfile import MAX_YAML_DEPTH, MAX_YAML_NODES, read_yaml

SLOW = 30.0  # a generous bound for "refused quickly" (was minutes, or a hang)


# -- helpers ---------------------------------------------------------------------------------


def cli(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def refused(argv: list[str], capsys: pytest.CaptureFixture[str], *parts: str) -> str:
    """Run the CLI; assert exit 2, one line on stderr ``benchctl <cmd>: error: …`` holding
    ``parts``, no traceback; return that line."""
    t0 = time.monotonic()
    code, _, err = cli(argv, capsys)
    assert time.monotonic() - t0 < SLOW
    assert code == 2, err
    assert "Traceback" not in err
    assert err.startswith(f"benchctl {argv[0]}: error: "), err
    assert err.count("\n") == 1 and err.endswith("\n"), err
    for p in parts:
        assert p in err, (p, err)
    return err


def csv_rows(n: int = 300, dt: float = 0.05) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.arange(n) * dt
    x = 5.0 * np.sin(2 * np.pi * 0.2 * t)
    y = 0.98 * x + 0.01 * np.random.default_rng(1).normal(size=n)
    return t, x, y


def write_csv(path: Path, t: np.ndarray, x: np.ndarray, y: np.ndarray) -> Path:
    lines = ["time,reference,device"]
    lines += [f"{float(a)!r},{float(b)!r},{float(c)!r}" for a, b, c in zip(t, x, y, strict=True)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def sim_config(tmp_path: Path, name: str = "sim.yaml") -> dict[str, Any]:
    """A shipped config as data, with absolute paths (so it can be written anywhere)."""
    data: dict[str, Any] = yaml.safe_load((ROOT / "config" / name).read_text())
    data["stand"]["port"] = 0
    for k in ("register_map", "eds", "dbc"):
        for section in ("stand", "instrument"):
            if k in data[section]:
                data[section][k] = str((ROOT / "config" / data[section][k]).resolve())
    data["run"]["output_dir"] = str(tmp_path / "runs")
    return data


def write_yaml(path: Path, data: Any) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return path


def put(data: dict[str, Any], dotted: str, value: Any) -> dict[str, Any]:
    node = data
    *head, last = dotted.split(".")
    for k in head:
        node = node.setdefault(k, {})
    node[last] = value
    return data


# -- 1. analysis CSVs: huge and odd numbers --------------------------------------------------


def test_last_time_1e308_is_refused_quickly_naming_file_row_and_value(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t, x, y = csv_rows()
    t[-1] = 1e308
    f = write_csv(tmp_path / "huge.csv", t, x, y)
    refused(["analyze", str(f)], capsys, str(f), "data row 300", "line 301", "1e+308", "time")


@pytest.mark.parametrize("last", [1e6, 1e11])
def test_a_huge_gap_is_refused_naming_the_gap(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], last: float
) -> None:
    t, x, y = csv_rows()
    t[-1] = last
    f = write_csv(tmp_path / "gap.csv", t, x, y)
    err = refused(["analyze", str(f)], capsys, str(f), "data row 300 (line 301)", "gap")
    assert "at most 30000" in err  # 100 × 300 samples


def test_gap_in_the_middle_names_its_row(tmp_path: Path) -> None:
    t, x, y = csv_rows()
    t[150:] += 1e4
    f = write_csv(tmp_path / "gap.csv", t, x, y)
    with pytest.raises(DataError, match=r"data row 151 \(line 152\): time 10007\.5 after 7\.45"):
        load_single_csv(f)


def test_api_refuses_a_huge_gap_quickly() -> None:
    t, x, y = csv_rows()
    t[-1] = 1e11
    t0 = time.monotonic()
    with pytest.raises(DataError, match=r"reference time: sample 299: time 100000000000\.0"):
        analyze(t, x, t, y)
    assert time.monotonic() - t0 < SLOW


@pytest.mark.parametrize(
    ("column", "value", "match"),
    [
        ("time", 5e-324, "median time step"),  # denormal steps
        ("time", 1e13, r"\|time\| ≤ 1e\+12"),
        ("reference", 1e308, r"\|value\| ≤ 1e\+06"),
        ("device", -1e300, r"\|value\| ≤ 1e\+06"),
    ],
)
def test_odd_numbers_are_refused(tmp_path: Path, column: str, value: float, match: str) -> None:
    t, x, y = csv_rows()
    if column == "time" and value < 1:
        t = np.arange(len(t)) * value
    elif column == "time":
        t = t + value
    elif column == "reference":
        x[7] = value
    else:
        y[7] = value
    f = write_csv(tmp_path / "odd.csv", t, x, y)
    with pytest.raises(DataError, match=match) as info:
        load_single_csv(f)
    assert str(f) in str(info.value)


def test_negative_zero_and_denormal_angles_give_a_result(tmp_path: Path) -> None:
    t, x, y = csv_rows()
    t[0] = -0.0
    x[3], y[4] = -0.0, 5e-324
    s = load_single_csv(write_csv(tmp_path / "ok.csv", t, x, y))
    r = analyze(s.t_ref, s.x_ref, s.t_dev, s.y_dev)
    assert np.isfinite(r.sigma) and r.n_samples == 300


# -- 2. analysis CSVs: any bytes -------------------------------------------------------------


def _big_csv_bytes(n: int = 1000) -> bytes:
    t, x, y = csv_rows(n)
    lines = ["time,reference,device"] + [f"{a!r},{b!r},{c!r}" for a, b, c in
                                         zip(t.tolist(), x.tolist(), y.tolist(), strict=True)]
    return ("\n".join(lines) + "\n").encode()


@pytest.mark.parametrize("where", ["data", "comment"])
def test_non_utf8_byte_after_8kb(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], where: str
) -> None:
    raw = _big_csv_bytes()
    cut = raw.index(b"\n", 9000) + 1
    line = raw[:cut].count(b"\n") + 1
    bad = b"1.0,2.0,\xe93.0\n" if where == "data" else b"# caf\xe9\n"
    f = tmp_path / "latin1.csv"
    f.write_bytes(raw[:cut] + bad + raw[cut:])
    offset = cut + bad.index(b"\xe9")
    refused(["analyze", str(f)], capsys, str(f), f"line {line}", "0xe9", f"offset {offset}")


def test_non_utf8_in_the_header_and_in_a_device_csv(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    h = tmp_path / "h.csv"
    h.write_bytes(b"time,r\xff\n0,1\n")
    refused(["analyze", "--reference", str(h), "--device", str(h)], capsys, str(h), "line 1",
            "0xff")
    good = tmp_path / "ref.csv"
    good.write_text("time,angle\n" + "".join(f"{i * 0.1},{i}\n" for i in range(100)))
    dev = tmp_path / "dev.csv"
    dev.write_bytes(b"time,angle\n0,1\n0.1,\x80\n")
    with pytest.raises(DataError, match=r"dev\.csv: line 3: byte 0x80 at offset 19"):
        load_csv_pair(good, dev)


@pytest.mark.parametrize(
    "payload",
    [
        b"time,reference,device\n0,1,\x002\n",
        b"time,reference,device\r0,1,2\r",
        b"\xef\xbb\xbftime,reference,device\n",
        b"time,reference,device\n\"0\",1,2\n",
        b"\x00\x01\x02",
        b"",
        b"time,reference,device\n" + b"0,1,2,3\n",
        b"time,reference,device\n1e999,1,2\n",
    ],
)
def test_odd_bytes_are_a_data_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], payload: bytes
) -> None:
    f = tmp_path / "b.csv"
    f.write_bytes(payload)
    refused(["analyze", str(f)], capsys, str(f))


# -- 3. numeric options ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("extra", "parts"),
    [
        (["--max-lag", "1e308"], ["--max-lag 1e+308", "0 < value ≤ 86400 s"]),
        (["--max-lag", "nan"], ["--max-lag nan"]),
        (["--max-lag", "inf"], ["--max-lag inf"]),
        (["--max-lag", "0"], ["--max-lag 0.0"]),
        (["--band", "0.05", "1e308"], ["--band 0.05 1e+308", "hi ≤ 1e+06 Hz"]),
        (["--band", "nan", "1"], ["--band nan 1.0"]),
        (["--band", "-1", "1"], ["--band -1.0 1.0"]),
        (["--compensate-delay", "1e308"], ["--compensate-delay '1e308'", "3600"]),
        (["--compensate-delay", "nan"], ["--compensate-delay 'nan'"]),
        (["--compensate-delay=-inf"], ["--compensate-delay '-inf'"]),
    ],
)
def test_analyze_option_ranges(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], parts: list[str]
) -> None:
    missing = tmp_path / "never-read.csv"  # checked before any file is read
    refused(["analyze", str(missing), *extra], capsys, *parts)


@pytest.mark.parametrize(
    ("extra", "parts"),
    [
        (["--duration", "inf"], ["--duration inf", "0 < value ≤ 86400 s"]),
        (["--duration", "1e9"], ["--duration 1000000000.0", "86400"]),
        (["--duration", "nan"], ["--duration nan"]),
        (["--duration", "0"], ["--duration 0.0"]),
        (["--duration", "-5"], ["--duration -5.0"]),
        (["--seed", "-1"], ["--seed -1", "0 ≤ value ≤ 9.22337e+18"]),
        (["--seed", str(2**64)], ["--seed 18446744073709551616"]),
    ],
)
def test_run_option_ranges_before_anything_opens(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], parts: list[str]
) -> None:
    cfg = write_yaml(tmp_path / "bench.yaml", sim_config(tmp_path))
    argv = ["run", "--config", str(cfg), "--profile", str(tmp_path / "absent.yaml"),
            "--serial", "S", "--operator", "O", *extra]
    refused(argv, capsys, *parts)
    assert not (tmp_path / "runs").exists()  # nothing opened, no recording


def test_run_duration_times_the_stand_rate_is_bounded(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data = put(sim_config(tmp_path), "stand.setpoint_rate_hz", 1000)
    cfg = write_yaml(tmp_path / "bench.yaml", data)
    # a profile that is not there: should the check not fire, the run fails, never starts
    argv = ["run", "--config", str(cfg), "--profile", str(tmp_path / "absent.yaml"),
            "--serial", "S", "--operator", "O", "--duration", "86400"]
    refused(argv, capsys, "--duration 86400", "8.64e+07 setpoints at 1000 Hz", "20000000")
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize(
    ("action", "extra", "parts"),
    [
        ("show", ["--duration", "1e9"], ["--duration 1000000000.0", "86400"]),
        ("show", ["--seed", "-3"], ["--seed -3"]),
        ("show", ["--rate", "1e308"], ["--rate 1e+308", "0 < value ≤ 100000 Hz"]),
        ("show", ["--rate", "nan"], ["--rate nan"]),
        ("show", ["--rate", "100000", "--duration", "86400"],
         ["86400 s at 100000 Hz", "8.64e+09 samples", "20000000"]),
        ("show", ["--rate", "100000"], ["samples per axis"]),  # the profile's own 900 s
        ("synth", ["--duration", "inf"], ["--duration inf"]),
        ("plot", ["--window", "inf"], ["--window inf", "86400"]),
        ("plot", ["--window", "-1"], ["--window -1.0"]),
    ],
)
def test_profile_option_ranges(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], action: str, extra: list[str],
    parts: list[str]
) -> None:
    out = ["--out", str(tmp_path / "o.x")] if action != "show" else []
    argv = ["profile", action, str(ROOT / "profiles" / "paper_vessel_roll.yaml"), *out, *extra]
    code, _, err = cli(argv, capsys)
    assert code == 2 and err.startswith("benchctl profile: error: ") and err.count("\n") == 1
    for p in parts:
        assert p in err, (p, err)
    assert not (tmp_path / "o.x").exists()


# -- 4. YAML rules -----------------------------------------------------------------------------


@pytest.mark.usefixtures("keep_signal_handlers")
def test_duplicate_key_in_a_config(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = (ROOT / "config" / "sim.yaml").read_text()
    text = text.replace("  port: 5020\n", "  port: 5020\n  port: 5021\n", 1)
    f = tmp_path / "dup.yaml"
    f.write_text(text)
    line = text.splitlines().index("  port: 5021") + 1
    refused(["sim", "--config", str(f)], capsys, str(f), f"line {line}", "duplicate key 'port'",
            "first at line")


def test_duplicate_key_in_a_profile_and_a_register_map(tmp_path: Path) -> None:
    prof = tmp_path / "p.yaml"
    prof.write_text((ROOT / "profiles" / "sine_5s_5deg.yaml").read_text() + "seed: 4\n")
    with pytest.raises(ConfigError, match=r"p\.yaml: not valid YAML: line \d+, column 1: "
                                          r"duplicate key 'seed'"):
        load_profile(prof)
    rmap = tmp_path / "map.yaml"
    rmap.write_text((ROOT / "drivers" / "stand_generic.yaml").read_text() + "word_order: big\n")
    with pytest.raises(ConfigError, match="duplicate key 'word_order'"):
        load_register_map(rmap)


def test_merge_keys_are_not_duplicates(tmp_path: Path) -> None:
    f = tmp_path / "m.yaml"
    f.write_text("base: &b {x: 1, y: 2}\nd:\n  <<: *b\n  x: 3\n")
    assert read_yaml(f, "test") == {"base": {"x": 1, "y": 2}, "d": {"x": 3, "y": 2}}


def _alias_bomb(levels: int = 9) -> str:
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for i in range(1, levels):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]")
    return "\n".join(lines) + "\n"


def test_alias_bomb_is_refused_quickly(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "bomb.yaml"
    f.write_text(_alias_bomb())
    t0 = time.monotonic()
    with pytest.raises(ConfigError, match=rf"line 6, column 5: this node expands to \d+ nodes "
                                          rf"through aliases; expected at most {MAX_YAML_NODES}"):
        read_yaml(f, "bench config")
    assert time.monotonic() - t0 < SLOW
    refused(["run", "--config", str(f), "--profile", str(f), "--serial", "S", "--operator", "O"],
            capsys, "expands to")


def test_a_few_aliases_are_fine(tmp_path: Path) -> None:
    f = tmp_path / "a.yaml"
    f.write_text("lim: &l {angle_deg: 30, rate_deg_s: 30, accel_deg_s2: 60}\nb: [*l, *l]\n")
    assert read_yaml(f, "test")["b"][1]["angle_deg"] == 30


@pytest.mark.parametrize("text", ["[" * 20000 + "]" * 20000, "{a: " * 20000 + "1" + "}" * 20000,
                                  "".join("  " * i + "a:\n" for i in range(400))])
def test_deep_nesting_is_refused(tmp_path: Path, text: str) -> None:
    f = tmp_path / "deep.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=rf"nested more than {MAX_YAML_DEPTH} levels"):
        read_yaml(f, "profile")


def test_recursive_alias_is_refused(tmp_path: Path) -> None:
    f = tmp_path / "r.yaml"
    f.write_text("a: &a [1, *a]\n")
    with pytest.raises(ConfigError, match=r"line 1, column 11: alias \*a is inside its own"):
        read_yaml(f, "profile")


def test_non_utf8_config_names_the_byte_offset(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    raw = (ROOT / "config" / "sim.yaml").read_bytes()
    cut = raw.index(b"station:")
    f = tmp_path / "latin1.yaml"
    f.write_bytes(raw[:cut] + b"# \xe9t\xe9\n" + raw[cut:])
    line = raw[:cut].count(b"\n") + 1
    refused(["sim", "--config", str(f)], capsys, str(f),
            f"line {line}: byte 0xe9 at offset {cut + 2}", "UTF-8")


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("a: 2001-13-45\n", r"line 1, column 4: cannot read '2001-13-45'"),
        ("a: 0x_\n", r"line 1, column 4: cannot read '0x_'"),
        ("a: !!int 30:00\n", "sexagesimal number '30:00'"),
        ("a: !!float abc\n", "cannot read 'abc'"),
        ("a:\t\x01\n", r"line 1: character U\+0001"),
        ("a: 1\n---\nb: 2\n", "expected a single document"),
        ("a: [1, 2\n", "not valid YAML: line 2"),
        ("a: *nothing\n", "undefined alias"),
        ("a: !!python/object:os.system x\n", "could not determine a constructor"),
    ],
)
def test_other_yaml_failures_are_one_line_config_errors(
    tmp_path: Path, text: str, match: str
) -> None:
    f = tmp_path / "x.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=match) as info:
        read_yaml(f, "profile")
    assert "\n" not in str(info.value) and str(f) in str(info.value)


def test_sexagesimal_and_leading_zero_numbers(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "n.yaml"
    f.write_text("a: 30:00\nb: 1:30.5\nc: 010\nd: 0x1F\ne: 1_000\nf: 1.5e+3\n")
    assert read_yaml(f, "test") == {"a": "30:00", "b": "1:30.5", "c": "010", "d": 31, "e": 1000,
                                     "f": 1500.0}
    data = put(sim_config(tmp_path), "stand.limits.angle_deg", "30:00")
    text = yaml.safe_dump(data, sort_keys=False).replace("'30:00'", "30:00")
    cfg = tmp_path / "bench.yaml"
    cfg.write_text(text)
    refused(["sim", "--config", str(cfg)], capsys, "field stand.limits.angle_deg = '30:00'")
    cfg.write_text(yaml.safe_dump(sim_config(tmp_path), sort_keys=False)
                   .replace("device_id: 1\n", "device_id: 010\n"))
    assert load_config(cfg).stand.device_id == 10  # decimal, not YAML 1.1 octal 8


NON_FINITE_FIELDS = [
        "stand.limits.rate_deg_s",
        "stand.timeout_s",
        "stand.tracking_tolerance_deg",
        "stand.setpoint_rate_hz",
        "instrument.silence_timeout_s",
        "instrument.expected_rate_hz",
        "instrument.can_options.x",
        "run.limit_sigma_deg",
        "run.precheck_window_s",
        "run.instrument_rate_tolerance",
        "run.analysis.max_lag_s",
        "run.analysis.compensate_delay",
        "sim.stand.bandwidth_hz",
        "sim.stand.watchdog_s",
        "sim.instrument.gain",
        "sim.instrument.bias_deg",
        "sim.instrument.rate_hz",
        "sim.motion_threshold_deg",
    ]


@pytest.mark.parametrize(
    ("field", "value"),
    [
        (f, v)
        for f in NON_FINITE_FIELDS
        for v in (".inf", "-.inf", ".nan", "inf")
        # a CAN option may be any string: unquoted `inf` is the string 'inf' there
        if not (f.startswith("instrument.can_options") and v == "inf")
    ],
)
def test_non_finite_numbers_in_a_config(tmp_path: Path, field: str, value: str) -> None:
    data = put(sim_config(tmp_path), field, "@@")
    f = tmp_path / "bench.yaml"
    f.write_text(yaml.safe_dump(data, sort_keys=False).replace("'@@'", value))
    with pytest.raises(ConfigError) as info:
        load_config(f)
    msg = str(info.value)
    assert str(f) in msg and f"field {field}" in msg and "\n" not in msg, msg


@pytest.mark.parametrize(
    ("field", "value", "match"),
    [
        ("stand.setpoint_rate_hz", 1e9, "less than or equal to 1000"),
        ("stand.timeout_s", 1e308, "less than or equal to 3600"),
        ("stand.baudrate", 10**30, "less than or equal to 100000000"),
        ("stand.retries", 10**9, "less than or equal to 100"),
        ("sim.instrument.seed", -1, "greater than or equal to 0"),
        ("sim.stand.tick_hz", 1e12, "less than or equal to 100000"),
        ("run.analysis.band_hz", [0.5, 0.1], "lo < hi"),
    ],
)
def test_config_numbers_are_bounded(
    tmp_path: Path, field: str, value: object, match: str
) -> None:
    f = write_yaml(tmp_path / "bench.yaml", put(sim_config(tmp_path), field, value))
    with pytest.raises(ConfigError, match=match):
        load_config(f)


def _profile(tmp_path: Path, name: str, **changes: Any) -> Path:
    data = yaml.safe_load((ROOT / "profiles" / name).read_text())
    for k, v in changes.items():
        put(data, k, v)
    return write_yaml(tmp_path / "p.yaml", data)


@pytest.mark.parametrize(
    ("name", "field", "value"),
    [
        ("sine_5s_5deg.yaml", "duration_s", float("inf")),
        ("sine_5s_5deg.yaml", "duration_s", 1e9),
        ("sine_5s_5deg.yaml", "fade_in_s", float("nan")),
        ("sine_5s_5deg.yaml", "axes.roll.phase_deg", float("inf")),
        ("sine_5s_5deg.yaml", "axes.roll.amplitude_deg", float("nan")),
        ("harmonics_example.yaml", "repeat_period_s", float("inf")),
        ("paper_vessel_roll.yaml", "duration_s", "inf"),
        ("linearity_sine_steps.yaml", "cycles", 10**9),
        ("linearity_sine_steps.yaml", "rest_s", 1e5),
    ],
)
def test_profile_numbers_finite_and_bounded(
    tmp_path: Path, name: str, field: str, value: object
) -> None:
    p = _profile(tmp_path, name, **{field: value})
    with pytest.raises(ConfigError) as info:
        load_profile(p)
    assert str(p) in str(info.value) and "\n" not in str(info.value)


def test_recorded_profile_csv_with_bad_bytes_or_a_huge_gap(tmp_path: Path) -> None:
    rows = "".join(f"{i * 0.1},{np.sin(i * 0.1):.4f}\n" for i in range(5000))
    csv = tmp_path / "rec.csv"
    p = write_yaml(tmp_path / "p.yaml", {
        "name": "r", "kind": "recorded", "seed": 1, "duration_s": 600, "band_hz": [0.05, 0.5],
        "axes": {"roll": {"csv": "rec.csv", "angle_column": "roll"}},
    })
    csv.write_bytes(b"time,roll\n" + rows.encode() + b"500.0,\xff\n")
    with pytest.raises(DataError, match=r"rec\.csv: line 5002: byte 0xff"):
        load_profile(p)
    csv.write_text("time,roll\n" + rows + "1e300,1\n")
    t0 = time.monotonic()
    with pytest.raises(DataError, match=r"rec\.csv: .*sample 5001 at 1e\+300 s follows 499\.9"):
        load_profile(p)
    assert time.monotonic() - t0 < SLOW


# -- 5. fault schedules --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("fault", "parts"),
    [
        ({"target": "stand", "kind": "stal"},
         ["field sim.faults[0].kind = 'stal'", "drop_connection, stall, modbus_exception"]),
        ({"target": "instrument", "kind": "garbeld"},
         ["field sim.faults[0].kind = 'garbeld'", "garbled, silent, stuck, drop"]),
        ({"target": "stand", "kind": "stall", "params": {"duraton_s": 1}},
         ["field sim.faults[0]", "params.duraton_s = 1", "a parameter of stall: duration_s"]),
        ({"target": "stand", "kind": "modbus_exception", "params": {"code": 300}},
         ["params.code = 300", "1 ≤ value ≤ 255"]),
        ({"target": "stand", "kind": "stand_fault", "params": {"code": "42"}},
         ["params.code = '42'", "an integer"]),
        ({"target": "stand", "kind": "stall", "params": {"duration_s": float("inf")}},
         ["sim.faults[0].params.duration_s"]),
        ({"target": "instrument", "kind": "garbled", "params": {"fraction": 1.5}},
         ["params.fraction = 1.5", "0 < value ≤ 1"]),
        ({"target": "instrument", "kind": "garbled", "params": {"how": "checksum"}},
         ["field sim.faults[0].params.how = 'checksum'", "for driver canopen",
          "(instrument.driver)"]),
        ({"target": "instrument", "kind": "silent", "params": {"fraction": 0.1}},
         ["params.fraction = 0.1", "a parameter of silent: none"]),
        ({"target": "robot", "kind": "stall"}, ["field sim.faults[0].target = 'robot'"]),
    ],
)
def test_bad_fault_schedule_is_refused_at_load(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], fault: dict[str, Any], parts: list[str]
) -> None:
    data = sim_config(tmp_path)
    data["sim"]["faults"] = [{"target": "stand", "kind": "estop", "after_motion_s": 1}]
    data["sim"]["faults"].insert(0, fault)
    f = write_yaml(tmp_path / "bench.yaml", data)
    refused(["sim", "--config", str(f)], capsys, str(f), *parts)


def test_good_fault_schedules_load(tmp_path: Path) -> None:
    data = sim_config(tmp_path, "sim_nmea0183.yaml")
    data["sim"]["faults"] = [
        {"target": "instrument", "kind": "garbled", "params": {"fraction": 1, "how": "checksum"}},
        {"target": "stand", "kind": "modbus_exception", "params": {"code": 4, "count": 3}},
        {"target": "stand", "kind": "stall", "params": {"duration_s": 2}},
    ]
    data["sim"]["stand"]["faults"] = [{"kind": "stand_fault", "after_s": 3, "code": 42}]
    cfg = load_config(write_yaml(tmp_path / "bench.yaml", data))
    assert cfg.sim is not None and len(cfg.sim.faults) == 3


@pytest.mark.parametrize(
    ("fault", "match"),
    [
        ({"kind": "drop"}, r"field sim\.stand\.faults\[0\]\.kind = 'drop': .*unknown stand fault"),
        ({"kind": "estop", "code": 3}, r"code = 3: expected a parameter of estop: none"),
        ({"kind": "modbus_exception", "code": 256}, r"code = 256: expected an integer, 1 ≤"),
        ({"kind": "stall", "duration_s": float("nan")}, r"sim\.stand\.faults\[0\]\.duration_s"),
        ({"kind": "stall", "after_s": 1e9}, r"sim\.stand\.faults\[0\]\.after_s"),
    ],
)
def test_bad_stand_fault_schedule(tmp_path: Path, fault: dict[str, Any], match: str) -> None:
    data = sim_config(tmp_path)
    data["sim"]["stand"]["faults"] = [fault]
    with pytest.raises(ConfigError, match=match):
        parse_config(data, tmp_path / "bench.yaml")


def test_inject_uses_the_same_table() -> None:
    from benchctl.sim.stand import FAULT_KINDS, SimStand

    sim = SimStand(SimStandConfig(), limits=StandLimits(angle_deg=30, rate_deg_s=30,
                                                        accel_deg_s2=60),
                   register_map=ROOT / "drivers" / "stand_generic.yaml")
    with pytest.raises(ConfigError, match=r"SimStand\.inject\(stal\): kind = 'stal': expected"):
        sim.inject("stal")
    with pytest.raises(ConfigError, match=r"params\.duraton_s = 1"):
        sim.inject("stall", duraton_s=1)
    with pytest.raises(ConfigError, match=r"params\.code = 0: expected an integer, 1 ≤ value"):
        sim.inject("modbus_exception", code=0)
    sim.stop()
    assert set(FAULT_KINDS) == set(faults.STAND)


def test_fault_table_matches_the_instrument_simulator() -> None:
    """Whoever adds a kind or a way of garbling to the simulator adds it to the table too
    (benchctl/faultspec.py), or the config refuses it."""
    from benchctl.sim import instrument

    assert set(instrument.FAULTS) == set(faults.INSTRUMENT)
    assert set(instrument.CAN_GARBLING) == set(faults.GARBLING["can"])
    assert set(instrument.NMEA_GARBLING) == set(faults.GARBLING["nmea0183"])


# -- 6. a taken TCP port ---------------------------------------------------------------------------


@pytest.fixture
def keep_signal_handlers() -> Iterator[None]:
    """``benchctl sim`` installs SIGINT/SIGTERM handlers: give pytest its own back."""
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    yield
    for s, h in saved.items():
        signal.signal(s, h)


@pytest.mark.usefixtures("keep_signal_handlers")
def test_sim_port_in_use_is_a_clean_error(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with socket.socket() as holder:
        holder.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        data = put(sim_config(tmp_path), "stand.port", port)
        data["instrument"]["channel"] = str(tmp_path / "slcan0")
        data["run"]["lock_dir"] = str(tmp_path / "locks")
        f = write_yaml(tmp_path / "bench.yaml", data)
        try:
            load_config(f)
        except ConfigError:  # a config.py without run.lock_dir: leave it out
            del data["run"]["lock_dir"]
            f = write_yaml(tmp_path / "bench.yaml", data)
        refused(["sim", "--config", str(f)], capsys, str(f), f"field stand.port = {port}",
                f"TCP port {port} on 127.0.0.1 is already in use")
        assert not (tmp_path / "slcan0").exists()


def test_input_errors_are_bench_errors() -> None:
    assert issubclass(ConfigError, InputError) and issubclass(DataError, InputError)
