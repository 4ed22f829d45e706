"""The bench configuration: one YAML file, validated strictly (unknown fields are errors).

Units are in field names. Relative paths in a config (register maps, EDS/DBC files, output
folders) are resolved against the config file's own folder, so a config works from any cwd.
A validation failure raises ``ConfigError`` naming the file, the field, the value and what
was expected; it is always fatal.
"""

from __future__ import annotations

import datetime
import json
import re
from pathlib import Path
from typing import Annotated, Any, Literal
from urllib.parse import urlsplit

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic.json_schema import SkipJsonSchema

from benchctl.errors import ConfigError
from benchctl.faultspec import (
    FAULTS,
    MAX_FAULT_S,
    STAND,
    FaultSpecError,
    check_kind,
    check_params,
)
from benchctl.options import MAX_BAND_HZ
from benchctl.text import PART_NUMBER_MAX, STATION_MAX
from benchctl.text import problem as text_problem
from benchctl.validation import invalid, shown_value
from benchctl.yamlfile import read_yaml

# Every number in a config is finite (``.inf``, ``.nan``, "inf" are refused); times and rates
# that size a buffer or a wait are bounded above (docs/reference/config.md).
Finite = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
MAX_WAIT_S = 3600.0  # timeouts, periods, windows
MAX_HOST_RATE_HZ = 1000.0  # the host's setpoint / stand polling rate
MAX_DEVICE_RATE_HZ = 100_000.0  # an instrument's (or a simulator's) own rate
Seconds = Annotated[float, Field(gt=0, le=MAX_WAIT_S, allow_inf_nan=False)]
HostRate = Annotated[float, Field(gt=0, le=MAX_HOST_RATE_HZ, allow_inf_nan=False)]
DeviceRate = Annotated[float, Field(gt=0, le=MAX_DEVICE_RATE_HZ, allow_inf_nan=False)]
Baud = Annotated[int, Field(gt=0, le=100_000_000)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True)


class StandLimits(Strict):
    """Per-axis limits of the stand; every motion is checked against them before it is sent."""

    angle_deg: Positive
    """The largest angle the stand may be commanded to, either way (°)."""
    rate_deg_s: Positive
    """The largest angular rate of a commanded motion (°/s)."""
    accel_deg_s2: Positive
    """The largest angular acceleration of a commanded motion (°/s²)."""


class StandConfig(Strict):
    """The motion stand: how it is reached over Modbus, its register map, limits and the way the
    motion reaches it."""

    driver: Literal["modbus-tcp", "modbus-rtu"]
    """How the stand is reached: Modbus TCP or Modbus RTU (serial)."""
    host: str = "127.0.0.1"
    """modbus-tcp: the stand controller's address."""
    port: int = Field(default=502, ge=0, le=65535)
    """modbus-tcp: its TCP port."""
    serial_port: str | None = None
    """modbus-rtu: a device path (`/dev/ttyUSB0`) or a pyserial URL."""
    baudrate: Baud = 115200
    """modbus-rtu: the line's baud rate."""
    parity: Literal["N", "E", "O"] = "N"
    """modbus-rtu: the line's parity (N, E or O)."""
    stopbits: Literal[1, 2] = 1
    """modbus-rtu: the line's stop bits."""
    device_id: int = Field(default=1, ge=0, le=247)
    """The stand controller's Modbus unit id (slave address)."""
    register_map: Path = Path("../drivers/stand_generic.yaml")
    """The register map of the stand controller (YAML; relative to this file)."""
    timeout_s: Seconds = 0.4
    """How long one Modbus request waits for its reply (s). One exchange lasts at most timeout_s ×
    (retries + 1), and the next heartbeat waits behind it: with heartbeat_period_s that must fit
    inside the stand's watchdog (checked when the config is loaded)."""
    retries: int = Field(default=1, ge=0, le=100)
    """How many times a request without a reply is sent again before the run gives up on the stand.
    """
    axes: tuple[Literal["roll", "pitch"], ...] = ("roll", "pitch")
    """The stand's axes the run drives."""
    mode: Literal["stream", "buffered", "table"] = "stream"
    """How the motion reaches the stand: `stream` (one setpoint from the host every period),
    `buffered` (points queued ahead in the stand's trajectory buffer; needs a `trajectory:` section
    in the register map) or `table` (the stand plays a whole table on its own)."""
    buffer_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 1.0
    """buffered: how far ahead of the motion the queue is kept full (s of motion; capped by the
    stand's capacity)."""
    setpoint_rate_hz: HostRate = 100.0
    """The rate of the commanded points (Hz): setpoints sent (stream), or points queued (buffered).
    """
    sample_rate_hz: HostRate = 100.0
    """How often the stand's encoder angle is read (Hz); in stream mode, each cycle."""
    heartbeat_period_s: Seconds = 0.1
    """How often the host writes the stand's heartbeat register (s)."""
    watchdog_s: Seconds | None = None
    """The stand's own heartbeat watchdog (its setting, from its manual or parameters, s). When
    given, the config is checked against it (with a `sim:` section, sim.stand.watchdog_s is the
    stand's)."""
    limits: StandLimits
    """The stand's angle, rate and acceleration limits; every motion is checked against them before
    it is sent."""
    tracking_tolerance_deg: Positive = 0.5
    """The run aborts when the measured angle departs from the commanded one by more than this (°),
    the following lag allowed for."""
    following_lag_s: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 0.0
    """The stand's following lag (s): a position servo without velocity feed-forward trails its
    setpoint by about this × its rate (2ζ/ω_n for a second-order loop); the tracking check judges
    measured − setpoint + following_lag_s × rate. 0: a stand that does not trail."""
    zero_tolerance_deg: Positive = 0.05
    """The stand is at rest at zero when every axis is within this of 0° (°)."""
    wire_trace: bool = False
    """Log every Modbus frame sent and received (debug level)."""
    calibration_due: datetime.date | None = None
    """The stand's calibration due date (YYYY-MM-DD), into the run's record and report."""

    @model_validator(mode="after")
    def _transport(self) -> StandConfig:
        if self.driver == "modbus-rtu" and not self.serial_port:
            raise ValueError("driver modbus-rtu needs serial_port (a device path or pyserial URL)")
        return self


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
    mapping (as ``_axes_mapping`` reads both)."""
    mapping = {k: v for k, v in schema.items() if k not in ("description", "title", "default")}
    for k in mapping:
        del schema[k]
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


FaultSeconds = Annotated[float, Field(ge=0, le=MAX_FAULT_S, allow_inf_nan=False)]


class SimStandFault(Strict):
    """A fault the simulated stand injects by itself, ``after_s`` seconds after it starts.

    ``kind`` and the parameters it takes (``duration_s``, ``code``) are checked against the
    kind's model in ``benchctl.faultspec`` (as ``SimStand.inject`` does).
    """

    kind: str = Field(json_schema_extra={"enum": list(STAND)})
    """The fault: drop_connection, stall, modbus_exception, stand_fault or estop."""
    after_s: FaultSeconds = 0.0
    """Seconds after the simulated stand starts."""
    duration_s: Positive | None = None
    """drop_connection, stall, modbus_exception: how long (s); none: until cleared (stall: 1 s)."""
    code: int | None = None
    """modbus_exception: the exception code (1–255); stand_fault: the fault code (1–65535)."""

    @field_validator("kind")
    @classmethod
    def _kind(cls, kind: str) -> str:
        try:
            return check_kind("stand", kind)
        except FaultSpecError as e:
            raise ValueError(f"unknown stand fault kind; expected {e.expected}") from None

    @model_validator(mode="after")
    def _params(self) -> SimStandFault:
        given = {k: v for k in ("duration_s", "code") if (v := getattr(self, k)) is not None}
        try:
            check_params("stand", self.kind, given)
        except FaultSpecError as e:
            raise ValueError(f"{e.field.removeprefix('params.')} = {e.value!r}: "
                             f"expected {e.expected}") from None
        return self


class SimStandConfig(Strict):
    """Physics of the simulated servo stand."""

    bandwidth_hz: Positive = 8.0
    """The simulated servo's natural frequency (Hz): a second-order position loop."""
    damping: Positive = 0.8
    """The simulated servo's damping ratio."""
    rate_limit_deg_s: Positive = 60.0
    """The simulated drive's own rate limit (°/s)."""
    accel_limit_deg_s2: Positive = 300.0
    """The simulated drive's own acceleration limit (°/s²); a fault or E-stop brakes at it."""
    encoder_resolution_deg: NonNegative = 0.001
    """The simulated encoder's resolution (°); 0: exact."""
    soft_limit_deg: Positive = 40.0
    """Crossing this angle outwards faults the simulated stand (code 1); setpoints beyond it are
    refused (°)."""
    watchdog_s: Seconds = 1.0
    """Heartbeat silence for this long while enabled faults the simulated stand (code 2) (s)."""
    tick_hz: DeviceRate = 1000.0
    """The simulated servo's physics rate (Hz)."""
    rtu_wire_delay: bool = True
    """Emulate the serial byte time on the RTU link."""
    stream_interpolation: bool = False
    """stream mode: the drive interpolates linearly between consecutive setpoints over the interval
    between them (as a drive in cyclic synchronous position mode does), instead of stepping to each
    one."""
    baudrate: Baud = 115200
    """The byte time of the emulated RTU wire (baud)."""
    faults: tuple[SimStandFault, ...] = ()
    """Faults the simulated stand injects by itself on a schedule, from its start."""


class CrossAxisConfig(Strict):
    """Cross-axis coupling of the simulated instrument (a misaligned sensing axis): each
    axis's input is its own angle plus this fraction of the other axis's angle (|k| ≤ 1)."""

    roll_from_pitch: Annotated[float, Field(ge=-1, le=1, allow_inf_nan=False)] = 0.0
    """The fraction of the pitch angle added to the roll axis's input."""
    pitch_from_roll: Annotated[float, Field(ge=-1, le=1, allow_inf_nan=False)] = 0.0
    """The fraction of the roll angle added to the pitch axis's input."""


class SimMountingConfig(Strict):
    """How the simulated unit is mounted on the stand: ``swap_axes`` (its roll output senses
    the stand's pitch and the other way round), then ``roll_sign``/``pitch_sign`` (−1: that
    output reads the angle it senses reversed). Applied to the true motion the instrument's
    model senses, so every protocol sees it; the default is a correct mount."""

    swap_axes: bool = False
    """The unit's roll output senses the stand's pitch and the other way round."""
    roll_sign: Literal[1, -1] = 1
    """-1: the roll output reads the angle it senses reversed."""
    pitch_sign: Literal[1, -1] = 1
    """-1: the pitch output reads the angle it senses reversed."""


class SimInstrumentConfig(Strict):
    """The simulated instrument's own model: what it measures of the true stand motion.

    Optional static effects on each axis's input before the dynamics, in this order: the
    cross-axis coupling, then the cubic term ``u + cubic_per_deg2 · u³``, then the saturation
    ``clip(u, −saturation_deg, +saturation_deg)``; all off by default (the model is linear).
    """

    gain: Finite = 1.0
    """The simulated instrument's static gain."""
    lag_s: Annotated[float, Field(ge=0, le=MAX_WAIT_S, allow_inf_nan=False)] = 0.0
    """Its first-order lag's time constant (s); 0: none."""
    natural_freq_hz: Positive | None = None
    """Its second-order response's natural frequency (Hz), in place of the first-order lag; none:
    first order."""
    damping: Positive = 0.7
    """The second-order response's damping ratio."""
    latency_s: Annotated[float, Field(ge=0, le=MAX_WAIT_S, allow_inf_nan=False)] = 0.0
    """A pure delay of its output (s)."""
    bias_deg: Finite = 0.0
    """A constant offset of its output (°)."""
    noise_deg: NonNegative = 0.0
    """The σ of white noise added to its output (°)."""
    drift_deg_s: Finite = 0.0
    """A slow linear drift of its output (°/s)."""
    quantisation_deg: NonNegative = 0.0
    """The step its output is rounded to (°); 0: none (the protocol's own resolution still applies).
    """
    rate_hz: DeviceRate = 100.0
    """Its output rate (Hz)."""
    seed: int = Field(default=1, ge=0, lt=2**63)
    """The seed of its noise: the same seed gives the same noise."""
    substep_hz: Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)] = 4000.0
    """The rate of the exact first-order-hold integration of its lag or second-order response (Hz).
    """
    cross_axis: CrossAxisConfig = CrossAxisConfig()
    """Cross-axis coupling (a misaligned sensing axis)."""
    cubic_per_deg2: Annotated[float, Field(ge=-1, le=1, allow_inf_nan=False)] = 0.0
    """The cubic term's coefficient: each axis's input u becomes u + cubic_per_deg2 · u³ (1/°²); 0:
    none."""
    saturation_deg: Annotated[float, Field(gt=0, le=360, allow_inf_nan=False)] | None = None
    """Each axis's input is clipped to ± this (°); none: no saturation."""
    serial_number: int | None = Field(default=None, ge=0, lt=2**32)
    """The serial number it reports where its protocol carries one (CANopen 1018h sub 4, an
    UNSIGNED32); None: the EDS's default."""
    mounting: SimMountingConfig = SimMountingConfig()
    """How the unit sits on the stand (swapped or reversed axes); by default mounted correctly."""


def _fault_params_schema(schema: dict[str, Any]) -> None:
    """``SimFault``'s JSON Schema: which ``params`` each target and kind takes."""
    rules = []
    for target, kinds in FAULTS.items():
        for kind, model in kinds.items():
            params = model.model_json_schema()
            params.pop("title", None)
            for prop in params.get("properties", {}).values():  # not given, never null
                prop.pop("default", None)
                prop.pop("title", None)
                given = [a for a in prop.pop("anyOf", []) if a.get("type") != "null"]
                if given:
                    prop.update(given[0])
            rules.append({
                "if": {"properties": {"target": {"const": target}, "kind": {"const": kind}},
                       "required": ["target", "kind"]},
                "then": {"properties": {"params": params}},
            })
    schema["allOf"] = rules


class SimFault(Strict):
    """A fault the simulators inject by themselves, ``after_motion_s`` after the stand first moves.

    ``target`` stand: kinds of ``SimStand.inject`` (drop_connection, stall, modbus_exception,
    stand_fault, estop); instrument: kinds of ``SimInstrument.inject`` (garbled, silent, stuck,
    drop). ``params`` are that method's keyword arguments. Kinds and parameters (names, types,
    ranges) are checked against the kind's model in ``benchctl.faultspec`` here; a garbled
    fault's ``how`` against the instrument's driver by ``parse_config``. The JSON Schema gives
    each kind's parameters (``if`` target and kind, ``then`` params).
    """

    model_config = ConfigDict(json_schema_extra=_fault_params_schema)

    target: Literal["stand", "instrument"]
    """Which simulator injects it: the stand or the instrument."""
    kind: str = Field(json_schema_extra={"enum": [k for t in FAULTS.values() for k in t]})
    """The fault: stand: drop_connection, stall, modbus_exception, stand_fault, estop; instrument:
    garbled, silent, stuck, drop."""
    after_motion_s: FaultSeconds = 0.0
    """Seconds after the stand first moves."""
    params: dict[str, bool | str | int | Finite] = Field(default_factory=dict)
    """The fault's parameters (its kind's; none by default)."""

    @field_validator("kind")
    @classmethod
    def _kind(cls, kind: str, info: ValidationInfo) -> str:
        target = info.data.get("target")
        if target is None:
            return kind  # the target's own error is reported
        try:
            return check_kind(target, kind)
        except FaultSpecError as e:
            raise ValueError(f"unknown {target} fault kind; expected {e.expected}") from None

    @model_validator(mode="after")
    def _params(self) -> SimFault:
        try:
            check_params(self.target, self.kind, self.params)
        except FaultSpecError as e:
            raise ValueError(str(e)) from None
        return self


Probability = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
SimSeconds = Annotated[float, Field(ge=0, le=60, allow_inf_nan=False)]


class SimDisturbConfig(Strict):
    """Seeded host and device behaviour for a run on simulated time (``sim.clock: virtual``).

    Everything is drawn from ``seed`` (one pseudo-random stream per kind), so a seed replays
    exactly: host stalls (the run's process stopped: a Poisson stream of ``host_stalls_per_min``,
    durations log-uniform in ``host_stall_s``), jitter on every frame the host sends (uniform in
    ``[0, send_jitter_s]``), stand replies that are slow (probability ``slow_reply_p``, an extra
    delay log-uniform in ``slow_reply_s``) or lost (``lost_reply_p``), instrument frames lost
    (``lost_frame_p``) or garbled (``garbled_frame_p``, one byte changed), ``faults`` stand or
    instrument faults at random moments of the motion (kinds drawn from ``fault_kinds``), and
    an operator's Ctrl-C at a random moment with probability ``operator_stop_p``.

    ``from_s``: the host's stalls, the send jitter and the slow, lost and garbled frames act
    from this many seconds after the simulators start; before it the run is undisturbed (a run
    disturbed from its motion's start on begins its motion at the same simulated instant as
    its undisturbed twin, the instrument's samples and noise in step with it).
    """

    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    """Everything is drawn from this seed (one pseudo-random stream per kind): a seed replays
    exactly."""
    from_s: Annotated[float, Field(ge=0, le=86_400, allow_inf_nan=False)] = 0.0
    """The host's stalls, the send jitter and the slow, lost and garbled frames act from this many
    seconds after the simulators start (s)."""
    host_stalls_per_min: Annotated[float, Field(ge=0, le=600, allow_inf_nan=False)] = 0.0
    """Host stalls (the run's process stopped), a Poisson stream of this many a minute."""
    host_stall_s: tuple[SimSeconds, SimSeconds] = (0.05, 0.3)
    """[shortest, longest]: a stall's duration, log-uniform between them (s)."""
    send_jitter_s: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 0.0
    """Every frame the host sends leaves late by up to this, uniform (s)."""
    slow_reply_p: Probability = 0.0
    """The probability that a stand reply is slow."""
    slow_reply_s: tuple[SimSeconds, SimSeconds] = (0.01, 0.5)
    """[shortest, longest]: a slow reply's extra delay, log-uniform between them (s)."""
    lost_reply_p: Probability = 0.0
    """The probability that a stand reply is lost."""
    lost_frame_p: Probability = 0.0
    """The probability that an instrument frame is lost."""
    garbled_frame_p: Probability = 0.0
    """The probability that an instrument frame is garbled (one byte changed)."""
    faults: Annotated[int, Field(ge=0, le=100)] = 0
    """How many stand or instrument faults, at random moments of the motion."""
    fault_kinds: tuple[str, ...] = ("stand:stall", "stand:stand_fault", "instrument:silent")
    """The kinds those faults are drawn from, as `stand:KIND` or `instrument:KIND`."""
    operator_stop_p: Probability = 0.0
    """The probability of an operator's Ctrl-C at a random moment."""

    @field_validator("host_stall_s", "slow_reply_s")
    @classmethod
    def _range(cls, r: tuple[float, float]) -> tuple[float, float]:
        if not 0 < r[0] <= r[1]:
            raise ValueError(f"expected [shortest, longest] with 0 < shortest <= longest, got {r}")
        return r

    @field_validator("fault_kinds")
    @classmethod
    def _kinds(cls, kinds: tuple[str, ...]) -> tuple[str, ...]:
        for k in kinds:
            target, _, kind = k.partition(":")
            if target not in ("stand", "instrument"):
                raise ValueError(f"{k!r}: expected stand:KIND or instrument:KIND")
            try:
                check_kind(target, kind)
            except FaultSpecError as e:
                raise ValueError(
                    f"{k!r}: unknown {target} fault kind; expected {e.expected}"
                ) from None
        return kinds


class SimConfig(Strict):
    """Present in a config → ``benchctl run`` starts the simulators itself (``benchctl sim``)."""

    stand: SimStandConfig = SimStandConfig()
    """The simulated stand's physics and faults."""
    instrument: SimInstrumentConfig = SimInstrumentConfig()
    """The simulated instrument's model."""
    faults: tuple[SimFault, ...] = ()
    """Faults the simulators inject by themselves, timed from the moment the stand first moves."""
    motion_threshold_deg: Positive = 0.01
    """"The stand first moves": its true angle beyond this (°)."""
    clock: Literal["real", "virtual"] = "real"
    """`real`: the simulators run beside the run on the host's time, over a TCP socket and
    pseudo-terminals; `virtual`: in the run's process on simulated time, over in-process links — a
    15-minute test in about a minute, the same bytes every time."""
    epoch_utc: datetime.datetime = datetime.datetime(2026, 1, 1, tzinfo=datetime.UTC)
    """Simulated time: the UTC wall time at its start (every stamp of the run follows from it)."""
    link_latency_s: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 0.0005
    """Simulated time: the one-way latency of the stand's link (Modbus TCP; RTU adds byte times)
    (s)."""
    host_cost_s: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 0.0002
    """Simulated time: the host computation charged to each cycle of the stand loop, so that a loop
    too slow for its rate still shows as one (s)."""
    disturb: SimDisturbConfig | None = None
    """Simulated time: seeded host stalls, slow, lost and garbled frames, faults and an operator's
    stop."""

    @field_validator("epoch_utc")
    @classmethod
    def _aware(cls, t: datetime.datetime) -> datetime.datetime:
        if t.tzinfo is None:
            raise ValueError("needs a time zone (e.g. 2026-01-01T00:00:00Z)")
        return t.astimezone(datetime.UTC)


class EqualiseConfig(Strict):
    """Equalisation (``benchctl.analysis.equalise``): before the motion a short pre-test at
    ``level`` × the profile's amplitudes measures the stand's response on the profile's lines
    over ``periods`` whole periods (a period over ``max_period_s``: a shorter one, the response
    interpolated), and the drive is corrected so the measured motion is the profile's. A line
    where the stand moves less than ``min_gain_db`` or whose response is uncertain beyond
    ``max_uncertainty_db`` is not corrected; no line is driven up by more than
    ``max_boost_db``, nor beyond the stand's limits."""

    enabled: bool = False
    """Equalise before the motion (off by default; `--equalise` turns it on)."""
    level: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = 0.2
    """The pre-test's amplitudes as a fraction of the profile's."""
    periods: Annotated[int, Field(ge=1, le=20)] = 1
    """The pre-test's length in whole periods of the profile's multisine."""
    max_period_s: Annotated[float, Field(ge=1, le=600, allow_inf_nan=False)] = 20.0
    """A profile period longer than this is pre-tested over a shorter one, the response interpolated
    (s)."""
    fade_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 2.0
    """The pre-test's fade in and out (s)."""
    settle_s: Annotated[float, Field(ge=0, le=60, allow_inf_nan=False)] = 3.0
    """Settling before the pre-test's samples are taken (s)."""
    min_gain_db: Annotated[float, Field(ge=-60, lt=0, allow_inf_nan=False)] = -20.0
    """A line where the stand moves less than this is not corrected (dB)."""
    max_boost_db: Annotated[float, Field(ge=0, le=40, allow_inf_nan=False)] = 10.0
    """No line is driven up by more than this (dB), nor beyond the stand's limits."""
    max_uncertainty_db: Annotated[float, Field(gt=0, le=6, allow_inf_nan=False)] = 0.5
    """A line whose measured response is uncertain beyond this is not corrected (dB)."""


class AnalysisConfig(Strict):
    """How the recording is analysed."""

    max_lag_s: Annotated[float, Field(gt=0, le=86400, allow_inf_nan=False)] | None = None
    """The longest delay between the two streams the analysis searches for (s); none: the documented
    default rule."""
    band_hz: tuple[NonNegative, Positive] | None = None
    """[lo, hi]: σ restricted to this band (Hz); none: the whole band."""
    compensate_delay: (
        Literal["none", "auto"] | Annotated[float, Field(ge=-3600, le=3600, allow_inf_nan=False)]
    ) = "none"
    """`none`; `auto` (the instrument's delay estimated and removed before σ); or a delay in seconds
    to remove."""
    departure_settle_s: Annotated[float, Field(ge=0, le=60, allow_inf_nan=False)] = 3.0
    """After an underrun or a rejoin, the stand is back on the profile: its servo and the instrument
    settle for this long before the analysis takes its samples again (s)."""

    @field_validator("band_hz")
    @classmethod
    def _band(cls, band: tuple[float, float] | None) -> tuple[float, float] | None:
        if band is not None and not (band[0] < band[1] <= MAX_BAND_HZ):
            raise ValueError(f"expected [lo, hi] in Hz with lo < hi ≤ {MAX_BAND_HZ:g}")
        return band


class ExcitationConfig(Strict):
    """Excitation fidelity (``benchctl.analysis.excitation``): the measured stand angle's
    spectrum against the profile's, judged per band: beyond ±``alarm_db`` an alarm, beyond
    ±``abort_db`` the abort level. Lines below ``weak_line_db`` (amplitude re the strongest)
    and bands below ``weak_band_db`` (power re the strongest band) are not judged, nor a band
    whose 95 % half-width exceeds ``max_ci_db``. ``band_edges_hz``: the bands' edges, ascending
    (default: third-octave bands). ``abort_run``: abort the run when a band's running estimate
    during the motion is confirmed beyond ±``abort_db``."""

    alarm_db: Annotated[float, Field(gt=0, le=20, allow_inf_nan=False)] = 1.5
    """A band's measured excitation beyond ± this of the profile's raises an alarm (dB)."""
    abort_db: Annotated[float, Field(gt=0, le=40, allow_inf_nan=False)] = 3.0
    """Beyond ± this, the abort level (dB); at least alarm_db."""
    weak_line_db: Annotated[float, Field(ge=-120, lt=0, allow_inf_nan=False)] = -30.0
    """Lines weaker than this, re the strongest (amplitude), are not judged (dB)."""
    weak_band_db: Annotated[float, Field(ge=-120, lt=0, allow_inf_nan=False)] = -20.0
    """Bands weaker than this, re the strongest (power), are not judged (dB)."""
    max_ci_db: Annotated[float, Field(gt=0, le=20, allow_inf_nan=False)] = 0.5
    """A band whose 95 % interval's half-width exceeds this is not judged (dB)."""
    band_edges_hz: tuple[Positive, ...] | None = None
    """The bands' edges, strictly ascending (Hz); none: third-octave bands."""
    abort_run: bool = True
    """Abort the run when, during the motion, a band's running estimate is confirmed beyond ±
    abort_db."""

    @field_validator("band_edges_hz")
    @classmethod
    def _edges(cls, e: tuple[float, ...] | None) -> tuple[float, ...] | None:
        if e is not None and (
            len(e) < 2 or any(e[i + 1] <= e[i] for i in range(len(e) - 1))
            or e[-1] > MAX_BAND_HZ
        ):
            raise ValueError(
                f"expected at least two band edges in Hz, strictly ascending, ≤ {MAX_BAND_HZ:g}"
            )
        return e

    @model_validator(mode="after")
    def _levels(self) -> ExcitationConfig:
        if self.abort_db < self.alarm_db:
            raise ValueError(
                f"abort_db = {self.abort_db:g}: expected ≥ alarm_db ({self.alarm_db:g})"
            )
        return self


class MountingCheckConfig(Strict):
    """The mounting check (``benchctl.run.mounting``), a precheck before the motion: each axis
    of the profile in turn is tilted slowly to ``tilt_deg`` and back (``hold_s`` held at each
    end), within the stand's limits (checked with the profile, before anything opens), and the
    instrument's response fitted: the reading of
    that axis must follow it with a gain within 1 ± ``gain_tolerance`` and every other
    reading within ± ``cross_tolerance`` of it. A unit mounted reversed (gain −1) or with roll
    and pitch swapped is refused before the test, with what was seen and how to fix it.
    The tolerances are wide on purpose: they separate the mounting errors (−1, 0, the other
    axis's ±1) from a correct mount; a poor unit's gain and cross-axis sensitivity are the
    test's to measure (and FAIL). Their sum must stay below 1 (the cases stay apart)."""

    enabled: bool = True
    """Run the mounting check before the motion."""
    tilt_deg: Annotated[float, Field(gt=0, le=10, allow_inf_nan=False)] = 2.0
    """How far each axis is tilted (°)."""
    hold_s: Annotated[float, Field(ge=0.2, le=10, allow_inf_nan=False)] = 1.0
    """How long the tilt is held at each end (s)."""
    gain_tolerance: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.3
    """The tilted axis's reading must follow it with a gain within 1 ± this."""
    cross_tolerance: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.3
    """Every other reading must stay within ± this of the tilt (as a gain)."""

    @model_validator(mode="after")
    def _apart(self) -> MountingCheckConfig:
        if self.gain_tolerance + self.cross_tolerance >= 1:
            raise ValueError(
                f"gain_tolerance = {self.gain_tolerance:g} + cross_tolerance = "
                f"{self.cross_tolerance:g}: expected a sum below 1 (else a reading that does "
                "not respond could pass as one that does)"
            )
        return self


class RunLimits(Strict):
    """Optional limits of further measurements (benchctl.results.measurements): each one set
    makes that measurement decide the verdict with σ; unset, it is recorded, not judged."""

    gain_min: Positive | None = None
    """The gain at the periods 3, 5, 7 and 10 s (where excited) must be at least this."""
    gain_max: Positive | None = None
    """… and at most this."""
    phase_deg: Annotated[float, Field(gt=0, le=180, allow_inf_nan=False)] | None = None
    """|phase| at those periods at most this (°)."""
    delay_s: Annotated[float, Field(gt=0, le=MAX_WAIT_S, allow_inf_nan=False)] | None = None
    """The instrument's delay at most this (s)."""
    mean_error_deg: Positive | None = None
    """|mean error| at most this (°)."""

    @model_validator(mode="after")
    def _gain(self) -> RunLimits:
        if self.gain_min is not None and self.gain_max is not None and (
            self.gain_min >= self.gain_max
        ):
            raise ValueError(
                f"gain_min = {self.gain_min:g}: expected below gain_max ({self.gain_max:g})"
            )
        return self


class HostCheckConfig(Strict):
    """The host fitness check (``benchctl.run.fitness``): before the motion, threads ask to
    wake every ``period_s`` and every stand-loop period for ``window_s`` and the lateness of
    each wake is measured (as cyclictest or LinuxCNC's latency test do). The worst lateness ×
    ``margin`` must fit inside what the stand tolerates — its buffer (``buffered``), a quarter
    of the setpoint period (``stream``: a later setpoint is a missed slot), and the slack its
    heartbeat watchdog leaves beyond the longest exchange — else ``on_poor``: ``warn`` (the
    run goes on, a warning in the record) or ``refuse`` (a failed precheck: exit 2, nothing
    moves). Not measured on simulated time. ``benchctl host-check`` runs it alone."""

    enabled: bool = True
    """Measure the host before the motion (never on simulated time)."""
    window_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 2.0
    """How long the wakes are measured (s)."""
    period_s: Annotated[float, Field(ge=1e-4, le=1.0, allow_inf_nan=False)] = 0.001
    """The fixed wake period measured besides the stand loop's own (s; cyclictest's 1 ms)."""
    margin: Annotated[float, Field(ge=1, le=1e6, allow_inf_nan=False)] = 4.0
    """The worst lateness × this must fit inside what the stand tolerates."""
    on_poor: Literal["warn", "refuse"] = "warn"
    """A host that does not fit: `warn` (the run goes on, a warning in the record) or `refuse` (a
    failed precheck: exit 2, nothing moves)."""


class RunConfig(Strict):
    """The run's rules: the verdict, the checks before and during the motion, the analysis and the
    outputs."""

    limit_sigma_deg: Positive
    """The verdict's limit: PASS when σ is at most this, on every axis (°)."""
    decision_rule: Literal["simple", "guarded"] = "simple"
    """How σ (and every measurement with an interval) is judged against its limit: `simple` (the
    value within the limit) or `guarded` (the 95 % interval wholly within: PASS; wholly beyond:
    FAIL; else INCONCLUSIVE, exit 3)."""
    limits: RunLimits = RunLimits()
    """Optional limits of further measurements (gain, phase, delay, mean error)."""
    output_dir: Path = Path("runs")
    """Where the runs' folders are written (relative to this file)."""
    min_free_disk_mb: Positive = 200.0
    """A run is refused when the output folder's disk has less free space than this (MB)."""
    precheck_window_s: Seconds = 1.0
    """The instrument's rate and its agreement with the stand at rest are measured over this (s)."""
    instrument_rate_tolerance: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.2
    """The instrument's measured rate must be within ± this fraction of instrument.expected_rate_hz.
    """
    profile_tolerance_deg: Positive = 1.0
    """The stand's motion departing from the profile by more than this aborts the run (°)."""
    linearity_spread_limit: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = 0.01
    """sine_steps profiles: PASS when the spread (max − min) of the steps' gains is at most this,
    per axis."""
    analysis: AnalysisConfig = AnalysisConfig()
    """Analysis options."""
    excitation: ExcitationConfig = ExcitationConfig()
    """The excitation fidelity's levels: the measured motion's spectrum against the profile's."""
    lock_dir: Path | None = None
    """One run per stand: where its lock files are kept (none: /run/benchctl-locks)."""
    precision: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] | None = None
    """Stop the motion once σ's 95 % interval is within ± this fraction of σ (after at least one
    whole period of the multisine); none: the whole profile runs."""
    equalise: EqualiseConfig = EqualiseConfig()
    """A low-level pre-test and the drive corrected by the stand's measured response (off by
    default)."""
    mounting_check: MountingCheckConfig = MountingCheckConfig()
    """Before the motion, each axis tilted a few degrees and back: a unit mounted reversed or with
    its axes swapped is refused (on by default)."""
    host_check: HostCheckConfig = HostCheckConfig()
    """The host's scheduling latency, measured before the motion and judged against the stand's
    buffer and watchdog."""
    realtime_priority: Annotated[int, Field(ge=1, le=99)] | None = None
    """The SCHED_FIFO priority (1–99) the stand loop's thread asks for on the real clock (Linux:
    CAP_SYS_NICE or an rtprio limit); whether it was granted is recorded, a refusal never stops the
    run; none: not asked for."""
    figures: bool = True
    """Draw the report's figures at the run's end (about 1–3 s per axis); false on a bench whose
    reports nobody opens at the station: `benchctl report REC` draws them later."""


_ARCHIVE_URL = re.compile(r"(sqlite:///.+|(postgresql|postgres)(\+psycopg)?://.+)\Z", re.S)


class ArchiveConfig(Strict):
    """The results archive (``benchctl.archive``): every run stored in a database.
    ``url``: ``sqlite:///PATH`` (a relative PATH against this config's folder) or
    ``postgresql+psycopg://USER@HOST[:PORT]/DB`` for a line of benches sharing one (its
    password best from libpq's own sources — ``~/.pgpass``, ``PGPASSFILE``, ``PGPASSWORD``, a
    service file — not written here; never written anywhere by benchctl either way);
    None: ``sqlite:///<run.output_dir>/archive.sqlite``. ``queue_dir``: where records wait
    while the database cannot be reached (None: ``<run.output_dir>/archive-queue``).
    ``write_timeout_s``: how long a statement waits for a lock (a busy SQLite file) before
    the record is queued; any one statement is given twice this."""

    enabled: bool = True
    """Store every run in the archive."""
    url: str | None = None
    """`sqlite:///PATH` (a relative PATH against this file's folder) or
    `postgresql+psycopg://USER@HOST[:PORT]/DB` (its password from libpq's own sources, never here);
    none: `sqlite:///<run.output_dir>/archive.sqlite`."""
    queue_dir: Path | None = None
    """Where records wait while the database cannot be reached (none:
    `<run.output_dir>/archive-queue`)."""
    connect_timeout_s: Annotated[float, Field(gt=0, le=30, allow_inf_nan=False)] = 2.0
    """How long a connection to the database may take (s)."""
    write_timeout_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 2.0
    """How long a statement waits for a lock (a busy SQLite file) before the record is queued (s);
    any one statement is given twice this."""

    @field_validator("url")
    @classmethod
    def _url(cls, v: str | None) -> str | None:
        if v is not None and not _ARCHIVE_URL.match(v):
            raise ValueError(
                "expected sqlite:///PATH or postgresql+psycopg://USER@HOST[:PORT]/DB"
            )
        if v is not None and not v.startswith("sqlite"):
            try:
                urlsplit(v).port  # noqa: B018 (a port that is not a number raises)
            except ValueError:
                raise ValueError(
                    "the port is not a number 0-65535: expected "
                    "postgresql+psycopg://USER@HOST[:PORT]/DB"
                ) from None
        return v


def _plain_text(v: str | None, max_chars: int, what: str) -> str | None:
    """A name or number for people to read (``benchctl.text``): printable, at most
    ``max_chars`` characters, the whitespace around it removed; else a ``ValueError`` saying
    what is wrong."""
    if v is None:
        return None
    s = v.strip()
    bad = text_problem(s, max_chars, what)
    if bad is not None:
        raise ValueError(bad)
    return s


MAX_SERIAL_PATTERN = 200  # characters of unit.serial_pattern


class UnitConfig(Strict):
    """The unit under test: its part number (the serial is given per run: --serial) and the
    form every serial typed for it must have, ``serial_pattern``: a Python regular expression
    the whole serial must match (e.g. ``SN-[0-9]{6}``), checked before anything opens.
    ``serial_check``: what a serial typed unlike the one the instrument reports does —
    ``warn`` (the default: a warning, the run goes on) or ``require`` (a precheck: the run is
    refused before the stand moves, as is an instrument that reports no serial)."""

    part_number: str | None = None
    """The unit's part number, into every record."""
    serial_pattern: str | None = Field(default=None, min_length=1, max_length=MAX_SERIAL_PATTERN)
    """A Python regular expression every serial typed for this unit must wholly match (e.g.
    `SN-[0-9]{6}`), checked before anything opens."""
    serial_check: Literal["warn", "require"] = "warn"
    """A serial typed unlike the one the instrument reports: `warn` (a warning, the run goes on) or
    `require` (the run is refused before the stand moves, as is an instrument that reports no
    serial)."""

    @field_validator("part_number")
    @classmethod
    def _part_number(cls, v: str | None) -> str | None:
        return _plain_text(v, PART_NUMBER_MAX, "part number")

    @field_validator("serial_pattern")
    @classmethod
    def _serial_pattern(cls, v: str | None) -> str | None:
        if v is not None:
            try:
                re.compile(v)
            except re.error as e:
                raise ValueError(f"expected a regular expression: {e}") from None
        return v


class PanelConfig(Strict):
    """The station's web panel (``benchctl serve``): what its operator sees and may choose.
    ``lang``: the language of every text the operator reads (en, ru). ``profiles``: the motion
    profiles offered (files, or folders whose ``*.yaml`` files are profiles); ``plans``: the
    acceptance plans offered; ``duration_s``: each run's duration (None: the profile's own).
    ``host``/``port``: where it listens (loopback by default; another address needs
    ``token_scrypt``, the hash ``benchctl serve --hash-token`` prints — never the token).
    ``require_token``: ask for the token on loopback too (behind a reverse proxy).
    ``origins``: the addresses browsers reach it by, behind a proxy. ``out_dir``: the runs'
    folder (None: ``run.output_dir``). Relative paths resolve against this config's folder;
    ``benchctl serve``'s options override each field."""

    lang: Literal["en", "ru"] = "en"
    """The language of every text the operator reads (en, ru)."""
    profiles: list[Path] = Field(default_factory=list)
    """The motion profiles offered: files, or folders whose `*.yaml` files are profiles."""
    plans: list[Path] = Field(default_factory=list)
    """The acceptance plans offered."""
    duration_s: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    """Each run's duration (s); none: the profile's own."""
    host: str = "127.0.0.1"
    """The address the panel listens on (loopback by default; another address needs token_scrypt).
    """
    port: Annotated[int, Field(ge=0, le=65535)] = 8350
    """The port the panel listens on."""
    token_scrypt: str | None = None
    """The hash of the operators' token that `benchctl serve --hash-token` prints (never the token
    itself)."""
    require_token: bool = False
    """Ask for the token on loopback too (behind a reverse proxy)."""
    origins: list[str] = Field(default_factory=list)
    """The addresses browsers reach the panel by, behind a proxy."""
    out_dir: Path | None = None
    """The runs' folder (none: run.output_dir)."""

    def resolved(self, base: Path) -> PanelConfig:
        """The same with its relative paths taken from ``base`` (a folder)."""
        def rel(p: Path) -> Path:
            return p if p.is_absolute() else base / p

        return self.model_copy(update={
            "profiles": [rel(p) for p in self.profiles],
            "plans": [rel(p) for p in self.plans],
            "out_dir": None if self.out_dir is None else rel(self.out_dir),
        })


class BenchConfig(Strict):
    """A bench: the stand, the instrument under test, the run's rules, and optionally the
    simulators, the archive and the web panel."""

    station: str = "bench"
    """The bench's name, into every record and on the panel."""
    unit: UnitConfig = UnitConfig()
    """The unit under test: its part number and the form of its serials."""
    stand: StandConfig
    """The motion stand: its link, register map, limits and how the motion reaches it."""
    instrument: InstrumentConfig
    """The instrument under test: its protocol, link and expected rate."""
    run: RunConfig
    """The run: its verdict limit, decision rule, checks and outputs."""
    sim: SimConfig | None = None
    """Present: a simulated bench (`benchctl run` starts the simulators itself)."""
    archive: ArchiveConfig = ArchiveConfig()
    """The results archive: every run stored in a database."""
    panel: PanelConfig | None = None
    """The station's web panel (`benchctl serve`)."""

    source: SkipJsonSchema[Path | None] = Field(default=None, exclude=True)
    """The file the config came from (set when it is loaded; not a field of the file)."""

    @field_validator("station")
    @classmethod
    def _station(cls, v: str) -> str:
        return _plain_text(v, STATION_MAX, "station name") or ""


_PATH_FIELDS = {
    ("stand", "register_map"),
    ("instrument", "eds"),
    ("instrument", "dbc"),
    ("run", "output_dir"),
    ("run", "lock_dir"),
    ("archive", "queue_dir"),
}


def _check_fault_transports(cfg: BenchConfig, source: Path) -> None:
    """A scheduled ``garbled`` fault's ``how`` must suit the instrument's driver."""
    if cfg.sim is None:
        return
    for i, fault in enumerate(cfg.sim.faults):
        if fault.target != "instrument":
            continue
        try:
            check_params("instrument", fault.kind, fault.params, driver=cfg.instrument.driver)
        except FaultSpecError as e:
            raise ConfigError(
                f"{source}: invalid bench config: field sim.faults[{i}].{e.field} = "
                f"{shown_value(e.value)}: expected {e.expected} (instrument.driver)"
            ) from None


def exchange_bound_s(stand: StandConfig) -> float:
    """The longest one stand exchange may take plus the heartbeat period: every try's reply
    timeout, ``timeout_s × (retries + 1)``, and the heartbeat that waits behind it."""
    return stand.timeout_s * (stand.retries + 1) + stand.heartbeat_period_s


def _check_watchdog(cfg: BenchConfig, source: Path) -> None:
    """One exchange at its longest plus the heartbeat period must fit inside the stand's
    watchdog (``stand.watchdog_s``, or the simulated stand's ``sim.stand.watchdog_s``): a link
    allowed to wait longer for a reply than the stand waits for a heartbeat lets the stand stop
    itself mid-run on a reply that was merely slow."""
    st = cfg.stand
    where, watchdog = "stand.watchdog_s", st.watchdog_s
    if cfg.sim is not None:
        sim_wd = cfg.sim.stand.watchdog_s
        if watchdog is not None and watchdog != sim_wd:
            raise ConfigError(
                f"{source}: invalid bench config: field stand.watchdog_s = {watchdog:g} s: "
                f"expected the simulated stand's, sim.stand.watchdog_s = {sim_wd:g} s (with a "
                "`sim:` section the simulator is the stand)"
            )
        where, watchdog = "sim.stand.watchdog_s", sim_wd
    if watchdog is None:
        return
    need = exchange_bound_s(st)
    if need > watchdog * (1 + 1e-9):
        raise ConfigError(
            f"{source}: invalid bench config: fields stand.timeout_s = {st.timeout_s:g} s × "
            f"(stand.retries = {st.retries} + 1) + stand.heartbeat_period_s = "
            f"{st.heartbeat_period_s:g} s = {need:g} s: expected at most the stand's watchdog, "
            f"{where} = {watchdog:g} s (one exchange may wait out every try's reply timeout, and "
            "the heartbeat waits behind it: the stand would stop itself mid-run on a slow reply)"
        )


def parse_config(data: Any, source: Path) -> BenchConfig:
    """Validate a config mapping; relative paths resolve against ``source``'s folder."""
    if not isinstance(data, dict):
        raise ConfigError(
            f"{source}: expected a YAML mapping at the top level, got {type(data).__name__}"
        )
    try:
        cfg = BenchConfig.model_validate({**data, "source": source})
    except ValidationError as err:
        raise ConfigError(invalid(source, "bench config", err)) from None
    _check_fault_transports(cfg, source)
    _check_watchdog(cfg, source)
    base = source.parent
    updates: dict[str, Any] = {}
    for section, name in sorted(_PATH_FIELDS):
        sub = getattr(cfg, section)
        value = getattr(sub, name)
        if isinstance(value, Path) and not value.is_absolute():
            try:
                updates.setdefault(section, {})[name] = (base / value).resolve()
            except (OSError, ValueError) as e:
                raise ConfigError(
                    f"{source}: invalid bench config: field {section}.{name} = "
                    f"{shown_value(str(value))}: not a usable path ({e})"
                ) from None
    for section, fields in updates.items():
        cfg = cfg.model_copy(update={section: getattr(cfg, section).model_copy(update=fields)})
    if cfg.panel is not None:
        cfg = cfg.model_copy(update={"panel": cfg.panel.resolved(base)})
    return cfg


CONFIG_SCHEMA_ID = "urn:benchctl:schema:bench-config"
CONFIG_SCHEMA_FILE = "bench-config.schema.json"  # in benchctl/schemas/, for editors


def config_schema() -> dict[str, Any]:
    """The bench config's JSON Schema (draft 2020-12), from the models that validate it: every
    section and field with its type, default, bounds and meaning. ``benchctl schema config``
    prints it; ``benchctl/schemas/bench-config.schema.json`` is the same, shipped for editors
    (a config's first line ``# yaml-language-server: $schema=…`` names it)."""
    schema = _one_line(BenchConfig.model_json_schema(mode="validation"))
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "$id": CONFIG_SCHEMA_ID,
        "title": "benchctl bench config",
        **{k: v for k, v in schema.items() if k != "title"},
    }


def _one_line(node: Any) -> Any:
    """Descriptions as editors show them: a docstring's line breaks become spaces (a blank line
    between paragraphs stays)."""
    if isinstance(node, dict):
        return {
            k: ("\n\n".join(" ".join(p.split()) for p in v.split("\n\n"))
                if k == "description" and isinstance(v, str) else _one_line(v))
            for k, v in node.items()
        }
    if isinstance(node, list):
        return [_one_line(v) for v in node]
    return node


def config_schema_text() -> str:
    """``config_schema()`` as the shipped file has it (indented, UTF-8, one final newline)."""
    return json.dumps(config_schema(), indent=2, ensure_ascii=False, allow_nan=False) + "\n"


def load_config(path: str | Path) -> BenchConfig:
    """Read and validate a bench config YAML file."""
    p = Path(path)
    return parse_config(read_yaml(p, "bench config"), p)


