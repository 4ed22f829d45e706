"""The bench configuration: one YAML file, validated strictly (unknown fields are errors).

Units are in field names. Relative paths in a config (register maps, EDS/DBC files, output
folders) are resolved against the config file's own folder, so a config works from any cwd.
A validation failure raises ``ConfigError`` naming the file, the field, the value and what
was expected; it is always fatal.
"""

from __future__ import annotations

import datetime
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
    model_config = ConfigDict(extra="forbid", frozen=True)


class StandLimits(Strict):
    """Per-axis limits of the stand; every motion is checked against them before it is sent."""

    angle_deg: Positive
    rate_deg_s: Positive
    accel_deg_s2: Positive


class StandConfig(Strict):
    driver: Literal["modbus-tcp", "modbus-rtu"]
    host: str = "127.0.0.1"
    port: int = Field(default=502, ge=0, le=65535)
    serial_port: str | None = None  # modbus-rtu: a device path or a pyserial URL
    baudrate: Baud = 115200
    parity: Literal["N", "E", "O"] = "N"  # modbus-rtu
    stopbits: Literal[1, 2] = 1  # modbus-rtu
    device_id: int = Field(default=1, ge=0, le=247)
    register_map: Path = Path("../drivers/stand_generic.yaml")
    # one exchange lasts at most timeout_s × (retries + 1), and the next heartbeat waits behind
    # it: with heartbeat_period_s that must fit inside the stand's watchdog (checked below)
    timeout_s: Seconds = 0.4
    retries: int = Field(default=1, ge=0, le=100)
    axes: tuple[Literal["roll", "pitch"], ...] = ("roll", "pitch")
    # stream: setpoints from the host; buffered: points queued ahead in the stand's trajectory
    # buffer (needs a `trajectory:` section in the register map); table: the stand plays a table
    mode: Literal["stream", "buffered", "table"] = "stream"
    # buffered: how far ahead the queue is kept (s of motion; capped by the stand's capacity)
    buffer_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 1.0
    setpoint_rate_hz: HostRate = 100.0
    sample_rate_hz: HostRate = 100.0  # how often the encoder angle is read (stream: each cycle)
    heartbeat_period_s: Seconds = 0.1
    # the stand's own heartbeat watchdog (its setting, from its manual or parameters): when
    # given, the config is checked against it (with a `sim:` section: sim.stand.watchdog_s)
    watchdog_s: Seconds | None = None
    limits: StandLimits
    tracking_tolerance_deg: Positive = 0.5  # |measured - commanded| beyond this aborts
    # the stand's following lag (s): a position servo without velocity feed-forward trails its
    # setpoint by about this × its rate (2ζ/ω_n for a second-order loop); the tracking check
    # judges measured − setpoint + following_lag_s × rate. 0: a stand that does not trail
    following_lag_s: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 0.0
    zero_tolerance_deg: Positive = 0.05  # "at rest" means |angle| below this
    wire_trace: bool = False  # debug-log every frame sent and received
    # the stand's calibration due date (YYYY-MM-DD), into the run's record and report
    calibration_due: datetime.date | None = None

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
    sign: Literal[1, -1] = 1


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


class InstrumentConfig(Strict):
    driver: Literal["canopen", "j1939", "nmea2000", "nmea0183"]
    # CAN (canopen, j1939, nmea2000): any python-can interface name and its channel
    interface: str | None = None  # slcan, socketcand, virtual, pcan, kvaser, socketcan …
    channel: str | None = None
    bitrate: Baud = 500000
    node_id: int = Field(default=10, ge=1, le=127)  # CANopen node id
    source_address: int | None = Field(default=None, ge=0, le=253)  # J1939 / NMEA 2000 SA filter
    eds: Path | None = None
    dbc: Path | None = None
    can_log: str | None = "can.blf"  # raw CAN frames beside the recording (.blf or .asc)
    # slcan: seconds to wait after opening the serial port (None: 0 for a pseudo-terminal, else
    # python-can's 2 s for a real adapter that resets on open)
    sleep_after_open_s: Annotated[float, Field(ge=0, le=MAX_WAIT_S, allow_inf_nan=False)] | None = (
        None
    )
    # slcan: ask the adapter to timestamp every received frame (Z1, its own ms clock); the
    # analysis then dates the samples by the adapter's clock, not by their receipt
    adapter_timestamps: bool = True
    # further keyword arguments for can.Bus (e.g. a hardware interface's own options)
    can_options: dict[str, str | int | Finite | bool] = Field(default_factory=dict)
    connect_timeout_s: Seconds = 3.0  # SDO answers / the first broadcast frame within this
    # serial (nmea0183)
    serial_port: str | None = None
    baudrate: Baud = 115200
    sentence: Literal["PASHR", "PHTRO", "XDR"] | None = None
    # what the run expects of it: the stand's axes it measures, and for each the instrument's
    # output that measures it and its sign (InstrumentAxis). A list (`[roll, pitch]`) reads
    # each output as the stand axis of its own name; a mapping (`roll: {output: pitch,
    # sign: -1}`) maps a unit whose axes are swapped or reversed on the stand
    axes: dict[AxisName, InstrumentAxis] = Field(
        default_factory=lambda: {a: InstrumentAxis(output=a) for a in ("roll", "pitch")}
    )
    expected_rate_hz: DeviceRate = 100.0
    static_tolerance_deg: Positive = 0.5  # at rest, |instrument - stand| must be within this
    silence_timeout_s: Seconds = 1.0  # no sample for this long aborts the run
    wire_trace: bool = False

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
    after_s: FaultSeconds = 0.0
    duration_s: Positive | None = None  # drop/stall/modbus_exception; None = until cleared
    code: int | None = None  # modbus_exception (1..255) or stand_fault (1..65535) code

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
    damping: Positive = 0.8
    rate_limit_deg_s: Positive = 60.0
    accel_limit_deg_s2: Positive = 300.0
    encoder_resolution_deg: NonNegative = 0.001
    soft_limit_deg: Positive = 40.0  # beyond this the simulated stand faults
    watchdog_s: Seconds = 1.0  # heartbeat silence that stops the stand
    tick_hz: DeviceRate = 1000.0
    rtu_wire_delay: bool = True  # emulate serial byte time on the RTU pty
    # stream mode: the drive interpolates linearly between consecutive setpoints over the
    # interval between them (as a drive in cyclic synchronous position mode does), instead of
    # stepping to each one (a staircase the servo follows with its own, higher acceleration)
    stream_interpolation: bool = False
    baudrate: Baud = 115200  # byte time of the emulated RTU wire
    faults: tuple[SimStandFault, ...] = ()  # injected by schedule (docs/reference/simulators.md)


class CrossAxisConfig(Strict):
    """Cross-axis coupling of the simulated instrument (a misaligned sensing axis): each
    axis's input is its own angle plus this fraction of the other axis's angle (|k| ≤ 1)."""

    roll_from_pitch: Annotated[float, Field(ge=-1, le=1, allow_inf_nan=False)] = 0.0
    pitch_from_roll: Annotated[float, Field(ge=-1, le=1, allow_inf_nan=False)] = 0.0


class SimMountingConfig(Strict):
    """How the simulated unit is mounted on the stand: ``swap_axes`` (its roll output senses
    the stand's pitch and the other way round), then ``roll_sign``/``pitch_sign`` (−1: that
    output reads the angle it senses reversed). Applied to the true motion the instrument's
    model senses, so every protocol sees it; the default is a correct mount."""

    swap_axes: bool = False
    roll_sign: Literal[1, -1] = 1
    pitch_sign: Literal[1, -1] = 1


class SimInstrumentConfig(Strict):
    """The simulated instrument's own model: what it measures of the true stand motion.

    Optional static effects on each axis's input before the dynamics, in this order: the
    cross-axis coupling, then the cubic term ``u + cubic_per_deg2 · u³``, then the saturation
    ``clip(u, −saturation_deg, +saturation_deg)``; all off by default (the model is linear).
    """

    gain: Finite = 1.0
    lag_s: Annotated[float, Field(ge=0, le=MAX_WAIT_S, allow_inf_nan=False)] = 0.0  # 1st order
    natural_freq_hz: Positive | None = None  # second-order response, if set
    damping: Positive = 0.7
    latency_s: Annotated[float, Field(ge=0, le=MAX_WAIT_S, allow_inf_nan=False)] = 0.0
    bias_deg: Finite = 0.0
    noise_deg: NonNegative = 0.0  # white noise σ
    drift_deg_s: Finite = 0.0  # slow linear drift
    quantisation_deg: NonNegative = 0.0
    rate_hz: DeviceRate = 100.0
    seed: int = Field(default=1, ge=0, lt=2**63)
    # exact first-order-hold integration rate of lag / 2nd order
    substep_hz: Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)] = 4000.0
    cross_axis: CrossAxisConfig = CrossAxisConfig()
    cubic_per_deg2: Annotated[float, Field(ge=-1, le=1, allow_inf_nan=False)] = 0.0
    saturation_deg: Annotated[float, Field(gt=0, le=360, allow_inf_nan=False)] | None = None
    # the serial number it reports where its protocol carries one (CANopen 1018h sub 4, an
    # UNSIGNED32); None: the EDS's default
    serial_number: int | None = Field(default=None, ge=0, lt=2**32)
    # how the unit sits on the stand (swapped or reversed axes); default: mounted correctly
    mounting: SimMountingConfig = SimMountingConfig()


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
    kind: str = Field(json_schema_extra={"enum": [k for t in FAULTS.values() for k in t]})
    after_motion_s: FaultSeconds = 0.0
    params: dict[str, bool | str | int | Finite] = Field(default_factory=dict)

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
    from_s: Annotated[float, Field(ge=0, le=86_400, allow_inf_nan=False)] = 0.0
    host_stalls_per_min: Annotated[float, Field(ge=0, le=600, allow_inf_nan=False)] = 0.0
    host_stall_s: tuple[SimSeconds, SimSeconds] = (0.05, 0.3)
    send_jitter_s: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 0.0
    slow_reply_p: Probability = 0.0
    slow_reply_s: tuple[SimSeconds, SimSeconds] = (0.01, 0.5)
    lost_reply_p: Probability = 0.0
    lost_frame_p: Probability = 0.0
    garbled_frame_p: Probability = 0.0
    faults: Annotated[int, Field(ge=0, le=100)] = 0
    fault_kinds: tuple[str, ...] = ("stand:stall", "stand:stand_fault", "instrument:silent")
    operator_stop_p: Probability = 0.0

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
    instrument: SimInstrumentConfig = SimInstrumentConfig()
    faults: tuple[SimFault, ...] = ()
    motion_threshold_deg: Positive = 0.01  # "the stand first moves": |true angle| beyond this
    #: ``real``: the simulators run beside the run on the host's time, over a TCP socket and
    #: pseudo-terminals; ``virtual``: in the run's process on simulated time, over in-process
    #: links (``benchctl.channels``) — a 15-minute test in about a minute, the same bytes
    #: every time
    clock: Literal["real", "virtual"] = "real"
    #: simulated time: the UTC wall time at its start (every stamp of the run follows from it)
    epoch_utc: datetime.datetime = datetime.datetime(2026, 1, 1, tzinfo=datetime.UTC)
    #: simulated time: one way latency of the stand's link (Modbus TCP; RTU adds byte times)
    link_latency_s: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 0.0005
    #: simulated time: the host computation charged to each cycle of the stand loop, so a loop
    #: too slow for its rate still shows as one
    host_cost_s: Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)] = 0.0002
    #: simulated time: seeded host stalls, slow/lost/garbled frames, faults, an operator's stop
    disturb: SimDisturbConfig | None = None

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
    level: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = 0.2
    periods: Annotated[int, Field(ge=1, le=20)] = 1
    max_period_s: Annotated[float, Field(ge=1, le=600, allow_inf_nan=False)] = 20.0
    fade_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 2.0
    settle_s: Annotated[float, Field(ge=0, le=60, allow_inf_nan=False)] = 3.0
    min_gain_db: Annotated[float, Field(ge=-60, lt=0, allow_inf_nan=False)] = -20.0
    max_boost_db: Annotated[float, Field(ge=0, le=40, allow_inf_nan=False)] = 10.0
    max_uncertainty_db: Annotated[float, Field(gt=0, le=6, allow_inf_nan=False)] = 0.5


class AnalysisConfig(Strict):
    # default: the documented rule in benchctl.analysis
    max_lag_s: Annotated[float, Field(gt=0, le=86400, allow_inf_nan=False)] | None = None
    band_hz: tuple[NonNegative, Positive] | None = None  # σ restricted to this band
    compensate_delay: (
        Literal["none", "auto"] | Annotated[float, Field(ge=-3600, le=3600, allow_inf_nan=False)]
    ) = "none"
    # after an underrun or a rejoin, the stand is back on the profile: its servo and the
    # instrument settle for this long before the analysis takes its samples again
    # (benchctl.analysis.departures)
    departure_settle_s: Annotated[float, Field(ge=0, le=60, allow_inf_nan=False)] = 3.0

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
    abort_db: Annotated[float, Field(gt=0, le=40, allow_inf_nan=False)] = 3.0
    weak_line_db: Annotated[float, Field(ge=-120, lt=0, allow_inf_nan=False)] = -30.0
    weak_band_db: Annotated[float, Field(ge=-120, lt=0, allow_inf_nan=False)] = -20.0
    max_ci_db: Annotated[float, Field(gt=0, le=20, allow_inf_nan=False)] = 0.5
    band_edges_hz: tuple[Positive, ...] | None = None
    # stop the run when, during the motion, a band's running estimate lies beyond ±abort_db
    abort_run: bool = True

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
    tilt_deg: Annotated[float, Field(gt=0, le=10, allow_inf_nan=False)] = 2.0
    hold_s: Annotated[float, Field(ge=0.2, le=10, allow_inf_nan=False)] = 1.0
    gain_tolerance: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.3
    cross_tolerance: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.3

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

    gain_min: Positive | None = None  # gain at the periods 3/5/7/10 s (where excited) ≥ this
    gain_max: Positive | None = None  # … ≤ this
    phase_deg: Annotated[float, Field(gt=0, le=180, allow_inf_nan=False)] | None = None  # |φ| ≤
    delay_s: Annotated[float, Field(gt=0, le=MAX_WAIT_S, allow_inf_nan=False)] | None = None
    mean_error_deg: Positive | None = None  # |mean error| ≤ this

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
    window_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 2.0
    # the fixed wake period measured besides the stand loop's own (cyclictest's 1 ms)
    period_s: Annotated[float, Field(ge=1e-4, le=1.0, allow_inf_nan=False)] = 0.001
    # worst lateness × margin must fit inside the stand's tolerance
    margin: Annotated[float, Field(ge=1, le=1e6, allow_inf_nan=False)] = 4.0
    on_poor: Literal["warn", "refuse"] = "warn"


class RunConfig(Strict):
    limit_sigma_deg: Positive  # the verdict: PASS when σ ≤ this, per axis
    # how σ (and every measurement with an interval) is judged against its limit:
    # simple (value ≤ limit) or guarded (the 95 % interval wholly within: PASS; wholly beyond:
    # FAIL; else INCONCLUSIVE, exit 3); benchctl.results.measurements
    decision_rule: Literal["simple", "guarded"] = "simple"
    limits: RunLimits = RunLimits()  # optional limits for gain, phase, delay, mean error
    output_dir: Path = Path("runs")
    min_free_disk_mb: Positive = 200.0
    precheck_window_s: Seconds = 1.0  # instrument rate and static agreement measured over this
    # ± fraction of instrument.expected_rate_hz
    instrument_rate_tolerance: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] = 0.2
    # stand motion departing from the profile beyond this aborts the run
    profile_tolerance_deg: Positive = 1.0
    # sine_steps profiles: PASS when max − min of the steps' gains ≤ this (per axis)
    linearity_spread_limit: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = 0.01
    analysis: AnalysisConfig = AnalysisConfig()
    excitation: ExcitationConfig = ExcitationConfig()  # measured excitation fidelity
    lock_dir: Path | None = None  # one run per stand: its lock files (None: /run/benchctl-locks)
    # stop the motion once σ's 95 % interval is within ± this fraction of σ (after at least one
    # whole period of the multisine; benchctl.run.precision); None: the whole profile runs
    precision: Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)] | None = None
    # a low-level pre-test and the drive corrected by the stand's measured response (off by
    # default; --equalise turns it on)
    equalise: EqualiseConfig = EqualiseConfig()
    # before the motion, each axis tilted to a few degrees and back: a unit mounted reversed
    # or with its axes swapped is refused (on by default)
    mounting_check: MountingCheckConfig = MountingCheckConfig()
    # the host's scheduling latency measured before the motion and judged against the stand's
    # buffer and watchdog (benchctl.run.fitness; docs/howto/host-check.md)
    host_check: HostCheckConfig = HostCheckConfig()
    # SCHED_FIFO priority (1–99) the stand loop thread asks for on the real clock (Linux:
    # CAP_SYS_NICE or an rtprio limit); whether it was granted is recorded, a refusal never
    # stops the run; None: not asked for
    realtime_priority: Annotated[int, Field(ge=1, le=99)] | None = None
    # the report's figures drawn at the run's end (analysis_<axis>.png and report.html's
    # figures, about 1-3 s per axis); false on a bench whose reports nobody opens at the
    # station (a CI bench, a campaign): report.html says so, `benchctl report REC` draws them
    figures: bool = True


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
    url: str | None = None
    queue_dir: Path | None = None
    connect_timeout_s: Annotated[float, Field(gt=0, le=30, allow_inf_nan=False)] = 2.0
    write_timeout_s: Annotated[float, Field(gt=0, le=60, allow_inf_nan=False)] = 2.0

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
    serial_pattern: str | None = Field(default=None, min_length=1, max_length=MAX_SERIAL_PATTERN)
    serial_check: Literal["warn", "require"] = "warn"

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
    profiles: list[Path] = Field(default_factory=list)
    plans: list[Path] = Field(default_factory=list)
    duration_s: Annotated[float, Field(gt=0, allow_inf_nan=False)] | None = None
    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=0, le=65535)] = 8350
    token_scrypt: str | None = None
    require_token: bool = False
    origins: list[str] = Field(default_factory=list)
    out_dir: Path | None = None

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
    station: str = "bench"
    unit: UnitConfig = UnitConfig()
    stand: StandConfig
    instrument: InstrumentConfig
    run: RunConfig
    sim: SimConfig | None = None
    archive: ArchiveConfig = ArchiveConfig()  # the results archive (benchctl.archive)
    panel: PanelConfig | None = None  # the station's web panel (benchctl serve)

    source: Path | None = Field(default=None, exclude=True)  # the file it came from

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


def load_config(path: str | Path) -> BenchConfig:
    """Read and validate a bench config YAML file."""
    p = Path(path)
    return parse_config(read_yaml(p, "bench config"), p)


