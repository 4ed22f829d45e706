"""Register map: loading, validation messages, and encodings checked against hand-made words."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import pytest
import yaml
from repo_paths import ROOT

from benchctl.devices.modbus.regmap import Field, pdu_address
from benchctl.devices.modbus.regmap_load import load_register_map, parse_register_map
from benchctl.errors import ConfigError, LimitError

MAP = ROOT / "drivers" / "stand_generic.yaml"


@pytest.fixture
def raw() -> dict[str, Any]:
    return yaml.safe_load(MAP.read_text())


def test_generic_map_loads_with_contiguous_feedback() -> None:
    m = load_register_map(MAP)
    assert set(m.axes) == {"roll", "pitch"}
    assert m.feedback_span() == (200, 26)  # 200..225: one FC3 read per cycle
    assert m.command_span(["roll", "pitch"]) == (300, 4)  # one FC16 write per setpoint
    assert m.control_bits == {
        "enable": 0,
        "start_table": 1,
        "stop": 2,
        "fault_reset": 3,
        "estop": 4,
        "start_trajectory": 5,
    }
    assert m.table_field("pitch", "freq_hz", 2).address == 2000 + 10 + 2 * 6
    tr = m.trajectory
    assert tr is not None and tr.capacity == 512 and tr.max_points_per_push == 24
    # a push of the most points fits one FC16 / FC23 write
    assert tr.push_size(len(m.axes), tr.max_points_per_push) == 99 <= m.max_write


def test_map_without_trajectory_section_and_a_bad_one(raw: dict[str, Any], tmp_path: Path) -> None:
    from benchctl.devices.modbus.regmap_load import parse_register_map

    plain = {k: v for k, v in raw.items() if k != "trajectory"}
    cb, sb = raw["control_bits"], raw["status_bits"]
    plain["control_bits"] = {k: v for k, v in cb.items() if k != "start_trajectory"}
    plain["status_bits"] = {k: v for k, v in sb.items() if k != "trajectory_running"}
    m = parse_register_map(plain, tmp_path / "plain.yaml")
    assert m.trajectory is None and m.feedback_span() == (200, 19)
    bad = dict(raw, trajectory={**raw["trajectory"], "max_points_per_push": 40})
    with pytest.raises(ConfigError, match=r"trajectory\.max_points_per_push"):
        parse_register_map(bad, tmp_path / "bad.yaml")
    nobit = dict(raw, control_bits=plain["control_bits"])
    with pytest.raises(ConfigError, match="start_trajectory"):
        parse_register_map(nobit, tmp_path / "nobit.yaml")


@pytest.mark.parametrize(
    ("ftype", "word_order", "value", "words"),
    [
        ("float32", "big", 1.0, [0x3F80, 0x0000]),
        ("float32", "little", 1.0, [0x0000, 0x3F80]),
        ("float32", "big", -2.0, [0xC000, 0x0000]),
        ("uint16", "big", 513, [0x0201]),
        ("int16", "big", -1, [0xFFFF]),
        ("int32", "big", -2, [0xFFFF, 0xFFFE]),
        ("uint32", "little", 0x12345678, [0x5678, 0x1234]),
    ],
)
def test_encode_decode_words(
    raw: dict[str, Any], ftype: str, word_order: str, value: float, words: list[int]
) -> None:
    raw["word_order"] = word_order
    m = parse_register_map(raw, MAP)
    f = Field("x", 0, ftype)  # type: ignore[arg-type]
    assert m.encode(f, value) == words
    assert m.decode(f, words) == value


@pytest.mark.parametrize("word_order", ["big", "little"])
def test_block_decoder_gives_decode_in_values(raw: dict[str, Any], word_order: str) -> None:
    """The feedback block decoded at once: the values decode_in gives, field by field, for
    every type, scale and offset, signs and special floats included."""
    import random

    raw["word_order"] = word_order
    m = parse_register_map(raw, MAP)
    addr, count = m.feedback_span()
    extra = [Field("u", 1, "uint16", scale=0.5, offset=-3.0), Field("i", 3, "int32"),
             Field("w", 6, "uint32", scale=1e-3), Field("h", 8, "int16", offset=0.25),
             Field("f", 10, "float32")]  # gaps between them; and overlapping ones
    rng = random.Random(1)
    for fields, at, n in ((m.feedback_fields(), addr, count), (extra, 0, 12),
                          ([*extra, Field("o", 4, "uint16")], 0, 12)):
        dec = m.block_decoder(fields, at, n)
        for block in ([0] * n, [0xFFFF] * n, ([0x7FC0, 0, 0x8000, 0] * n)[:n],
                      *([rng.randrange(0x10000) for _ in range(n)] for _ in range(200))):
            got = dec(block)
            want = [float(m.decode_in(f, at, block)) for f in fields]
            assert [repr(v) for v in got] == [repr(v) for v in want]
            assert all(math.copysign(1, g) == math.copysign(1, w)
                       for g, w in zip(got, want, strict=True))
    with pytest.raises(ValueError, match="outside the block"):
        m.block_decoder([Field("far", addr + count, "uint16")], addr, count)


@pytest.mark.parametrize("word_order", ["big", "little"])
def test_block_encoder_writes_what_encode_writes(raw: dict[str, Any], word_order: str) -> None:
    """The feedback fields put at once: the words encode puts field by field, and on a value
    encode refuses, its error with the fields before it written."""
    import random

    raw["word_order"] = word_order
    m = parse_register_map(raw, MAP)
    rng = random.Random(2)
    for fields in (m.feedback_fields()[::-1],
                   [Field("u", 0, "uint16"), Field("h", 2, "int16", scale=0.01, offset=1.0)]):
        addr = min(f.address for f in fields) - 3
        enc = m.block_encoder(fields, addr)
        for trial in range(300):
            values: list[float] = []
            for f in fields:
                v = {"uint16": rng.randrange(0x10000), "int16": rng.uniform(-300, 300),
                     "uint32": rng.randrange(1 << 32), "int32": rng.randrange(-1 << 31, 1 << 31),
                     "float32": rng.uniform(-1e3, 1e3)}[f.type]
                if trial % 7 == 0 and rng.random() < 0.2:
                    v = rng.choice([math.nan, math.inf, 1e39, -70000, 1 << 33])
                values.append(v)
            got, want = [9] * 40, [9] * 40
            err_got = err_want = None
            try:
                enc(got, values)
            except (LimitError, OverflowError) as e:
                err_got = repr(e)
            try:
                for f, v in zip(fields, values, strict=True):
                    i = f.address - addr
                    want[i : i + f.n_registers] = m.encode(f, v)
            except (LimitError, OverflowError) as e:
                err_want = repr(e)
            assert (got, err_got) == (want, err_want)


def test_scaled_integer_and_string(raw: dict[str, Any]) -> None:
    m = parse_register_map(raw, MAP)
    f = Field("angle", 0, "int32", scale=0.001)
    assert m.encode(f, 12.345) == [0x0000, 0x3039]  # 12345 counts of 0.001°
    assert m.decode(f, [0xFFFF, 0xCFC7]) == pytest.approx(-12.345, abs=1e-12)
    s = Field("vendor", 0, "string", length=5)
    assert m.encode(s, "ACME") == [0x4143, 0x4D45, 0x0000]
    assert m.decode(s, [0x4143, 0x4D45, 0x0000]) == "ACME"


def test_out_of_range_values_raise_limit_error(raw: dict[str, Any]) -> None:
    m = parse_register_map(raw, MAP)
    with pytest.raises(LimitError, match="outside int16 range"):
        m.encode(Field("a", 0, "int16", scale=0.01), 400.0)
    with pytest.raises(LimitError, match="not finite"):
        m.encode(Field("a", 0, "float32"), float("nan"))


def test_pdu_address_is_the_map_address_in_range() -> None:
    assert pdu_address(0) == 0
    assert pdu_address(65535) == 65535
    with pytest.raises(ValueError):
        pdu_address(65536)


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        (lambda d: d["axes"]["roll"]["angle"].update(type="float64"), "axes.roll.angle.type"),
        (lambda d: d["axes"]["roll"]["angle"].update(address=202), "axes.roll.angle"),  # overlap
        (lambda d: d["axes"]["roll"].pop("rate"), "axes.roll.rate"),
        (lambda d: d["axes"]["roll"]["command"].update(access="r"), "axes.roll.command.access"),
        (lambda d: d["status_bits"].update(limit=3), "status_bits"),  # same bit as fault
        (lambda d: d.update(word_order="middle"), "word_order"),
        (lambda d: d["axes"].update(yaw=d["axes"]["roll"]), "axes.yaw"),
        (lambda d: d["axes"]["pitch"]["table"].update(address=1100), "axes.pitch.table"),
    ],
)
def test_bad_maps_name_file_and_field(raw: dict[str, Any], edit: Any, field: str) -> None:
    data = copy.deepcopy(raw)
    edit(data)
    with pytest.raises(ConfigError) as err:
        parse_register_map(data, MAP)
    assert str(MAP) in str(err.value)
    assert field in str(err.value)


def test_missing_file_is_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read register map"):
        load_register_map(tmp_path / "nope.yaml")
