"""The simulators' fault kinds and their parameters: the one table both the bench config's
validator (``sim.faults``, ``sim.stand.faults``) and ``SimStand.inject`` /
``SimInstrument.inject`` check against, so a misspelt kind or parameter is refused when the
config is loaded, before anything starts.

To add a kind, a parameter or a way of garbling: add it to ``STAND``, ``INSTRUMENT`` or
``GARBLING`` below (and implement it in the simulator). Nothing else needs to change.

Pure data and checks: no simulator imports (``benchctl.config`` imports this module).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

MAX_FAULT_S = 86400.0  # durations and delays of faults: at most a day


@dataclass(frozen=True)
class Param:
    """One keyword parameter of a fault: its type and allowed values."""

    type: Literal["int", "float", "str"]
    lo: float | None = None  # inclusive, unless lo_open
    hi: float | None = None  # inclusive
    lo_open: bool = False
    choices: tuple[str, ...] = ()

    def expected(self) -> str:
        if self.type == "str":
            return f"one of {', '.join(self.choices)}"
        what = "an integer" if self.type == "int" else "a number"
        if self.lo is None and self.hi is None:
            return what
        lo = "" if self.lo is None else f"{self.lo:g} {'<' if self.lo_open else '≤'} "
        hi = "" if self.hi is None else f" ≤ {self.hi:g}"
        return f"{what}, {lo}value{hi}"

    def check(self, field: str, value: object) -> str | int | float:
        """The value (an int given for a float becomes a float), or ``FaultSpecError``."""
        if self.type == "str":
            if not isinstance(value, str) or value not in self.choices:
                raise FaultSpecError(field, value, self.expected())
            return value
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise FaultSpecError(field, value, self.expected())
        if self.type == "int" and not isinstance(value, numbers.Integral):
            raise FaultSpecError(field, value, self.expected())
        v = float(value)
        if not math.isfinite(v):
            raise FaultSpecError(field, value, self.expected())
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            raise FaultSpecError(field, value, self.expected())
        if self.hi is not None and v > self.hi:
            raise FaultSpecError(field, value, self.expected())
        if isinstance(value, numbers.Integral) and self.type == "int":
            return int(value)
        return v


class FaultSpecError(ValueError):
    """A fault kind or parameter that the table does not allow: field, value, expectation."""

    def __init__(self, field: str, value: object, expected: str) -> None:
        self.field = field
        self.value = value
        self.expected = expected
        shown = repr(value)
        if len(shown) > 60:
            shown = shown[:57] + "..."
        super().__init__(f"{field} = {shown}: expected {expected}")


SECONDS = Param("float", 0.0, MAX_FAULT_S, lo_open=True)

# SimStand.inject(kind, **params); docs/reference/simulators.md, the stand's fault knobs
STAND: dict[str, dict[str, Param]] = {
    "drop_connection": {"duration_s": SECONDS},
    "stall": {"duration_s": SECONDS},
    "modbus_exception": {
        "code": Param("int", 1, 255),
        "duration_s": SECONDS,
        "count": Param("int", 1, 1e9),
    },
    "stand_fault": {"code": Param("int", 1, 65535)},
    "estop": {},
}

# how ``garbled`` damages frames, by transport: the CAN drivers (slcan) and NMEA 0183
GARBLING: dict[str, tuple[str, ...]] = {
    "can": ("length", "range", "id", "line", "bytes"),
    "nmea0183": ("checksum", "truncated", "range", "bytes"),
}

# SimInstrument.inject(kind, **params); docs/reference/simulators.md, the instrument's fault
# injection
INSTRUMENT: dict[str, dict[str, Param]] = {
    "garbled": {
        "fraction": Param("float", 0.0, 1.0, lo_open=True),
        "how": Param("str", choices=tuple(dict.fromkeys(w for g in GARBLING.values() for w in g))),
    },
    "silent": {},
    "stuck": {},
    "drop": {},
}

FAULTS: dict[str, dict[str, dict[str, Param]]] = {"stand": STAND, "instrument": INSTRUMENT}


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
    """Validated parameters of one fault (names, types, ranges); ``FaultSpecError`` on the
    first bad one, naming it (``params.<name>``). With the instrument's ``driver`` a
    ``garbled`` fault's ``how`` must also suit its transport."""
    table = FAULTS[target][check_kind(target, kind)]
    out: dict[str, str | int | float] = {}
    for name, value in params.items():
        spec = table.get(name)
        if spec is None:
            allowed = ", ".join(table) if table else "none"
            raise FaultSpecError(f"params.{name}", value, f"a parameter of {kind}: {allowed}")
        out[name] = spec.check(f"params.{name}", value)
    if driver is not None and "how" in out:
        ways = GARBLING[transport(driver)]
        if out["how"] not in ways:
            raise FaultSpecError(
                "params.how", out["how"], f"one of {', '.join(ways)} for driver {driver}"
            )
    return out
