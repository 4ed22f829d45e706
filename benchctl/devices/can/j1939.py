"""J1939 PGN 61459 (0xF013) Slope Sensor Information, from ``drivers/j1939_slope.dbc``.

Pitch and roll: 0.002 °/bit, offset −64°, raw 0xFB00–0xFFFF reserved / error / not available.
The figure of merit of an axis (0 ok, 1 degraded, 2 error, 3 not available) marks the frame bad
when it says error or not available. Byte 8 is the measurement latency (0.5 ms/bit):
``device_time_s = t_host − latency``, the instant the angles refer to, on the host clock.
No counter. Identity: the source address of the first frame.
"""

from __future__ import annotations

from benchctl.devices.can.dbc import DbcAngleInstrument, DbcAngleSpec

#: highest valid raw value of a 16-bit J1939 parameter; above it: reserved, error, n/a
J1939_MAX_VALID_16 = 0xFAFF

SPEC = DbcAngleSpec(
    protocol="J1939",
    message="SSI",
    angle_signals={"pitch": "PitchAngle", "roll": "RollAngle"},
    to_deg=1.0,
    raw_valid=lambda r: 0 <= r <= J1939_MAX_VALID_16,
    latency_signal_ms="RollAndPitchMeasurementLatency",
    status_signals={"pitch": "PitchAngleFigureOfMerit", "roll": "RollAngleFigureOfMerit"},
    status_bad=frozenset({2, 3}),
)


class J1939SlopeSensor(DbcAngleInstrument):
    """A J1939 slope sensor broadcasting PGN 61459; implements ``AngleSensor``."""

    spec = SPEC
