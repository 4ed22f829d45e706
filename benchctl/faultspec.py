"""The simulators' fault kinds and their parameters, as pydantic models.

One model per kind of fault (``StallParams``, ``GarbledParams``, …) holds the parameters that
kind takes: their types, ranges and meanings. The bench config's validator (``sim.faults``,
``sim.stand.faults``) and ``SimStand.inject`` / ``SimInstrument.inject`` all check against
them (:func:`check_params`), so a misspelt kind or parameter is refused when the config is
loaded, before anything starts; the bench config's JSON Schema carries them, so an editor
offers a kind's parameters.

To add a kind, a parameter or a way of garbling: add a model to ``STAND`` or ``INSTRUMENT``, or
a way to ``GARBLING`` below (and implement it in the simulator). Nothing else needs to change.

Pure data and checks: no simulator imports (``benchctl.config`` imports this module).
"""

from __future__ import annotations

import types
import typing
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import annotated_types
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from pydantic.fields import FieldInfo

from benchctl.validation import shown_value

MAX_FAULT_S = 86400.0  # durations and delays of faults: at most a day

FaultDuration = Annotated[float, Field(gt=0, le=MAX_FAULT_S, allow_inf_nan=False)]

# how ``garbled`` damages frames, by transport: the CAN drivers (slcan) and NMEA 0183
GARBLING: dict[str, tuple[str, ...]] = {
    "can": ("length", "range", "id", "line", "bytes"),
    "nmea0183": ("checksum", "truncated", "range", "bytes"),
}
Garbling = Literal["length", "range", "id", "line", "bytes", "checksum", "truncated"]


class FaultParams(BaseModel):
    """The parameters of one kind of fault (none by default)."""

    model_config = ConfigDict(
        extra="forbid", frozen=True, strict=True, use_attribute_docstrings=True
    )


# -- the stand's faults: SimStand.inject(kind, **params) ---------------------------------------


class DropConnectionParams(FaultParams):
    """``drop_connection``: the link goes dead. Modbus TCP: the server closes every client
    connection, and any new one as soon as it speaks; RTU: the line goes silent."""

    duration_s: FaultDuration | None = None
    """How long the link stays dead (s); not given: until the faults are cleared."""


class StallParams(FaultParams):
    """``stall``: requests are neither acted on nor answered."""

    duration_s: FaultDuration | None = None
    """How long the stand stalls (s); not given: 1 s."""


class ModbusExceptionParams(FaultParams):
    """``modbus_exception``: every request is answered with one Modbus exception."""

    code: Annotated[int, Field(ge=1, le=255)] | None = None
    """The exception code; not given: 4 (server device failure)."""
    duration_s: FaultDuration | None = None
    """For how long (s); with neither this nor ``count``: until the faults are cleared."""
    count: Annotated[int, Field(ge=1, le=1_000_000_000)] | None = None
    """For the next this many requests."""


class StandFaultParams(FaultParams):
    """``stand_fault``: the stand faults — brakes to rest at its acceleration limit, servo
    off — latched until a fault reset over Modbus."""

    code: Annotated[int, Field(ge=1, le=65535)] | None = None
    """The stand's fault code; not given: 10."""


class EstopParams(FaultParams):
    """``estop``: the E-stop is pressed (a stand fault with code 3 and the E-stop bit)."""


# -- the instrument's faults: SimInstrument.inject(kind, **params) -----------------------------


class GarbledParams(FaultParams):
    """``garbled``: a fraction of the frames is damaged; the host counts them as bad frames
    by reason and never takes them as data."""

    fraction: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] | None = None
    """The fraction of frames damaged; not given: 0.1."""
    how: Garbling | None = None
    """How frames are damaged. CAN drivers: ``length`` (the default), ``range``, ``id``,
    ``line`` (corrupt slcan text), ``bytes``; NMEA 0183: ``checksum`` (the default),
    ``truncated``, ``range``, ``bytes`` (1–3 bytes of garbage on the serial line)."""


class SilentParams(FaultParams):
    """``silent``: the instrument stops sending until the faults are cleared."""


class StuckParams(FaultParams):
    """``stuck``: the instrument keeps sending its last output."""


class DropParams(FaultParams):
    """``drop``: the instrument's link goes dead and stays dead."""


STAND: dict[str, type[FaultParams]] = {
    "drop_connection": DropConnectionParams,
    "stall": StallParams,
    "modbus_exception": ModbusExceptionParams,
    "stand_fault": StandFaultParams,
    "estop": EstopParams,
}
INSTRUMENT: dict[str, type[FaultParams]] = {
    "garbled": GarbledParams,
    "silent": SilentParams,
    "stuck": StuckParams,
    "drop": DropParams,
}
FAULTS: dict[str, dict[str, type[FaultParams]]] = {"stand": STAND, "instrument": INSTRUMENT}


class FaultSpecError(ValueError):
    """A fault kind or parameter that the models do not allow: field, value, expectation."""

    def __init__(self, field: str, value: object, expected: str) -> None:
        self.field = field
        self.value = value
        self.expected = expected
        super().__init__(f"{field} = {shown_value(value)}: expected {expected}")


def expected(info: FieldInfo) -> str:
    """What a parameter takes, in words: ``an integer, 1 ≤ value ≤ 255``, ``a number,
    0 < value ≤ 1``, ``one of checksum, truncated``."""
    kind: Any = info.annotation
    metadata = list(info.metadata)
    args = [a for a in typing.get_args(kind) if a is not type(None)]
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        kind = args[0]
    if typing.get_origin(kind) is Annotated:
        base, *extra = typing.get_args(kind)
        for item in extra:
            metadata += list(item.metadata) if isinstance(item, FieldInfo) else [item]
        kind = base
    if typing.get_origin(kind) is Literal:
        return "one of " + ", ".join(str(v) for v in typing.get_args(kind))
    what = "an integer" if kind is int else "a number"
    lo = hi = ""
    for m in metadata:
        if isinstance(m, annotated_types.Gt):
            lo = f"{m.gt:g} < "
        elif isinstance(m, annotated_types.Ge):
            lo = f"{m.ge:g} ≤ "
        elif isinstance(m, annotated_types.Le):
            hi = f" ≤ {m.le:g}"
        elif isinstance(m, annotated_types.Lt):
            hi = f" < {m.lt:g}"
    return f"{what}, {lo}value{hi}" if lo or hi else what


def transport(driver: str) -> str:
    """The key of ``GARBLING`` for an instrument driver."""
    return "nmea0183" if driver == "nmea0183" else "can"


def check_kind(target: str, kind: object) -> str:
    """``kind`` if ``target`` (stand|instrument) has it, else ``FaultSpecError`` on ``kind``."""
    table = FAULTS.get(target)
    if table is None:
        raise FaultSpecError("target", target, f"one of {', '.join(FAULTS)}")
    if not isinstance(kind, str) or kind not in table:
        raise FaultSpecError("kind", kind, f"one of {', '.join(table)} ({target} faults)")
    return kind


def check_params(
    target: str, kind: str, params: Mapping[str, object], *, driver: str | None = None
) -> dict[str, str | int | float]:
    """The parameters of one fault, validated by its kind's model (names, types, ranges), as
    given (a number given for an integer parameter stays an integer, for a number becomes a
    float); ``FaultSpecError`` on the first bad one, naming it (``params.<name>``). With the
    instrument's ``driver`` a ``garbled`` fault's ``how`` must also suit its transport."""
    model = FAULTS[target][check_kind(target, kind)]
    fields = model.model_fields
    for name, value in params.items():
        if name not in fields:
            allowed = ", ".join(fields) if fields else "none"
            raise FaultSpecError(f"params.{name}", value, f"a parameter of {kind}: {allowed}")
        if value is None:  # a parameter left out is not given: None is no value of one
            raise FaultSpecError(f"params.{name}", value, expected(fields[name]))
    try:
        got = model.model_validate(dict(params))
    except ValidationError as err:
        first = err.errors()[0]
        name = str(first["loc"][0])
        raise FaultSpecError(f"params.{name}", params[name], expected(fields[name])) from None
    out: dict[str, str | int | float] = {name: getattr(got, name) for name in params}
    if driver is not None and "how" in out:
        ways = GARBLING[transport(driver)]
        if out["how"] not in ways:
            raise FaultSpecError(
                "params.how", out["how"], f"one of {', '.join(ways)} for driver {driver}"
            )
    return out
