"""A register map read from its YAML file (``drivers/*.yaml``) and validated.

Every key of the file is checked for its type and range, the fields' addresses for overlaps and
the spans read or written in one request against the map's request limits, before a
:class:`~benchctl.devices.modbus.regmap.RegisterMap` is built; a bad file raises ``ConfigError``
naming the file, the field, the value and what was expected. What the map then means (the fields,
their encoding to register words) is ``regmap``'s.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from benchctl.devices.modbus.regmap import (
    WORDS_OF_TYPE,
    AxisMap,
    Field,
    RegisterMap,
    TableLayout,
    TrajectoryMap,
)
from benchctl.errors import ConfigError
from benchctl.yamlfile import read_yaml

_STATUS_BITS = ("ready", "enabled", "moving", "fault", "estop", "limit", "table_running")
_CONTROL_BITS = ("enable", "start_table", "stop", "fault_reset", "estop")
# bits a map only has when the stand has a trajectory queue (``trajectory:`` section)
_STATUS_BITS_TRAJ = ("trajectory_running",)
_CONTROL_BITS_TRAJ = ("start_trajectory",)
_TRAJ_FIELDS = ("level", "next_index", "played", "underruns")
_AXIS_FIELDS = ("angle", "rate", "setpoint", "fault_code", "command")


class _Loader:
    def __init__(self, source: Path) -> None:
        self.source = source

    def fail(self, where: str, value: object, expected: str) -> ConfigError:
        return ConfigError(f"{self.source}: field {where} = {value!r}: expected {expected}")

    def section(self, data: Mapping[str, Any], key: str, where: str = "") -> Mapping[str, Any]:
        path = f"{where}.{key}" if where else key
        value = data.get(key)
        if not isinstance(value, Mapping):
            raise self.fail(path, value, "a mapping")
        return value

    def integer(self, data: Mapping[str, Any], key: str, where: str, lo: int, hi: int) -> int:
        value = data.get(key)
        if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
            raise self.fail(f"{where}.{key}", value, f"an integer {lo}..{hi}")
        return value

    def field(
        self, data: Any, where: str, *, offset_key: str = "address", writable: bool = False
    ) -> Field:
        if not isinstance(data, Mapping):
            raise self.fail(where, data, "a mapping with address and type")
        known = {offset_key, "type", "scale", "offset", "length", "access", "unit"}
        for k in data:
            if k not in known:
                raise self.fail(f"{where}.{k}", data[k], f"one of the keys {sorted(known)}")
        address = self.integer(data, offset_key, where, 0, 0xFFFF)
        ftype = data.get("type")
        if ftype not in (*WORDS_OF_TYPE, "string"):
            raise self.fail(f"{where}.type", ftype, f"one of {[*WORDS_OF_TYPE, 'string']}")
        length = 0
        if ftype == "string":
            length = self.integer(data, "length", where, 1, 250)
        scale = data.get("scale", 1.0)
        offset = data.get("offset", 0.0)
        if (
            not isinstance(scale, int | float)
            or isinstance(scale, bool)
            or scale == 0
            or not math.isfinite(scale)
        ):
            raise self.fail(f"{where}.scale", scale, "a finite non-zero number")
        if (
            not isinstance(offset, int | float)
            or isinstance(offset, bool)
            or not math.isfinite(offset)
        ):
            raise self.fail(f"{where}.offset", offset, "a finite number")
        access = data.get("access", "r")
        if access not in ("r", "rw"):
            raise self.fail(f"{where}.access", access, "r or rw")
        if writable and access != "rw":
            raise self.fail(f"{where}.access", access, "rw (the host writes this register)")
        return Field(where, address, ftype, float(scale), float(offset), length, access == "rw")

    def bits(
        self,
        data: Mapping[str, Any],
        key: str,
        names: Sequence[str],
        optional: Sequence[str] = (),
    ) -> dict[str, int]:
        sec = self.section(data, key)
        out: dict[str, int] = {}
        for n in names:
            out[n] = self.integer(sec, n, key, 0, 15)
        for n in optional:
            if n in sec:
                out[n] = self.integer(sec, n, key, 0, 15)
        extra = set(sec) - set(names) - set(optional)
        if extra:
            raise self.fail(
                f"{key}.{sorted(extra)[0]}", sec[sorted(extra)[0]], f"one of {list(names)}"
            )
        if len(set(out.values())) != len(out):
            raise self.fail(key, dict(sec), "distinct bit numbers")
        return out


def load_register_map(path: str | Path) -> RegisterMap:
    """Read and validate a register-map YAML file (see ``drivers/stand_generic.yaml``).

    Raises
    ------
    ConfigError
        Naming the file, the field, the value and what was expected.
    """
    source = Path(path)
    data = read_yaml(source, "register map")  # the one YAML reader and its rules
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: expected a YAML mapping at the top level")
    return parse_register_map(data, source)


def parse_register_map(data: Mapping[str, Any], source: Path) -> RegisterMap:
    """Validate a register map already parsed from YAML (``source`` names it in errors)."""
    ld = _Loader(source)
    word_order = data.get("word_order", "big")
    if word_order not in ("big", "little"):
        raise ld.fail("word_order", word_order, "big or little")
    max_read = ld.integer(
        {"v": data.get("max_read_registers", 125)}, "v", "max_read_registers", 8, 125
    )
    max_write = ld.integer(
        {"v": data.get("max_write_registers", 123)}, "v", "max_write_registers", 8, 123
    )

    rwm = data.get("read_write_multiple", False)
    if not isinstance(rwm, bool):
        raise ld.fail("read_write_multiple", rwm, "true or false")

    ident_sec = ld.section(data, "identity")
    identity = {k: ld.field(v, f"identity.{k}") for k, v in ident_sec.items()}
    for k in ("vendor", "model"):
        if k not in identity:
            raise ld.fail(f"identity.{k}", None, "a field (vendor and model are required)")

    ctl = ld.section(data, "control")
    st = ld.section(data, "status")
    fault_codes_raw = data.get("fault_codes", {})
    if not isinstance(fault_codes_raw, Mapping):
        raise ld.fail("fault_codes", fault_codes_raw, "a mapping code: text")
    axes_sec = ld.section(data, "axes")
    axes: dict[str, AxisMap] = {}
    for name, ax in axes_sec.items():
        if name not in ("roll", "pitch"):
            raise ld.fail(f"axes.{name}", ax, "axes named roll and/or pitch")
        if not isinstance(ax, Mapping):
            raise ld.fail(f"axes.{name}", ax, "a mapping")
        f = {
            k: ld.field(ax.get(k), f"axes.{name}.{k}", writable=(k == "command"))
            for k in _AXIS_FIELDS
        }
        tab = ld.section(ax, "table", f"axes.{name}")
        axes[name] = AxisMap(
            **f,
            table_address=ld.integer(tab, "address", f"axes.{name}.table", 0, 0xFFFF),
            table_max_lines=ld.integer(tab, "max_lines", f"axes.{name}.table", 1, 1000),
        )
    if not axes:
        raise ld.fail("axes", dict(axes_sec), "at least one axis (roll, pitch)")

    lay = ld.section(data, "table_layout")
    line = ld.section(lay, "line", "table_layout")
    table = TableLayout(
        **{
            k: ld.field(lay.get(k), f"table_layout.{k}", offset_key="offset")
            for k in ("n_lines", "duration_s", "fade_in_s", "fade_out_s")
        },
        lines_offset=ld.integer(lay, "lines_offset", "table_layout", 0, 1000),
        line_stride=ld.integer(lay, "line_stride", "table_layout", 1, 100),
        **{
            k: ld.field(line.get(k), f"table_layout.line.{k}", offset_key="offset")
            for k in ("freq_hz", "amp_deg", "phase_rad")
        },
    )
    rmap = RegisterMap(
        source=source,
        name=str(data.get("name", source.stem)),
        word_order=word_order,
        max_read=max_read,
        max_write=max_write,
        read_write_multiple=rwm,
        identity=identity,
        control_word=ld.field(ctl.get("control_word"), "control.control_word", writable=True),
        heartbeat=ld.field(ctl.get("heartbeat"), "control.heartbeat", writable=True),
        status_word=ld.field(st.get("status_word"), "status.status_word"),
        fault_code=ld.field(st.get("fault_code"), "status.fault_code"),
        heartbeat_echo=ld.field(st.get("heartbeat_echo"), "status.heartbeat_echo"),
        control_bits=ld.bits(data, "control_bits", _CONTROL_BITS, _CONTROL_BITS_TRAJ),
        status_bits=ld.bits(data, "status_bits", _STATUS_BITS, _STATUS_BITS_TRAJ),
        fault_codes={int(k): str(v) for k, v in fault_codes_raw.items()},
        axes=axes,
        table=table,
        trajectory=_trajectory(ld, data, len(axes), max_write),
        sample_time=(None if st.get("sample_time") is None
                     else ld.field(st.get("sample_time"), "status.sample_time")),
    )
    stime = rmap.sample_time
    if stime is not None and (stime.type not in ("uint16", "uint32") or stime.offset != 0
                              or not stime.scale > 0):
        raise ld.fail("status.sample_time", f"{stime.type}, scale {stime.scale}, offset "
                      f"{stime.offset}", "uint16 or uint32 with a positive scale (s) and no offset")
    if rmap.trajectory is not None:
        for bits, names in (
            (rmap.control_bits, _CONTROL_BITS_TRAJ),
            (rmap.status_bits, _STATUS_BITS_TRAJ),
        ):
            missing = [n for n in names if n not in bits]
            if missing:
                raise ld.fail(
                    "control_bits/status_bits", missing[0], "a bit for it (the map has trajectory)"
                )
    _check_layout(ld, rmap)
    return rmap


def _trajectory(
    ld: _Loader, data: Mapping[str, Any], n_axes: int, max_write: int
) -> TrajectoryMap | None:
    """The optional ``trajectory:`` section (a buffered trajectory queue)."""
    if "trajectory" not in data:
        return None
    sec = ld.section(data, "trajectory")
    known = {"capacity", "max_points_per_push", "push", "period_s", *_TRAJ_FIELDS}
    for k in sec:
        if k not in known:
            raise ld.fail(f"trajectory.{k}", sec[k], f"one of the keys {sorted(known)}")
    push = ld.section(sec, "push", "trajectory")
    fits = (max_write - 3) // (2 * n_axes)
    tr = TrajectoryMap(
        capacity=ld.integer(sec, "capacity", "trajectory", 4, 65535),
        max_points_per_push=ld.integer(sec, "max_points_per_push", "trajectory", 1, max(1, fits)),
        push_address=ld.integer(push, "address", "trajectory.push", 0, 0xFFFF),
        period_s=ld.field(sec.get("period_s"), "trajectory.period_s", writable=True),
        **{k: ld.field(sec.get(k), f"trajectory.{k}") for k in _TRAJ_FIELDS},
    )
    for f in (tr.level, tr.underruns):
        if f.type != "uint16":
            raise ld.fail(f"{f.name}.type", f.type, "uint16")
    for f in (tr.next_index, tr.played):
        if f.type != "uint32":
            raise ld.fail(f"{f.name}.type", f.type, "uint32")
    if tr.period_s.type != "float32":
        raise ld.fail("trajectory.period_s.type", tr.period_s.type, "float32")
    return tr


def _check_layout(ld: _Loader, m: RegisterMap) -> None:
    """No two fields overlap; spans read or written in one request fit the request limits."""
    for f in (m.control_word, m.heartbeat, m.status_word, m.fault_code, m.heartbeat_echo):
        if f.type not in ("uint16", "int16"):
            raise ld.fail(f"{f.name}.type", f.type, "uint16 (a 16-bit word)")
    line_fields = (m.table.freq_hz, m.table.amp_deg, m.table.phase_rad)
    for lf in line_fields:
        if lf.address + lf.n_registers > m.table.line_stride:
            raise ld.fail(
                f"{lf.name}.offset", lf.address, f"a field inside line_stride {m.table.line_stride}"
            )
    taken: list[tuple[int, int, str]] = []
    fields: list[Field] = [*m.identity.values(), m.control_word, m.heartbeat, *m.feedback_fields()]
    fields += [ax.command for ax in m.axes.values()]
    tr = m.trajectory
    if tr is not None:
        fields.append(tr.period_s)
        n = tr.push_size(len(m.axes), tr.max_points_per_push)
        taken.append((tr.push_address, tr.push_address + n, "trajectory.push"))
    for f in fields:
        taken.append((f.address, f.address + f.n_registers, f.name))
    for name, ax in m.axes.items():
        taken.append(
            (
                ax.table_address,
                ax.table_address + m.table.size(ax.table_max_lines),
                f"axes.{name}.table",
            )
        )
    taken.sort()
    for (a0, a1, n0), (b0, _b1, n1) in itertools.pairwise(taken):
        if b0 < a1:
            raise ld.fail(n1, b0, f"an address not overlapping {n0} ({a0}..{a1 - 1})")
    if taken[-1][1] > 0x10000:
        raise ld.fail(taken[-1][2], taken[-1][0], "a span ending within 0..65535")
    _, count = m.feedback_span()
    if count > m.max_read:
        raise ld.fail(
            "status/axes", count, f"a feedback span of at most max_read_registers={m.max_read}"
        )


__all__ = ["load_register_map", "parse_register_map"]
