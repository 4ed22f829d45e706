"""The bench config's ``instrument:`` section: the instrument under test, its link, and the
stand's axes it measures."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    Field,
    field_validator,
    model_validator,
)

from benchctl.config.types import (
    MAX_WAIT_S,
    Baud,
    DeviceRate,
    Finite,
    Positive,
    Seconds,
    Strict,
)

AxisName = Literal["roll", "pitch"]


class InstrumentAxis(Strict):
    """How one of the stand's axes is read from the instrument (``instrument.axes``): the
    instrument's ``output`` that measures it (its own axis of that name: ``roll`` or ``pitch``,
    by default the stand axis's own name) and the ``sign`` applied to it (``-1``: the unit is
    mounted reversed on that axis). Applied to every sample as it is read, so the recording,
    the running σ, the analysis and the report all see the stand's axes."""

    output: AxisName
    """The instrument's own output that measures this stand axis (`roll` or `pitch`)."""
    sign: Literal[1, -1] = 1
    """The sign applied to that output: -1 for a unit mounted reversed on this axis."""


def _axes_mapping(v: Any) -> Any:
    """``instrument.axes`` as a mapping stand axis → ``{output, sign}``: a list of names
    (``[roll, pitch]``: each output is the stand axis of its own name, sign +1) or a mapping
    whose entries may leave out ``output`` (the axis's own name) and ``sign`` (+1)."""
    if isinstance(v, list | tuple):
        return {a: {"output": a, "sign": 1} if isinstance(a, str) else a for a in v}
    if isinstance(v, dict):
        out: dict[Any, Any] = {}
        for a, m in v.items():
            if m is None:
                m = {}
            if isinstance(m, dict) and "output" not in m:
                m = {"output": a, **m}
            out[a] = m
        return out
    return v


def axis_map(axes: Any) -> dict[str, tuple[str, int]]:
    """``instrument.axes`` as {stand axis: (instrument output, sign)}; a plain tuple or list of
    names (a config copied with ``model_copy(update=...)``, which skips validation) is read as
    the identity."""
    if isinstance(axes, dict):
        return {a: (m.output, m.sign) if isinstance(m, InstrumentAxis)
                else (str(m.get("output", a)), int(m.get("sign", 1)))
                for a, m in axes.items()}
    return {str(a): (str(a), 1) for a in axes}


def _axes_schema(schema: dict[str, Any]) -> None:
    """``instrument.axes`` in the JSON Schema: the list form (``[roll, pitch]``) besides the
    mapping (as ``_axes_mapping`` reads both), its keys the stand's axes (said here: pydantic
    before 2.8 leaves ``propertyNames`` out)."""
    mapping = {k: v for k, v in schema.items() if k not in ("description", "title", "default")}
    for k in mapping:
        del schema[k]
    mapping["propertyNames"] = {"enum": ["roll", "pitch"]}
    listed = {"type": "array", "items": {"enum": ["roll", "pitch"]}, "uniqueItems": True,
              "minItems": 1}
    schema["anyOf"] = [listed, mapping]


class InstrumentConfig(Strict):
    """The instrument under test: its protocol and link, what it measures and what the run expects
    of it."""

    driver: Literal["canopen", "j1939", "nmea2000", "nmea0183"]
    """The instrument's protocol: CANopen (CiA 410 inclinometer), J1939, NMEA 2000 (over CAN) or
    NMEA 0183 (serial)."""
    interface: str | None = None
    """CAN drivers: the python-can interface name (slcan, socketcand, socketcan, pcan, kvaser,
    virtual, …)."""
    channel: str | None = None
    """CAN drivers: the python-can channel (a serial port for slcan, `can0` for socketcan, …)."""
    bitrate: Baud = 500000
    """CAN drivers: the bus bit rate (bit/s)."""
    node_id: int = Field(default=10, ge=1, le=127)
    """canopen: the instrument's CANopen node id."""
    source_address: int | None = Field(default=None, ge=0, le=253)
    """j1939, nmea2000: accept frames from this source address only (none: from any)."""
    eds: Path | None = None
    """canopen: the instrument's EDS file (relative to this file)."""
    dbc: Path | None = None
    """j1939: the DBC file that describes its messages (relative to this file)."""
    can_log: str | None = "can.blf"
    """CAN drivers: the raw frames are logged beside the recording under this name (.blf or .asc);
    none: not logged."""
    sleep_after_open_s: Annotated[float, Field(ge=0, le=MAX_WAIT_S, allow_inf_nan=False)] | None = (
        None
    )
    """slcan: seconds to wait after opening the serial port (none: 0 for a pseudo-terminal, else
    python-can's 2 s for a real adapter that resets on open)."""
    adapter_timestamps: bool = True
    """slcan: ask the adapter to timestamp every received frame (Z1, its own millisecond clock); the
    analysis then dates the samples by the adapter's clock, not by their receipt."""
    can_options: dict[str, str | int | Finite | bool] = Field(default_factory=dict)
    """CAN drivers: further keyword arguments for python-can's `can.Bus` (a hardware interface's own
    options)."""
    connect_timeout_s: Seconds = 3.0
    """The instrument must answer (SDO) or send its first frame within this (s) when the run opens
    it."""
    serial_port: str | None = None
    """nmea0183: the serial port (a device path or a pyserial URL)."""
    baudrate: Baud = 115200
    """nmea0183: the serial line's baud rate."""
    sentence: Literal["PASHR", "PHTRO", "XDR"] | None = None
    """nmea0183: the sentence that carries roll and pitch (none: whichever comes)."""
    axes: dict[AxisName, InstrumentAxis] = Field(
        default_factory=lambda: {a: InstrumentAxis(output=a) for a in ("roll", "pitch")},
        json_schema_extra=_axes_schema,
    )
    """The stand's axes the instrument measures, and for each the instrument's output that measures
    it and its sign. A list (`[roll, pitch]`) reads each output as the stand axis of its own name; a
    mapping (`roll: {output: pitch, sign: -1}`) maps a unit whose axes are swapped or reversed on
    the stand."""
    expected_rate_hz: DeviceRate = 100.0
    """The instrument's output rate (Hz); the precheck measures it against this."""
    static_tolerance_deg: Positive = 0.5
    """At rest before the motion, the instrument and the stand must agree within this (°)."""
    silence_timeout_s: Seconds = 1.0
    """No sample from the instrument for this long aborts the run (s)."""
    wire_trace: bool = False
    """Log every frame received from the instrument (debug level)."""

    @field_validator("axes", mode="before")
    @classmethod
    def _axes_before(cls, v: Any) -> Any:
        return _axes_mapping(v)

    @field_validator("axes")
    @classmethod
    def _axes(cls, v: dict[str, InstrumentAxis]) -> dict[str, InstrumentAxis]:
        if not v:
            raise ValueError("expected at least one axis")
        outputs = [m.output for m in v.values()]
        for o in set(outputs):
            if outputs.count(o) > 1:
                users = [a for a, m in v.items() if m.output == o]
                raise ValueError(
                    f"axes {users} all read the instrument's output {o!r}: expected each "
                    "output for one stand axis only"
                )
        return v

    @property
    def outputs(self) -> tuple[str, ...]:
        """The instrument's own outputs the driver decodes (``output`` of each axis)."""
        return tuple(o for o, _ in axis_map(self.axes).values())

    @model_validator(mode="after")
    def _transport(self) -> InstrumentConfig:
        if self.driver == "nmea0183":
            if not self.serial_port:
                raise ValueError("driver nmea0183 needs serial_port")
        elif not (self.interface and self.channel is not None):
            raise ValueError(f"driver {self.driver} needs interface and channel (python-can)")
        if self.driver == "canopen" and self.eds is None:
            raise ValueError("driver canopen needs eds (an EDS file in drivers/)")
        if self.driver in ("j1939", "nmea2000") and self.dbc is None:
            raise ValueError(f"driver {self.driver} needs dbc (a DBC file in drivers/)")
        return self
