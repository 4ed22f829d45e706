"""Property tests of the input edges: any bytes as a CSV give a result or a ``DataError``,
any text as a bench config (or a profile) gives a valid config or a ``ConfigError``; never
another exception, and each within a bounded time."""

from __future__ import annotations

import contextlib
import copy
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from repo_paths import ROOT

from benchctl.analysis import analyze
from benchctl.analysis.inputs import load_csv_pair, load_single_csv
from benchctl.config import load_config
from benchctl.errors import ConfigError, DataError, InputError
from benchctl.profiles import load_profile

BOUND_S = 20.0  # per example: generous (a bad gap once meant minutes, or a hang)
SETTINGS = settings(
    max_examples=100,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
HEADER = b"time,reference,device\n"


def _analyse_file(path: Path) -> None:
    """Load and analyse; only a result or a DataError (naming the file when it is the file's
    fault) may come out."""
    t0 = time.monotonic()
    try:
        s = load_single_csv(path)
    except DataError as e:
        assert str(path) in str(e) and "\n" not in str(e), str(e)
    else:
        try:
            r = analyze(s.t_ref, s.x_ref, s.t_dev, s.y_dev)
        except DataError as e:
            assert "\n" not in str(e), str(e)
        else:
            assert r.n_samples >= 64
            r.to_dict()
    assert time.monotonic() - t0 < BOUND_S


numbers = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 5e-324, -5e-324, 1e308, -1e308, 2.2250738585072014e-308, 1e-300]),
    st.integers(min_value=-(10**20), max_value=10**20).map(float),
)
cells = st.one_of(
    numbers.map(repr),
    st.sampled_from(["", " ", "nan", "inf", "-inf", "1e999", "0x10", "1,5", '"1"', "#", "1e"]),
    st.text(max_size=6),
)


@SETTINGS
@given(payload=st.binary(max_size=3000))
def test_any_bytes(tmp_path: Path, payload: bytes) -> None:
    f = tmp_path / "any.csv"
    f.write_bytes(payload)
    _analyse_file(f)


@SETTINGS
@given(body=st.binary(max_size=3000))
def test_any_bytes_after_a_good_header(tmp_path: Path, body: bytes) -> None:
    f = tmp_path / "hdr.csv"
    f.write_bytes(HEADER + body)
    _analyse_file(f)


@st.composite
def near_good_csv(draw: st.DrawFn) -> bytes:
    """A plausible CSV (64–400 rows, a sine seen through a gain) with odd numbers, gaps,
    odd cells and odd bytes put in at random places."""
    n = draw(st.integers(64, 400))
    dt = draw(st.sampled_from([0.01, 0.05, 1e-7, 5e-324, 1e5, 1e7]))
    t = np.arange(n) * dt + draw(st.sampled_from([0.0, -0.0, 1e9, 1e12, -1e13]))
    x = 5.0 * np.sin(2 * np.pi * 0.2 * np.arange(n) * 0.05)
    y = 0.98 * x + 0.01 * np.cos(np.arange(n) * 1.3)
    rows = [[repr(float(a)), repr(float(b)), repr(float(c))] for a, b, c in zip(t, x, y,
                                                                                strict=True)]
    for _ in range(draw(st.integers(0, 4))):
        i, j = draw(st.integers(0, n - 1)), draw(st.integers(0, 2))
        rows[i][j] = draw(cells)
    for _ in range(draw(st.integers(0, 2))):  # a gap: every later time shifted
        i, gap = draw(st.integers(1, n - 1)), draw(numbers)
        for k in range(i, n):
            with contextlib.suppress(ValueError):
                rows[k][0] = repr(float(rows[k][0]) + gap)
    data = HEADER + "".join(",".join(r) + "\n" for r in rows).encode()
    for _ in range(draw(st.integers(0, 2))):
        at = draw(st.integers(0, len(data)))
        data = data[:at] + draw(st.binary(min_size=1, max_size=3)) + data[at:]
    return data


@SETTINGS
@given(payload=near_good_csv())
def test_near_good_csv(tmp_path: Path, payload: bytes) -> None:
    f = tmp_path / "near.csv"
    f.write_bytes(payload)
    _analyse_file(f)


@SETTINGS
@given(ref=near_good_csv(), dev=near_good_csv())
def test_two_csvs(tmp_path: Path, ref: bytes, dev: bytes) -> None:
    r, d = tmp_path / "ref.csv", tmp_path / "dev.csv"
    r.write_bytes(ref)
    d.write_bytes(dev)
    t0 = time.monotonic()
    try:
        s = load_csv_pair(r, d, reference_col="reference", device_col="device")
        analyze(s.t_ref, s.x_ref, s.t_dev, s.y_dev, compensate_delay="auto")
    except DataError as e:
        assert "\n" not in str(e), str(e)
    assert time.monotonic() - t0 < BOUND_S


@SETTINGS
@given(
    t=st.lists(numbers, min_size=64, max_size=200),
    x=st.lists(numbers, min_size=64, max_size=200),
)
def test_api_arrays(t: list[float], x: list[float]) -> None:
    """``analyze`` on arbitrary arrays (a recording's streams come this way)."""
    n = min(len(t), len(x))
    tt, xx = np.array(t[:n]), np.array(x[:n])
    t0 = time.monotonic()
    for times in (tt, np.sort(tt), np.cumsum(np.abs(tt))):
        with contextlib.suppress(DataError):
            analyze(times, xx, times, 0.9 * xx)
    assert time.monotonic() - t0 < BOUND_S


# -- YAML -----------------------------------------------------------------------------------

GOOD = yaml.safe_load((ROOT / "config" / "sim.yaml").read_text())
for _k in ("register_map", "eds", "dbc"):
    for _s in ("stand", "instrument"):
        if _k in GOOD[_s]:
            GOOD[_s][_k] = str((ROOT / "config" / GOOD[_s][_k]).resolve())


def _load(path: Path) -> None:
    t0 = time.monotonic()
    try:
        cfg = load_config(path)
    except ConfigError as e:
        assert "\n" not in str(e), str(e)
    else:
        for v in _numbers(cfg.model_dump()):
            assert math.isfinite(v), cfg
    assert time.monotonic() - t0 < BOUND_S


def _numbers(obj: Any) -> list[float]:
    if isinstance(obj, bool):
        return []
    if isinstance(obj, int | float):
        return [float(obj)]
    if isinstance(obj, dict):
        return [v for x in obj.values() for v in _numbers(x)]
    if isinstance(obj, list | tuple):
        return [v for x in obj for v in _numbers(x)]
    return []


@SETTINGS
@given(text=st.text(max_size=2000))
def test_any_text_as_a_config(tmp_path: Path, text: str) -> None:
    f = tmp_path / "any.yaml"
    f.write_text(text, encoding="utf-8")
    _load(f)


@SETTINGS
@given(payload=st.binary(max_size=2000))
def test_any_bytes_as_a_config(tmp_path: Path, payload: bytes) -> None:
    f = tmp_path / "any.yaml"
    f.write_bytes(payload)
    _load(f)


yaml_tokens = st.sampled_from([
    "a", "b", "port", "stand", ":", ": ", "- ", "\n", "\n  ", "  ", "[", "]", "{", "}", ", ",
    "&x ", "*x", "&y ", "*y", "<<: ", "!!int ", "!!float ", "!!str ", "!!binary ", "!!set ",
    "? ", "|", ">", "'", '"', "#", "---\n", "...", "30:00", "010", "0x_", ".inf", ".nan", "1e5",
    "2001-13-45", "~", "null", "yes", "\t", "%YAML 1.1\n", "\ufeff", "\x85", "\u2028",
])


@SETTINGS
@given(parts=st.lists(yaml_tokens, max_size=80))
def test_yaml_shaped_text(tmp_path: Path, parts: list[str]) -> None:
    f = tmp_path / "tok.yaml"
    f.write_text("".join(parts), encoding="utf-8")
    _load(f)


values = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=10),
    st.lists(st.floats(allow_nan=True), max_size=3),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
)


def _paths(obj: Any, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = [prefix] if prefix else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, (*prefix, k))
    return out


CONFIG_PATHS = [*_paths(GOOD), ("sim", "faults"), ("sim", "stand", "faults")]


@SETTINGS
@given(
    changes=st.lists(st.tuples(st.sampled_from(CONFIG_PATHS), values), min_size=1, max_size=4),
    faults=st.lists(
        st.fixed_dictionaries(
            {"target": st.sampled_from(["stand", "instrument", "x"]),
             "kind": st.sampled_from(["stall", "garbled", "estop", "silent", "drop", "stal"])},
            optional={"params": st.dictionaries(
                st.sampled_from(["code", "duration_s", "count", "fraction", "how", "x"]),
                st.one_of(values, st.sampled_from(["length", "checksum", "bytes"])),
                max_size=3)},
        ),
        max_size=3,
    ),
)
def test_mutated_config(
    tmp_path: Path, changes: list[tuple[tuple[str, ...], Any]], faults: list[dict[str, Any]]
) -> None:
    data = copy.deepcopy(GOOD)
    data["sim"]["faults"] = faults
    for path, value in changes:
        node = data
        for k in path[:-1]:
            if not isinstance(node.get(k), dict):
                node[k] = {}
            node = node[k]
        node[path[-1]] = value
    f = tmp_path / "mut.yaml"
    f.write_text(yaml.safe_dump(data, allow_unicode=True), encoding="utf-8")
    _load(f)


PROFILES = sorted((ROOT / "profiles").glob("*.yaml"))


@SETTINGS
@given(
    which=st.sampled_from(PROFILES),
    changes=st.lists(st.tuples(st.text(min_size=1, max_size=1), values), max_size=4),
    picks=st.lists(st.integers(0, 10_000), min_size=4, max_size=4),
)
def test_mutated_profile(
    tmp_path: Path, which: Path, changes: list[tuple[str, Any]], picks: list[int]
) -> None:
    data = yaml.safe_load(which.read_text())
    paths = _paths(data)
    for (_, value), pick in zip(changes, picks, strict=False):
        path = paths[pick % len(paths)]
        node = data
        for k in path[:-1]:  # an earlier change may have replaced part of the path
            node = node.get(k) if isinstance(node, dict) else None
        if isinstance(node, dict):
            node[path[-1]] = value
    f = tmp_path / which.name
    f.write_text(yaml.safe_dump(data, allow_unicode=True), encoding="utf-8")
    if (which.parent / "records").is_dir():
        (tmp_path / "records").mkdir(exist_ok=True)
        for rec in (which.parent / "records").iterdir():
            (tmp_path / "records" / rec.name).write_bytes(rec.read_bytes())
    t0 = time.monotonic()
    try:
        load_profile(f)
    except InputError as e:  # ConfigError, or a DataError of a recorded CSV
        assert "\n" not in str(e), str(e)
    assert time.monotonic() - t0 < BOUND_S


@pytest.mark.parametrize("name", [p.name for p in PROFILES])
def test_library_profiles_still_load(name: str) -> None:
    load_profile(ROOT / "profiles" / name)
