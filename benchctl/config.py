"""The bench configuration: one YAML file, validated strictly (unknown fields are errors).

Units are in field names. Relative paths in a config (register maps, EDS/DBC files, output
folders) are resolved against the config file's own folder, so a config works from any cwd.
A validation failure raises ``ConfigError`` naming the file, the field, the value and what
was expected; it is always fatal.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from benchctl.errors import ConfigError

Positive = Annotated[float, Field(gt=0)]
NonNegative = Annotated[float, Field(ge=0)]


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
    baudrate: int = 115200
    parity: Literal["N", "E", "O"] = "N"  # modbus-rtu
    stopbits: Literal[1, 2] = 1  # modbus-rtu
    device_id: int = Field(default=1, ge=0, le=247)
    register_map: Path = Path("../drivers/stand_generic.yaml")
    timeout_s: Positive = 0.5
    retries: int = Field(default=1, ge=0)
    axes: tuple[Literal["roll", "pitch"], ...] = ("roll", "pitch")
    mode: Literal["stream", "table"] = "stream"
    setpoint_rate_hz: Positive = 100.0
    sample_rate_hz: Positive = 100.0  # how often the encoder angle is read (stream: each cycle)
    heartbeat_period_s: Positive = 0.1
    limits: StandLimits
    tracking_tolerance_deg: Positive = 0.5  # |measured - commanded| beyond this aborts
    zero_tolerance_deg: Positive = 0.05  # "at rest" means |angle| below this
    wire_trace: bool = False  # debug-log every frame sent and received

    @model_validator(mode="after")
    def _transport(self) -> StandConfig:
        if self.driver == "modbus-rtu" and not self.serial_port:
            raise ValueError("driver modbus-rtu needs serial_port (a device path or pyserial URL)")
        return self


class InstrumentConfig(Strict):
    driver: Literal["canopen", "j1939", "nmea2000", "nmea0183"]
    # CAN (canopen, j1939, nmea2000): any python-can interface name and its channel
    interface: str | None = None  # slcan, socketcand, virtual, pcan, kvaser, socketcan …
    channel: str | None = None
    bitrate: int = 500000
    node_id: int = Field(default=10, ge=1, le=127)  # CANopen node id
    source_address: int | None = Field(default=None, ge=0, le=253)  # J1939 / NMEA 2000 SA filter
    eds: Path | None = None
    dbc: Path | None = None
    can_log: str | None = "can.blf"  # raw CAN frames beside the recording (.blf or .asc)
    # slcan: seconds to wait after opening the serial port (None: 0 for a pseudo-terminal, else
    # python-can's 2 s for a real adapter that resets on open)
    sleep_after_open_s: NonNegative | None = None
    # further keyword arguments for can.Bus (e.g. a hardware interface's own options)
    can_options: dict[str, str | int | float | bool] = Field(default_factory=dict)
    connect_timeout_s: Positive = 3.0  # SDO answers / the first broadcast frame within this
    # serial (nmea0183)
    serial_port: str | None = None
    baudrate: int = 115200
    sentence: Literal["PASHR", "PHTRO", "XDR"] | None = None
    # what the run expects of it
    axes: tuple[Literal["roll", "pitch"], ...] = ("roll", "pitch")
    expected_rate_hz: Positive = 100.0
    static_tolerance_deg: Positive = 0.5  # at rest, |instrument - stand| must be within this
    silence_timeout_s: Positive = 1.0  # no sample for this long aborts the run
    wire_trace: bool = False

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


class SimStandFault(Strict):
    """A fault the simulated stand injects by itself, ``after_s`` seconds after it starts."""

    kind: Literal["drop_connection", "stall", "modbus_exception", "stand_fault", "estop"]
    after_s: NonNegative = 0.0
    duration_s: Positive | None = None  # drop/stall/modbus_exception; None = until cleared
    code: int | None = Field(default=None, ge=1, le=65535)  # modbus_exception or stand_fault code


class SimStandConfig(Strict):
    """Physics of the simulated servo stand."""

    bandwidth_hz: Positive = 8.0
    damping: Positive = 0.8
    rate_limit_deg_s: Positive = 60.0
    accel_limit_deg_s2: Positive = 300.0
    encoder_resolution_deg: NonNegative = 0.001
    soft_limit_deg: Positive = 40.0  # beyond this the simulated stand faults
    watchdog_s: Positive = 1.0  # heartbeat silence that stops the stand
    tick_hz: Positive = 1000.0
    rtu_wire_delay: bool = True  # emulate serial byte time on the RTU pty
    baudrate: int = Field(default=115200, gt=0)  # byte time of the emulated RTU wire
    faults: tuple[SimStandFault, ...] = ()  # injected by schedule (see README, "### Stand")


class SimInstrumentConfig(Strict):
    """The simulated instrument's own model: what it measures of the true stand motion."""

    gain: float = 1.0
    lag_s: NonNegative = 0.0  # first-order time constant
    natural_freq_hz: Positive | None = None  # second-order response, if set
    damping: Positive = 0.7
    latency_s: NonNegative = 0.0
    bias_deg: float = 0.0
    noise_deg: NonNegative = 0.0  # white noise σ
    drift_deg_s: float = 0.0  # slow linear drift
    quantisation_deg: NonNegative = 0.0
    rate_hz: Positive = 100.0
    seed: int = 1
    substep_hz: Positive = 4000.0  # exact first-order-hold integration rate of lag / 2nd order


class SimFault(Strict):
    """A fault the simulators inject by themselves, ``after_motion_s`` after the stand first moves.

    ``target`` stand: kinds of ``SimStand.inject`` (drop_connection, stall, modbus_exception,
    stand_fault, estop); instrument: kinds of ``SimInstrument.inject`` (garbled, silent, stuck,
    drop). ``params`` are that method's keyword arguments.
    """

    target: Literal["stand", "instrument"]
    kind: str
    after_motion_s: NonNegative = 0.0
    params: dict[str, str | int | float] = Field(default_factory=dict)


class SimConfig(Strict):
    """Present in a config → ``benchctl run`` starts the simulators itself (``benchctl sim``)."""

    stand: SimStandConfig = SimStandConfig()
    instrument: SimInstrumentConfig = SimInstrumentConfig()
    faults: tuple[SimFault, ...] = ()
    motion_threshold_deg: Positive = 0.01  # "the stand first moves": |true angle| beyond this


class AnalysisConfig(Strict):
    max_lag_s: Positive | None = None  # default: the documented rule in benchctl.analysis
    band_hz: tuple[NonNegative, Positive] | None = None  # σ restricted to this band
    compensate_delay: Literal["none", "auto"] | float = "none"


class RunConfig(Strict):
    limit_sigma_deg: Positive  # the verdict: PASS when σ ≤ this, per axis
    output_dir: Path = Path("runs")
    min_free_disk_mb: Positive = 200.0
    precheck_window_s: Positive = 1.0  # instrument rate and static agreement measured over this
    # ± fraction of instrument.expected_rate_hz
    instrument_rate_tolerance: Annotated[float, Field(gt=0, lt=1)] = 0.2
    # stand motion departing from the profile beyond this aborts the run
    profile_tolerance_deg: Positive = 1.0
    analysis: AnalysisConfig = AnalysisConfig()


class BenchConfig(Strict):
    station: str = "bench"
    stand: StandConfig
    instrument: InstrumentConfig
    run: RunConfig
    sim: SimConfig | None = None

    source: Path | None = Field(default=None, exclude=True)  # the file it came from


_PATH_FIELDS = {
    ("stand", "register_map"),
    ("instrument", "eds"),
    ("instrument", "dbc"),
    ("run", "output_dir"),
}


def _format_error(path: Path, err: ValidationError) -> str:
    lines = [f"{path}: invalid bench config"]
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "(top level)"
        value = e.get("input")
        shown = "" if isinstance(value, dict) else f" = {value!r}"
        lines.append(f"  field {loc}{shown}: {e['msg']}")
    return "\n".join(lines)


def parse_config(data: Any, source: Path) -> BenchConfig:
    """Validate a config mapping; relative paths resolve against ``source``'s folder."""
    if not isinstance(data, dict):
        raise ConfigError(
            f"{source}: expected a YAML mapping at the top level, got {type(data).__name__}"
        )
    try:
        cfg = BenchConfig.model_validate({**data, "source": source})
    except ValidationError as err:
        raise ConfigError(_format_error(source, err)) from None
    base = source.parent
    updates: dict[str, Any] = {}
    for section, name in _PATH_FIELDS:
        sub = getattr(cfg, section)
        value = getattr(sub, name)
        if isinstance(value, Path) and not value.is_absolute():
            updates.setdefault(section, {})[name] = (base / value).resolve()
    for section, fields in updates.items():
        cfg = cfg.model_copy(update={section: getattr(cfg, section).model_copy(update=fields)})
    return cfg


def read_yaml(path: Path, what: str) -> Any:
    """Parse a YAML file; ``ConfigError`` naming the file (and ``what`` it is) on any problem."""
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"{path}: cannot read {what}: {e.strerror}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as e:
        raise ConfigError(f"{path}: not valid YAML: {e}") from None


def load_config(path: str | Path) -> BenchConfig:
    """Read and validate a bench config YAML file."""
    p = Path(path)
    return parse_config(read_yaml(p, "bench config"), p)
