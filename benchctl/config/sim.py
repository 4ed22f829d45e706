"""The bench config's ``sim:`` section: the simulated stand and instrument, their faults, and
the run on simulated time (its clock and seeded disturbances)."""

from __future__ import annotations

import datetime
from typing import Annotated, Any, Literal

from pydantic import (
    ConfigDict,
    Field,
    ValidationInfo,
    field_validator,
    model_validator,
)

from benchctl.config.types import (
    MAX_WAIT_S,
    Baud,
    DeviceRate,
    Finite,
    NonNegative,
    Positive,
    Seconds,
    Strict,
)
from benchctl.faultspec import (
    FAULTS,
    MAX_FAULT_S,
    STAND,
    FaultSpecError,
    check_kind,
    check_params,
)

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
