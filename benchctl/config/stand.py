"""The bench config's ``stand:`` section: the motion stand, its link and its limits."""

from __future__ import annotations

import datetime
from pathlib import Path
from typing import Annotated, Literal

from pydantic import (
    Field,
    model_validator,
)

from benchctl.config.types import (
    Baud,
    HostRate,
    NonNegative,
    Positive,
    Seconds,
    Strict,
)


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
    encoder_resolution_deg: NonNegative | None = None
    """The reference angle's quantisation step (°): the smallest change of the encoder angle the
    stand reports (its encoder's count, or the register's scaling if coarser). Into σ's
    uncertainty budget (its quantisation adds about q²/12 to σ²); unset: the budget says the
    resolution is not stated."""
    encoder_uncertainty_deg: NonNegative | None = None
    """The standard uncertainty of the reference angle (°, type B: the stand's calibration
    certificate, or its maker's accuracy taken as a rectangular bound ÷ √3), its error beyond the
    quantisation. Into σ's uncertainty budget; unset: the budget says it is not stated."""

    @model_validator(mode="after")
    def _transport(self) -> StandConfig:
        if self.driver == "modbus-rtu" and not self.serial_port:
            raise ValueError("driver modbus-rtu needs serial_port (a device path or pyserial URL)")
        return self




def exchange_bound_s(stand: StandConfig) -> float:
    """The longest one stand exchange may take plus the heartbeat period: every try's reply
    timeout, ``timeout_s × (retries + 1)``, and the heartbeat that waits behind it."""
    return stand.timeout_s * (stand.retries + 1) + stand.heartbeat_period_s
