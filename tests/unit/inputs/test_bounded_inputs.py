"""Bounded inputs: every file benchctl reads for a user is a regular file under a size cap, and
every motion is under the setpoint cap before any of it is synthesised.

A config, profile, plan, register map or CSV that is a device (``/dev/zero``,
``/dev/urandom``), a FIFO, a folder or a file over the cap is refused at once with an
``InputError`` (exit 2) naming the file, what it is and what was expected — it was read until
memory ran out (≈ 20 GB in 60 s) or, for a FIFO, forever. A profile's own duration, a plan
step's and the Python API's are held to the 2×10⁷-setpoint cap the CLI's ``--duration`` had
(a day at 1000 Hz was synthesised to 7.5 GB and ended in MemoryError)."""

from __future__ import annotations

import math
import os
import time
import tracemalloc
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from repo_paths import ROOT

import benchctl.profiles
from benchctl.analysis.inputs import load_csv_pair, load_single_csv
from benchctl.cli import main
from benchctl.config import load_config, parse_config
from benchctl.devices.modbus.regmap_load import load_register_map
from benchctl.errors import ConfigError, DataError, InputError, LimitError
from benchctl.options import MAX_PROFILE_SAMPLES
from benchctl.plan import load_plan, run_plan
from benchctl.profiles import load_profile
from benchctl.profiles.loader import read_angle_csv
from benchctl.run.plan import check_setpoints, make_plan, setpoint_count
from benchctl.run.prepare import RunOptions, prepare_motion
from benchctl.run.session import run_test
from benchctl.textfile import MAX_CSV_BYTES, MAX_YAML_BYTES, read_input

QUICK_S = 20.0  # a generous bound for "refused at once" (was a hang, or minutes of reading)

# -- the files that are not regular files, or too big -----------------------------------------


def _fifo(tmp: Path) -> Path:
    p = tmp / "fifo"
    os.mkfifo(p)
    return p


def _folder(tmp: Path) -> Path:
    p = tmp / "folder"
    p.mkdir()
    return p


def _huge(cap: int) -> Callable[[Path], Path]:
    def make(tmp: Path) -> Path:
        p = tmp / "huge"
        with p.open("wb") as f:
            f.truncate(cap + 1)  # sparse: one byte over the cap, nothing written to the disk
        return p

    return make


BAD_YAML: dict[str, tuple[Callable[[Path], Path], str]] = {
    "dev_zero": (lambda _: Path("/dev/zero"), "a character device"),
    "dev_urandom": (lambda _: Path("/dev/urandom"), "a character device"),
    "fifo": (_fifo, "a FIFO"),
    "folder": (_folder, "a folder"),
    "huge": (_huge(MAX_YAML_BYTES), f"{MAX_YAML_BYTES + 1} bytes"),
}
BAD_CSV = {**BAD_YAML, "huge": (_huge(MAX_CSV_BYTES), f"{MAX_CSV_BYTES + 1} bytes")}

YAML_READERS: dict[str, tuple[Callable[[Path], Any], str]] = {
    "config": (load_config, "bench config"),
    "profile": (load_profile, "profile"),
    "plan": (load_plan, "plan"),
    "register map": (load_register_map, "register map"),
}


def _write_csv(path: Path) -> Path:
    t = np.arange(200) * 0.05
    x = 5.0 * np.sin(2 * np.pi * 0.2 * t)
    rows = "".join(f"{a:.6f},{b:.6f},{0.98 * b:.6f}\n" for a, b in zip(t, x, strict=True))
    path.write_text("time,reference,device\n" + rows, encoding="utf-8")
    return path


CSV_READERS: dict[str, Callable[[Path, Path], Any]] = {
    "analysis single CSV": lambda p, ok: load_single_csv(p),
    "analysis reference CSV": lambda p, ok: load_csv_pair(p, ok, reference_col="reference",
                                                          device_col="device"),
    "analysis device CSV": lambda p, ok: load_csv_pair(ok, p, reference_col="reference",
                                                       device_col="device"),
    "recorded profile CSV": lambda p, ok: read_angle_csv(p, "time", "reference"),
}


@pytest.fixture
def quickly() -> Iterator[None]:
    t0 = time.monotonic()
    yield
    assert time.monotonic() - t0 < QUICK_S


@pytest.mark.timeout(60, method="thread")  # a FIFO open blocks SIGALRM out
@pytest.mark.parametrize("bad", list(BAD_YAML))
@pytest.mark.parametrize("reader", list(YAML_READERS))
def test_yaml_inputs_must_be_regular_files_under_the_cap(
    tmp_path: Path, reader: str, bad: str, quickly: None
) -> None:
    make, kind = BAD_YAML[bad]
    path = make(tmp_path)
    load, what = YAML_READERS[reader]
    with pytest.raises(ConfigError) as e:
        load(path)
    msg = str(e.value)
    assert msg.startswith(f"{path}: {kind}"), msg
    assert f"expected the {what} as a regular file of at most 16 MiB" in msg, msg


@pytest.mark.timeout(60, method="thread")  # a FIFO open blocks SIGALRM out
@pytest.mark.parametrize("bad", list(BAD_CSV))
@pytest.mark.parametrize("reader", list(CSV_READERS))
def test_csv_inputs_must_be_regular_files_under_the_cap(
    tmp_path: Path, reader: str, bad: str, quickly: None
) -> None:
    make, kind = BAD_CSV[bad]
    path = make(tmp_path)
    ok = _write_csv(tmp_path / "ok.csv")
    with pytest.raises(DataError) as e:
        CSV_READERS[reader](path, ok)
    msg = str(e.value)
    assert msg.startswith(f"{path}: {kind}"), msg
    assert "as a regular file of at most 512 MiB" in msg, msg


def test_the_readers_still_read_regular_files(tmp_path: Path) -> None:
    ok = _write_csv(tmp_path / "ok.csv")
    link = tmp_path / "link.csv"
    link.symlink_to(ok)  # a link to a regular file is a regular file to read
    for reader in CSV_READERS.values():
        reader(link, ok)
    assert load_profile(ROOT / "profiles/sine_5s_5deg.yaml").duration_s == 60


@pytest.mark.timeout(60, method="thread")
def test_a_recorded_profile_whose_csv_is_a_fifo_is_refused_naming_it(tmp_path: Path) -> None:
    fifo = _fifo(tmp_path)
    text = (ROOT / "profiles/recorded_example.yaml").read_text(encoding="utf-8")
    data = yaml.safe_load(text)
    for ax in data["axes"].values():
        ax["csv"] = str(fifo)
    prof = tmp_path / "recorded.yaml"
    prof.write_text(yaml.safe_dump(data), encoding="utf-8")
    t0 = time.monotonic()
    with pytest.raises(DataError, match=f"{fifo}: a FIFO"):
        load_profile(prof)
    assert time.monotonic() - t0 < QUICK_S


def test_a_file_longer_than_its_stated_size_stops_one_byte_past_the_cap() -> None:
    # /proc files say size 0: the cap holds while reading, not only by fstat
    status = Path("/proc/self/status")
    assert os.stat(status).st_size == 0
    with pytest.raises(ConfigError, match="more than 100 bytes"):
        read_input(status, "thing", ConfigError, 100)
    assert len(read_input(status, "thing", ConfigError, 1 << 20)) > 100


@settings(max_examples=100, deadline=None)
@given(content=st.binary(max_size=300), cap=st.integers(min_value=0, max_value=300))
def test_read_input_returns_the_bytes_iff_within_the_cap(
    tmp_path_factory: pytest.TempPathFactory, content: bytes, cap: int
) -> None:
    p = tmp_path_factory.mktemp("read") / "f"
    p.write_bytes(content)
    if len(content) <= cap:
        assert read_input(p, "thing", DataError, cap) == content
    else:
        with pytest.raises(DataError, match=f"{len(content)} bytes"):
            read_input(p, "thing", DataError, cap)


@pytest.mark.timeout(60, method="thread")  # a FIFO open blocks SIGALRM out
@pytest.mark.parametrize(
    ("argv", "what"),
    [
        (["run", "--config", "{fifo}", "--profile", "{profile}", "--serial", "S",
          "--operator", "O"], "bench config"),
        (["run", "--config", "{config}", "--profile", "/dev/zero", "--serial", "S",
          "--operator", "O"], "profile"),
        (["plan", "{fifo}", "--serial", "S", "--yes"], "plan"),
        (["analyze", "{fifo}"], "CSV file"),
        (["analyze", "/dev/urandom"], "CSV file"),
    ],
)
def test_cli_refuses_devices_and_fifos_with_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], what: str,
    quickly: None,
) -> None:
    names = {"fifo": str(_fifo(tmp_path)), "profile": str(ROOT / "profiles/sine_5s_5deg.yaml"),
             "config": str(ROOT / "config/sim.yaml")}
    code = main([a.format(**names) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and err.count("\n") == 1, err
    assert f"expected the {what} as a regular file" in err, err


# -- the setpoint cap: every motion, before anything is synthesised -----------------------------

LONG_PROFILE = """\
name: a_day_of_sine
kind: sine
duration_s: 86400
fade_in_s: 5
fade_out_s: 5
seed: 0
axes:
  roll: {amplitude_deg: 5.0, period_s: 5.0}
"""

BENCH_1000HZ: dict[str, Any] = {
    "station": "unit",
    "stand": {
        "driver": "modbus-tcp",
        "host": "127.0.0.1",
        "port": 9,  # discard: nothing listens, nothing may reach it
        "timeout_s": 0.5,
        "register_map": str(ROOT / "drivers/stand_generic.yaml"),
        "setpoint_rate_hz": 1000,
        "sample_rate_hz": 1000,
        "limits": {"angle_deg": 30, "rate_deg_s": 30, "accel_deg_s2": 60},
    },
    "instrument": {
        "driver": "canopen",
        "interface": "slcan",
        "channel": "/nonexistent/slcan0",
        "eds": str(ROOT / "drivers/cia410_inclinometer.eds"),
    },
    "run": {"limit_sigma_deg": 0.4},
}


@pytest.fixture
def never_synthesised(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[Any]]:
    """Fails the test if a profile is synthesised; measures the memory the refusal took."""
    calls: list[Any] = []

    def spy(*a: Any, **k: Any) -> Any:
        calls.append(a)
        raise AssertionError("the profile was synthesised before the setpoint cap was checked")

    monkeypatch.setattr(benchctl.profiles, "synthesize", spy)
    tracemalloc.start()
    t0 = time.monotonic()
    try:
        yield calls
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert time.monotonic() - t0 < QUICK_S
    assert peak < 50 * 2**20, f"{peak / 2**20:.0f} MiB traced"  # 8.64e7 setpoints: ≥ 690 MB
    assert not calls


def _bench(tmp_path: Path) -> Path:
    p = tmp_path / "bench.yaml"
    data = {**BENCH_1000HZ, "run": {**BENCH_1000HZ["run"], "output_dir": str(tmp_path / "runs")}}
    p.write_text(yaml.safe_dump(data), encoding="utf-8")
    return p


def _long_profile(tmp_path: Path) -> Path:
    p = tmp_path / "day.yaml"
    p.write_text(LONG_PROFILE, encoding="utf-8")
    return p


def test_a_profiles_own_long_duration_is_refused_before_synthesis(
    tmp_path: Path, never_synthesised: list[Any]
) -> None:
    cfg = load_config(_bench(tmp_path))
    prof = _long_profile(tmp_path)
    with pytest.raises(ConfigError) as e:
        prepare_motion(cfg, prof, RunOptions(serial="S", operator="O"))
    msg = str(e.value)
    assert msg.startswith(f"{prof} on {cfg.source}: 8.64e+07 setpoints at 1000 Hz"), msg
    assert f"expected at most {MAX_PROFILE_SAMPLES}" in msg, msg


def test_the_cli_refuses_a_profiles_own_long_duration_with_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], never_synthesised: list[Any]
) -> None:
    code = main(["run", "--config", str(_bench(tmp_path)), "--profile",
                 str(_long_profile(tmp_path)), "--serial", "S", "--operator", "O"])
    err = capsys.readouterr().err
    assert code == 2 and "8.64e+07 setpoints at 1000 Hz" in err, err
    assert not (tmp_path / "runs").exists()


def test_a_plan_steps_long_duration_is_refused_before_synthesis(
    tmp_path: Path, never_synthesised: list[Any]
) -> None:
    _bench(tmp_path)
    plan = tmp_path / "plan.yaml"
    plan.write_text(yaml.safe_dump({
        "name": "long", "config": "bench.yaml", "operator": "tester",
        "steps": [{"name": "a day", "profile": str(ROOT / "profiles/sine_5s_5deg.yaml"),
                   "duration_s": 86400}],
    }), encoding="utf-8")
    out = tmp_path / "out"
    with pytest.raises(ConfigError) as e:
        run_plan(plan, serial="SN1", yes=True, out_dir=out)
    msg = str(e.value)
    assert "step 'a day'" in msg and "8.64e+07 setpoints at 1000 Hz" in msg, msg
    assert not out.exists()


def test_the_python_api_refuses_a_long_duration_before_synthesis(
    tmp_path: Path, never_synthesised: list[Any]
) -> None:
    cfg = load_config(_bench(tmp_path))
    opts = RunOptions(serial="S", operator="O", duration_s=50_000.0)
    with pytest.raises(ConfigError, match=r"5e\+07 setpoints at 1000 Hz"):
        run_test(cfg, ROOT / "profiles/sine_5s_5deg.yaml", opts)
    assert not (tmp_path / "runs").exists()


def test_a_hand_made_plan_is_refused_before_it_is_evaluated() -> None:
    evaluated: list[int] = []

    def evaluate(t: np.ndarray) -> dict[str, np.ndarray]:
        evaluated.append(t.size)
        return {"roll": np.zeros_like(t)}

    with pytest.raises(ConfigError, match=r"motion plan: 8\.64e\+07 setpoints"):
        make_plan(evaluate, ("roll",), 86400.0, 1000.0, 1.0, 1.0)
    assert not evaluated
    plan = make_plan(evaluate, ("roll",), 10.0, 1000.0, 1.0, 1.0)
    assert evaluated == [10_001] and plan.values["roll"].size == 10_001


def test_a_stand_at_1000_hz_takes_the_shipped_profiles() -> None:
    cfg = parse_config(BENCH_1000HZ, ROOT / "bench.yaml")
    opts = RunOptions(serial="S", operator="O")
    prepared = prepare_motion(cfg, ROOT / "profiles/sine_5s_5deg.yaml", opts)
    assert prepared.plan.values["roll"].size == 60_001


@settings(max_examples=200, deadline=None)
@given(
    duration=st.one_of(st.floats(min_value=0.0, max_value=1e9), st.just(math.inf),
                       st.just(math.nan)),
    rate=st.one_of(st.floats(min_value=1e-3, max_value=1e6), st.just(math.inf)),
)
def test_the_setpoint_cap_holds_for_any_duration_and_rate(duration: float, rate: float) -> None:
    n = setpoint_count(duration, rate)
    try:
        check_setpoints(duration, rate, "here")
    except ConfigError as e:
        assert str(e).startswith("here: ")
        assert not (n <= MAX_PROFILE_SAMPLES and math.isfinite(rate))
        return
    # accepted: a finite count under the cap, the count make_plan makes
    assert n <= MAX_PROFILE_SAMPLES
    assert n == math.floor(duration * rate + 1e-9) + 1
    if n <= 5_000:
        plan = make_plan(lambda t: {"roll": t}, ("roll",), duration, rate, 0.0, 0.0)
        assert plan.values["roll"].size == n


def test_the_cap_is_the_one_the_run_command_states() -> None:
    assert MAX_PROFILE_SAMPLES == 20_000_000
    with pytest.raises(InputError):
        check_setpoints(20_000.0, 1000.0, "x")  # 2×10⁷ + 1 setpoints
    check_setpoints(19_999.0, 1000.0, "x")


def test_a_table_longer_than_the_stands_is_refused_before_anything_opens() -> None:
    """Table mode: the profile's table must fit the stand's (the register map's
    ``axes.<axis>.table.max_lines``); refused while preparing, as a limit is — not after the
    prechecks, as the driver's own upload check did (safety campaign seed 471)."""
    cfg = load_config(ROOT / "config/sim.yaml")
    cfg = cfg.model_copy(update={"stand": cfg.stand.model_copy(update={"mode": "table"})})
    prof = ROOT / "profiles/sea_state_4_small_vessel.yaml"
    with pytest.raises(LimitError) as e:
        prepare_motion(cfg, prof, RunOptions(serial="S", operator="O", duration_s=300.0))
    msg = str(e.value)
    assert msg.startswith(f"{prof} on {cfg.source} (field stand.mode = 'table'): the roll table "
                          "has 127 lines over 300 s, the stand's table takes at most 64"), msg
    assert "expected mode 'buffered' or 'stream'" in msg
    # a table that fits is prepared
    ok = prepare_motion(cfg, ROOT / "profiles/sine_5s_5deg.yaml", RunOptions("S", "O"))
    assert ok.plan.tables is not None


# ------------------------------------------------------------- a CSV read once, parsed fast
def test_a_csv_parsed_by_its_descriptor_is_the_bytes_read_and_a_changed_file_is_noticed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """loadtxt reads the open file again by /proc/self/fd (its fast path); the columns are
    exactly those of the bytes read, and where the file changed after it was read the bytes
    read are parsed instead (never a mix of two versions of the file)."""
    from benchctl.analysis import inputs
    from benchctl.errors import DataError
    from benchctl.textfile import InputFile, input_file

    p = tmp_path / "r.csv"
    t = np.arange(2000) * 0.01
    rows = "".join(f"{a:.2f},{np.sin(a):.6f},{np.cos(a):.6f}\n" for a in t)
    p.write_text("\ufefftime,reference,device\r\n" + rows.replace("\n", "\r\n"))
    fast = load_single_csv(p)
    assert np.array_equal(fast.t_ref, np.round(t, 2)) and fast.x_ref[5] == round(math.sin(0.05), 6)
    # the slow path (no /proc path) gives the same arrays
    monkeypatch.setattr(InputFile, "reopened", lambda self: None)
    slow = load_single_csv(p)
    for a, b in ((fast.t_ref, slow.t_ref), (fast.x_ref, slow.x_ref), (fast.y_dev, slow.y_dev)):
        assert np.array_equal(a, b)
    monkeypatch.undo()
    # changed after the read: unchanged() says so, and the bytes read are what is parsed
    with input_file(p, "CSV file", DataError, 1 << 20) as f:
        assert f.reopened() is not None and f.unchanged()
        with p.open("a") as fh:
            fh.write("20.00,1.0,1.0\r\n")
        assert not f.unchanged()
        cols = inputs._columns(p, f.data, [("time", "--time-col"), ("device", "--device-col")], f)
    assert len(cols[0]) == 2000 and np.array_equal(cols[1], slow.y_dev)
