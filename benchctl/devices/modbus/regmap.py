"""A stand's Modbus register map: its fields, and their values to and from register words.

Pure data and conversions, no I/O (the map is read from YAML in ``drivers/`` and validated by
``regmap_load``). Addresses in the map are 0-based
protocol (PDU) addresses; :func:`pdu_address` is the one place a map address becomes a wire
address. Values are encoded to and decoded from 16-bit register words here, so the driver
(client side) and the simulated stand (server side) agree to the bit.

Engineering value = raw × scale + offset. 32-bit types follow the map's ``word_order``; bytes
within a register are big-endian (Modbus). Strings hold two characters per register, the
first in the high byte, NUL padded.
"""

from __future__ import annotations

import functools
import math
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from benchctl.errors import LimitError

FieldType = Literal["uint16", "int16", "uint32", "int32", "float32", "string"]
WORDS_OF_TYPE: dict[str, int] = {"uint16": 1, "int16": 1, "uint32": 2, "int32": 2, "float32": 2}
_INT_RANGE: dict[str, tuple[int, int]] = {
    "uint16": (0, 0xFFFF),
    "int16": (-0x8000, 0x7FFF),
    "uint32": (0, 0xFFFFFFFF),
    "int32": (-0x80000000, 0x7FFFFFFF),
}
_FLOAT32_MAX = 3.4028234663852886e38
_PACK_F = struct.Struct(">f").pack
_UNPACK_F = struct.Struct(">f").unpack
_PACK_HH = struct.Struct(">HH").pack
_UNPACK_HH = struct.Struct(">HH").unpack
#: a numeric field's raw value as one struct code (big word order, big-endian bytes)
_STRUCT_CODES = {"uint16": "H", "int16": "h", "uint32": "I", "int32": "i", "float32": "f"}


def pdu_address(map_address: int) -> int:
    """The protocol (PDU) address of a register-map address.

    The map is written in 0-based PDU addresses, so this is the identity, checked to lie in
    0…65535. It is the one named place where a map address becomes a wire address: a map in
    another numbering would be converted here and nowhere else.
    """
    if not 0 <= map_address <= 0xFFFF:
        raise ValueError(f"Modbus address must be 0..65535, got {map_address}")
    return map_address


@dataclass(frozen=True)
class Field:
    """One value in the register map: where it lives and how it is encoded."""

    name: str  # dotted path in the map file, for messages
    address: int  # 0-based PDU address of the first register
    type: FieldType
    scale: float = 1.0
    offset: float = 0.0
    length: int = 0  # strings: characters
    writable: bool = False

    @functools.cached_property
    def n_registers(self) -> int:
        return (self.length + 1) // 2 if self.type == "string" else WORDS_OF_TYPE[self.type]

    def shifted(self, base: int, name: str) -> Field:
        """The same field at ``base`` + its address (table layouts hold offsets)."""
        return Field(
            name,
            base + self.address,
            self.type,
            self.scale,
            self.offset,
            self.length,
            self.writable,
        )


@dataclass(frozen=True)
class AxisMap:
    angle: Field
    rate: Field
    setpoint: Field
    fault_code: Field
    command: Field
    table_address: int
    table_max_lines: int


@dataclass(frozen=True)
class TableLayout:
    n_lines: Field  # addresses here are offsets from an axis's table address
    duration_s: Field
    fade_in_s: Field
    fade_out_s: Field
    lines_offset: int
    line_stride: int
    freq_hz: Field
    amp_deg: Field
    phase_rad: Field

    def size(self, max_lines: int) -> int:
        """Registers spanned by a table area holding ``max_lines`` lines."""
        return self.lines_offset + max_lines * self.line_stride


@dataclass(frozen=True)
class TrajectoryMap:
    """A stand's buffered trajectory queue (PT mode): points sent ahead, played on its clock.

    The host writes a *push* block at ``push_address``: ``first_index`` (uint32), ``count``
    (uint16), then ``count`` points, each one float32 angle per map axis in the map's axis
    order. The stand appends them if ``first_index`` is the index it expects next (else
    exception 3), plays point k at ``start + k·period`` (``period_s`` register, written before
    the start) interpolating linearly, and reports ``level`` (points queued and not yet
    reached), ``next_index``, ``played`` (the index being played) and ``underruns`` in the
    feedback block. A queue that runs dry before its end is an underrun: the stand stops
    within its limits and counts it; a queue ending with its last point repeated is the normal
    end. A push starting at index 0 while the stand is not playing starts a new queue.
    """

    capacity: int
    max_points_per_push: int
    push_address: int
    period_s: Field
    level: Field
    next_index: Field
    played: Field
    underruns: Field

    def push_size(self, n_axes: int, n_points: int) -> int:
        """Registers of a push block carrying ``n_points`` points of ``n_axes`` axes."""
        return 3 + 2 * n_axes * n_points


@dataclass(frozen=True)
class RegisterMap:
    """A validated register map. Build it with ``regmap_load.load_register_map``."""

    source: Path
    name: str
    word_order: Literal["big", "little"]
    max_read: int
    max_write: int
    read_write_multiple: bool  # the stand takes FC23 (write then read in one request)
    identity: dict[str, Field]
    control_word: Field
    heartbeat: Field
    status_word: Field
    fault_code: Field
    heartbeat_echo: Field
    control_bits: dict[str, int]
    status_bits: dict[str, int]
    fault_codes: dict[int, str]
    axes: dict[str, AxisMap]
    table: TableLayout
    trajectory: TrajectoryMap | None = None
    #: the stand's own clock when it took the state a reply carries (optional, status section):
    #: an unsigned count of ``scale`` seconds that wraps (``sample_time_wrap_s``)
    sample_time: Field | None = None

    @property
    def sample_time_wrap_s(self) -> float:
        """Seconds after which ``sample_time`` wraps (NaN without one)."""
        f = self.sample_time
        if f is None:
            return math.nan
        return float(2 ** (16 * f.n_registers)) * f.scale

    # -- encoding -------------------------------------------------------------------------
    def encode(self, field: Field, value: float | int | str) -> list[int]:
        """Register words for ``value`` (engineering units) in ``field``; out of range raises."""
        ftype = field.type
        if ftype == "string":
            return _encode_string(field, str(value))
        v = float(value)
        if not math.isfinite(v):
            raise LimitError(f"{self.source}: {field.name}: value {value!r} is not finite")
        raw = (v - field.offset) / field.scale
        if ftype == "float32":
            if abs(raw) > _FLOAT32_MAX:
                raise LimitError(f"{self.source}: {field.name}: value {value!r} overflows float32")
            words = list(_UNPACK_HH(_PACK_F(raw)))
            return words if self.word_order == "big" else words[::-1]
        n = round(raw)
        lo, hi = _INT_RANGE[ftype]
        if not lo <= n <= hi:
            raise LimitError(
                f"{self.source}: {field.name}: value {value!r} is raw {n}, outside {ftype} "
                f"range {lo}..{hi}"
            )
        if field.n_registers == 1:
            return [n & 0xFFFF]
        return self._order([(n >> 16) & 0xFFFF, n & 0xFFFF])

    def decode(self, field: Field, words: Sequence[int]) -> Any:
        """The engineering value of ``field`` from its register words."""
        if len(words) != field.n_registers:
            raise ValueError(f"{field.name}: need {field.n_registers} registers, got {len(words)}")
        ftype = field.type
        if ftype == "string":
            raw = b"".join(int(w).to_bytes(2, "big") for w in words)
            return raw.rstrip(b"\x00").decode("ascii", errors="replace")
        if ftype == "float32":
            hi, lo = words if self.word_order == "big" else (words[1], words[0])
            raw_f = _UNPACK_F(_PACK_HH(hi, lo))[0]
            return raw_f * field.scale + field.offset
        if field.n_registers == 1:
            n = int(words[0])
            if ftype == "int16" and n >= 0x8000:
                n -= 0x10000
        else:
            hi, lo = self._order(list(words))
            n = (hi << 16) | lo
            if ftype == "int32" and n >= 0x80000000:
                n -= 0x100000000
        if field.scale == 1.0 and field.offset == 0.0:
            return n
        return n * field.scale + field.offset

    def decode_in(self, field: Field, block_address: int, block: Sequence[int]) -> Any:
        """Decode ``field`` out of a block of registers read from ``block_address`` onwards."""
        i = field.address - block_address
        if i < 0 or i + field.n_registers > len(block):
            raise ValueError(f"{field.name} at {field.address} is outside the block read")
        return self.decode(field, block[i : i + field.n_registers])

    def _order(self, words: list[int]) -> list[int]:
        return words if self.word_order == "big" else words[::-1]

    def block_decoder(
        self, fields: Sequence[Field], block_address: int, count: int
    ) -> Callable[[Sequence[int]], list[float]]:
        """A function of a block of ``count`` registers read from ``block_address`` giving
        ``float(decode_in(f, block_address, block))`` for each of ``fields``, in order: the same
        values, with the block's layout worked out once. A field outside the block raises
        ``ValueError`` here; a block of another length is decoded field by field."""
        for f in fields:
            i = f.address - block_address
            if i < 0 or i + f.n_registers > count:
                raise ValueError(f"{f.name} at {f.address} is outside the block read")

        def each(block: Sequence[int]) -> list[float]:
            return [float(self.decode_in(f, block_address, block)) for f in fields]

        # one struct for the whole block: each field's raw value at its place, pad between
        # (big word order, numeric fields that do not overlap; anything else field by field)
        placed = sorted(range(len(fields)), key=lambda k: fields[k].address)
        fmt, at = ">", 0
        for k in placed:
            f = fields[k]
            i = f.address - block_address
            if f.type not in _STRUCT_CODES or i < at or self.word_order != "big":
                return each
            fmt += "x" * (2 * (i - at)) + _STRUCT_CODES[f.type]
            at = i + f.n_registers
        raw_of = struct.Struct(fmt).unpack
        words_of = struct.Struct(f">{count}H").pack
        # per field in the caller's order: its index among the raw values, scale, offset and
        # whether decode() returns the raw integer itself
        where = {k: j for j, k in enumerate(placed)}
        plan = [
            (where[k], f.scale, f.offset,
             f.type != "float32" and f.scale == 1.0 and f.offset == 0.0)
            for k, f in enumerate(fields)
        ]

        def fast(block: Sequence[int]) -> list[float]:
            if len(block) != count:
                return each(block)
            try:
                raw = raw_of(words_of(*block))
            except struct.error:  # a word that is no 16-bit register's
                return each(block)
            return [float(raw[j]) if ident else float(raw[j] * scale + offset)
                    for j, scale, offset, ident in plan]

        return fast

    def block_encoder(
        self, fields: Sequence[Field], block_address: int
    ) -> Callable[[list[int], Sequence[float | int]], None]:
        """A function ``(regs, values)`` putting ``encode(f, v)`` of each of ``fields`` with its
        value into ``regs`` (registers from ``block_address`` on) at the field's place, as
        ``regs[i : i + n] = encode(f, v)`` one field after another would: the same words, the
        registers between the fields left as they are, and the same ``LimitError`` (raised
        where ``encode`` raises it, the fields before it written). Numeric fields that do not
        overlap (big word order) are packed with one struct laid out once, the registers
        between them packed back as they are; anything else field by field."""

        def each(regs: list[int], values: Sequence[float | int]) -> None:
            for f, v in zip(fields, values, strict=True):
                i = f.address - block_address
                regs[i : i + f.n_registers] = self.encode(f, v)

        order = sorted(range(len(fields)), key=lambda k: fields[k].address)
        if not fields or self.word_order != "big":
            return each
        first = fields[order[0]].address
        i0 = first - block_address
        if i0 < 0:
            return each
        # in address order: (kind, the caller's index or a kept register's, scale, offset, the
        # integer range); kind 0 an integer field, 1 a float32 field, 2 a register kept
        plan: list[tuple[int, int, float, float, int, int]] = []
        fmt, at = ">", first
        for k in order:
            f = fields[k]
            if f.type not in _STRUCT_CODES or f.address < at:
                return each  # a string, or an overlap
            for gap in range(at, f.address):
                plan.append((2, gap - block_address, 1.0, 0.0, 0, 0))
                fmt += "H"
            lo, hi = _INT_RANGE.get(f.type, (0, 0))
            plan.append((1 if f.type == "float32" else 0, k, f.scale, f.offset, lo, hi))
            fmt += _STRUCT_CODES[f.type]
            at = f.address + f.n_registers
        n = at - first
        pack = struct.Struct(fmt).pack
        words_of = struct.Struct(f">{n}H").unpack
        isfinite = math.isfinite

        def fast(regs: list[int], values: Sequence[float | int]) -> None:
            if len(values) != len(fields) or len(regs) < i0 + n:
                return each(regs, values)
            raws: list[float | int] = []
            for kind, k, scale, offset, lo, hi in plan:
                if kind == 2:
                    raws.append(regs[k])
                    continue
                v = float(values[k])
                if not isfinite(v):
                    return each(regs, values)  # encode's error, the fields before it written
                raw = (v - offset) / scale
                if kind:
                    if not abs(raw) <= _FLOAT32_MAX:
                        return each(regs, values)
                    raws.append(raw)
                else:
                    if not isfinite(raw):
                        return each(regs, values)
                    r = round(raw)
                    if not lo <= r <= hi:
                        return each(regs, values)
                    raws.append(r)
            try:
                words = words_of(pack(*raws))
            except (OverflowError, struct.error):  # float32 rounding to infinity; a kept
                return each(regs, values)  # register that is no 16-bit word
            regs[i0 : i0 + n] = words
            return None

        return fast

    # -- spans ----------------------------------------------------------------------------
    def feedback_fields(self) -> list[Field]:
        """Everything read each cycle: status, fault code, heartbeat echo, per-axis feedback."""
        out = [self.status_word, self.fault_code, self.heartbeat_echo]
        if self.sample_time is not None:
            out.append(self.sample_time)
        for ax in self.axes.values():
            out += [ax.angle, ax.rate, ax.setpoint, ax.fault_code]
        tr = self.trajectory
        if tr is not None:
            out += [tr.level, tr.next_index, tr.played, tr.underruns]
        return out

    def feedback_span(self) -> tuple[int, int]:
        """(address, count) of one read covering every feedback field."""
        return span(self.feedback_fields())

    def command_span(self, axes: Sequence[str]) -> tuple[int, int]:
        return span([self.axes[a].command for a in axes])

    def table_field(self, axis: str, part: str, line: int | None = None) -> Field:
        """Absolute field of a table header part, or of line ``line``'s freq/amp/phase."""
        ax = self.axes[axis]
        layout_field: Field = getattr(self.table, part)
        base = ax.table_address
        if line is not None:
            base += self.table.lines_offset + line * self.table.line_stride
        return layout_field.shifted(base, f"axes.{axis}.table.{part}")

    def status_from_word(self, word: int) -> dict[str, bool]:
        return {name: bool(word >> bit & 1) for name, bit in self.status_bits.items()}

    def word_from_bits(self, bits: Mapping[str, int], names: Sequence[str]) -> int:
        word = 0
        for n in names:
            word |= 1 << bits[n]
        return word


def span(fields: Sequence[Field]) -> tuple[int, int]:
    """(first address, register count) covering all ``fields``."""
    start = min(f.address for f in fields)
    end = max(f.address + f.n_registers for f in fields)
    return start, end - start


def _encode_string(field: Field, text: str) -> list[int]:
    raw = text.encode("ascii", errors="replace")[: field.length]
    raw = raw.ljust(2 * field.n_registers, b"\x00")
    return [int.from_bytes(raw[i : i + 2], "big") for i in range(0, len(raw), 2)]
